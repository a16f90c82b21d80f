#!/usr/bin/env python3
"""Markdown tables of the micro-benchmarks, from their Google Benchmark JSON files.

  tables.py [--trace benchmarks/results/trace.json] [--incremental benchmarks/results/incremental.json]

The tables of docs/performance.md ("Tracing" and "Incremental evaluation") and
benchmarks/results/micro.md are this script's output (with the machine line it prints
first), so that every figure there comes from a file `make bench` writes.
Ratios (incremental / full retrace) are taken within one file, i.e. one run.
"""
from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def load(path: Path) -> tuple[dict, list[dict]]:
    d = json.loads(path.read_text())
    return d["context"], [b for b in d["benchmarks"] if b.get("run_type", "iteration") == "iteration"]


def machine(ctx: dict, name: str) -> str:
    load_avg = ", ".join(f"{x:.1f}" for x in ctx.get("load_avg", []))
    return f"{name}: {ctx.get('date', '?')}, {ctx.get('num_cpus', '?')} CPUs, load average {load_avg}"


def trace_tables(benchmarks: list[dict]) -> str:
    rates: dict[tuple, float] = {}
    for b in benchmarks:
        m = re.match(r"trace/(\w+)/(\w+)/(\w+)/(\d+)/threads:(\d+)", b["name"])
        if m:
            rates[(m[1], m[2], m[3], int(m[4]), int(m[5]))] = b["items_per_second"] / 1e6
    out = ["| tracer | light | hits | mesh | 1 thread (M rays/s) | 2 threads (M rays/s) |",
           "|---|---|---|---:|---:|---:|"]
    for key in sorted({k[:4] for k in rates}, key=lambda k: (k[0] != "heightfield", k[1], k[2] != "phong", k[3])):
        one, two = rates.get((*key, 1)), rates.get((*key, 2))
        hits = "Phong α = 0.75" if key[2] == "phong" else "flat"
        out.append(f"| {key[0]} | {key[1]} | {hits} | {key[3]}² | {one or 0:.2f} | {two or 0:.2f} |")
    refit = ["", "| Embree refit | mesh | tiles refitted | µs |", "|---|---:|---:|---:|"]
    for b in benchmarks:
        m = re.match(r"refit/embree/(\w+)/(\d+)", b["name"])
        if m:
            refit.append(f"| {'7 × 7 patch' if m[1] == 'patch7x7' else 'whole surface'} | {m[2]}² | "
                         f"{b.get('tiles', 0):.1f} | {b['real_time']:.0f} |")
    return "\n".join(out + (refit if len(refit) > 3 else []))


def incremental_tables(benchmarks: list[dict]) -> str:
    rows: dict[tuple, dict] = {}
    for b in benchmarks:
        m = re.match(r"(\w+)/mesh:(\d+)/receiver:(\d+)/kernel:(\d+)/speculative:(\d+)", b["name"])
        if m:
            rows[(m[1], int(m[2]), int(m[3]), int(m[4]), int(m[5]))] = b
    ips = {k: v.get("iterations_per_second", 0.0) for k, v in rows.items()}
    out = ["| tracer | mesh | receiver | kernel | full retrace (it/s) | incremental (it/s) | "
           "incremental, 2 speculative (it/s) | incremental / full | rays per move | acceptance |",
           "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    keys = sorted({k[1:4] for k in rows}, key=lambda k: (k[2] != 5, k[1], k[0], k[2]))
    for tracer, inc, full in (("heightfield", "incremental", "full_retrace"),
                              ("embree", "embree_incremental", "embree_full_retrace")):
        for mesh, rec, kern in keys:
            i1 = ips.get((inc, mesh, rec, kern, 1))
            if i1 is None:
                continue
            f = ips.get((full, mesh, rec, kern, 1))
            i2 = ips.get((inc, mesh, rec, kern, 2))
            b = rows[(inc, mesh, rec, kern, 1)]
            rays = b.get("rays_per_move")
            cells = [tracer, f"{mesh}²", f"{rec}²", str(kern), f"{f:.1f}" if f else "—", f"{i1:,.0f}",
                     f"{i2:,.0f}" if i2 else "—", f"{i1 / f:.0f}×" if f else "—",
                     f"{rays:,.0f}" if rays else "—", f"{b.get('acceptance', 0):.2f}"]
            out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trace", type=Path, default=ROOT / "benchmarks/results/trace.json")
    ap.add_argument("--incremental", type=Path, default=ROOT / "benchmarks/results/incremental.json")
    a = ap.parse_args()
    if a.trace.exists():
        ctx, b = load(a.trace)
        print(machine(ctx, a.trace.name) + "\n")
        print(trace_tables(b) + "\n")
    if a.incremental.exists():
        ctx, b = load(a.incremental)
        print(machine(ctx, a.incremental.name) + "\n")
        print(incremental_tables(b))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

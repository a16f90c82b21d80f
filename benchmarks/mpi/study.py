#!/usr/bin/env python3
"""Replica exchange over MPI against the plain design at equal total cores (issue 12).

For each scene, seed and configuration, runs `freeform design` (1 rank x C threads) or
`mpirun -np N freeform_mpi design` (N ranks x C/N threads; N > C oversubscribes: the
ranks share the cores) with the same time budget, and records the final error (the
exact tracer's, metrics.json "error") and the wall time of the whole command.

    benchmarks/mpi/study.py --bin build/release/bin --cores 2 --budget 20 --seeds 1 2 3 \
        --scenes examples/scenes/camera.json examples/scenes/letter-e.json \
        --out benchmarks/results/mpi

Writes runs.csv and summary.md under --out (the raw design outputs go to a temporary
directory).
"""
import argparse
import csv
import json
import os
import statistics
import subprocess
import tempfile
import time


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default="build/release/bin")
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--budget", type=float, default=20)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--scenes", nargs="+", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--ladder-ratio", type=float, default=None, help="freeform_mpi --ladder-ratio")
    ap.add_argument("--exchange-every", type=int, default=None, help="freeform_mpi --exchange-every")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    rows = []
    work = tempfile.mkdtemp(prefix="mpi-study-")
    for scene in a.scenes:
        name = os.path.splitext(os.path.basename(scene))[0]
        for seed in a.seeds:
            for ranks in a.ranks:
                threads = max(1, a.cores // ranks)
                out = os.path.join(work, f"{name}-s{seed}-r{ranks}")
                common = ["design", scene, "--out", out, "--seed", str(seed), "--time-budget", str(a.budget),
                          "--threads", str(threads), "--quiet"]
                if ranks == 1:
                    cmd = [os.path.join(a.bin, "freeform")] + common
                else:
                    cmd = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-np", str(ranks),
                           os.path.join(a.bin, "freeform_mpi")] + common
                    if a.ladder_ratio is not None:
                        cmd += ["--ladder-ratio", str(a.ladder_ratio)]
                    if a.exchange_every is not None:
                        cmd += ["--exchange-every", str(a.exchange_every)]
                t0 = time.monotonic()
                p = subprocess.run(cmd, capture_output=True, text=True)
                wall = time.monotonic() - t0
                if p.returncode != 0:
                    print("FAILED", " ".join(cmd), p.stderr[-2000:])
                    continue
                m = json.load(open(os.path.join(out, "metrics.json")))
                r = m.get("replicas", {})
                pairs = r.get("pairs", [])
                row = {
                    "scene": name, "seed": seed, "ranks": ranks, "threads_per_rank": threads,
                    "oversubscribed": ranks * threads > a.cores, "budget_s": a.budget,
                    "wall_s": round(wall, 2), "design_s": round(m["seconds"], 2), "error": m["error"],
                    "energy": m["energy"], "iterations_winner": m["iterations"],
                    "iterations_all": r.get("iterations_all_ranks", m["iterations"]),
                    "winner_rank": r.get("winner_rank", 0),
                    "swaps": ";".join(f'{p["accepted"]}/{p["proposed"]}' for p in pairs),
                }
                rows.append(row)
                print(json.dumps(row), flush=True)
    with open(os.path.join(a.out, "runs.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)
    lines = ["| scene | ranks x threads | runs | median error | errors (by seed) | median wall s | median iterations (all ranks) | winner ranks | swaps accepted/proposed |",
             "|---|---|---|---|---|---|---|---|---|"]
    for scene in dict.fromkeys(r["scene"] for r in rows):
        for ranks in a.ranks:
            rs = [r for r in rows if r["scene"] == scene and r["ranks"] == ranks]
            if not rs:
                continue
            over = " (oversubscribed)" if rs[0]["oversubscribed"] else ""
            lines.append(
                f'| {scene} | {ranks} x {rs[0]["threads_per_rank"]}{over} | {len(rs)} | '
                f'{statistics.median(r["error"] for r in rs):.4f} | '
                f'{", ".join("%.4f" % r["error"] for r in rs)} | '
                f'{statistics.median(r["wall_s"] for r in rs):.1f} | '
                f'{int(statistics.median(r["iterations_all"] for r in rs))} | '
                f'{",".join(str(r["winner_rank"]) for r in rs)} | {" ".join(r["swaps"] or "-" for r in rs)} |')
    open(os.path.join(a.out, "summary.md"), "w").write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

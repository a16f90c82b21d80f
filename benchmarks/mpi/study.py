#!/usr/bin/env python3
"""freeform_mpi (domains or tempering) against the plain design at equal total cores (issue 12).

For each scene, seed and configuration, runs `freeform design` (1 rank x C threads) or
`mpirun -np N freeform_mpi design` (N ranks x C/N threads; N > C oversubscribes: the
ranks share the cores) with the same time budget, and records the final error (the
exact tracer's, metrics.json "error", and "error_held_out" with rays the design was not
fitted to, where the build reports it) and the wall time of the whole command.

    benchmarks/mpi/study.py --bin build/release/bin --cores 2 --budget 20 --seeds 1 2 3 \
        --scenes examples/scenes/camera.json examples/scenes/letter-e.json \
        --out /tmp/mpi-study

Writes runs.csv and summary.md under --out (the raw design outputs go to a temporary
directory). runs.csv is rewritten after every run, so a study stopped early keeps what
it ran. Runs are interleaved by seed (seed, then scene, then configuration), so that
load from other work on the machine falls on every configuration alike.

--ladder-ratios 1.5 1.1 runs every multi-rank configuration at each ratio (the 1-rank
runs once per seed); --ladder-ratio R is the same as --ladder-ratios R (tempering only).
--replica-mode and --merge-coverage are passed to every multi-rank run; without them
freeform_mpi's defaults apply (domains, coverage 30). benchmarks/mpi/plot.py draws the
error against the budget from one or more runs.csv.
"""
import argparse
import csv
import json
import os
import shutil
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
    ap.add_argument("--scenes", nargs="+", default=[])
    ap.add_argument("--out", required=True)
    ap.add_argument("--ladder-ratio", type=float, default=None, help="freeform_mpi --ladder-ratio")
    ap.add_argument("--ladder-ratios", type=float, nargs="+", default=None,
                    help="run each multi-rank configuration at each of these ratios")
    ap.add_argument("--exchange-every", type=int, default=None, help="freeform_mpi --exchange-every")
    ap.add_argument("--replica-mode", choices=["tempering", "domains"], default=None,
                    help="freeform_mpi --replica-mode (default: freeform_mpi's)")
    ap.add_argument("--merge-coverage", type=float, default=None, help="freeform_mpi --merge-coverage")
    ap.add_argument("--summary-only", action="store_true",
                    help="run nothing: write summary.md from the runs.csv already in --out")
    a = ap.parse_args()
    if not a.scenes and not a.summary_only:
        ap.error("--scenes is required (unless --summary-only)")
    os.makedirs(a.out, exist_ok=True)
    ratios = a.ladder_ratios or [a.ladder_ratio]  # None: freeform_mpi's default
    rows = []
    work = tempfile.mkdtemp(prefix="mpi-study-")
    configs = [(ranks, None) if ranks == 1 else (ranks, ratio) for ranks in a.ranks
               for ratio in ([None] if ranks == 1 else ratios)]
    if a.summary_only:
        summarize(read_rows(os.path.join(a.out, "runs.csv")), configs, a.out)
        return
    for seed in a.seeds:
        for scene in a.scenes:
            name = os.path.splitext(os.path.basename(scene))[0]
            for ranks, ratio in configs:
                threads = max(1, a.cores // ranks)
                tag = "" if ratio is None else f"-l{ratio}"
                out = os.path.join(work, f"{name}-s{seed}-r{ranks}{tag}")
                common = ["design", scene, "--out", out, "--seed", str(seed), "--time-budget", str(a.budget),
                          "--threads", str(threads), "--quiet"]
                if ranks == 1:
                    cmd = [os.path.join(a.bin, "freeform")] + common
                else:
                    cmd = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-np", str(ranks),
                           os.path.join(a.bin, "freeform_mpi")] + common
                    if ratio is not None:
                        cmd += ["--ladder-ratio", str(ratio)]
                    if a.exchange_every is not None:
                        cmd += ["--exchange-every", str(a.exchange_every)]
                    if a.replica_mode is not None:
                        cmd += ["--replica-mode", a.replica_mode]
                    if a.merge_coverage is not None:
                        cmd += ["--merge-coverage", str(a.merge_coverage)]
                load = os.getloadavg()[0]  # other work on the machine when the run started
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
                    "mode": r.get("mode", ""), "merges": r.get("merges", ""),
                    "ladder_ratio": r.get("ladder_ratio", ""),
                    "cores_per_rank": ";".join(str(c) for c in r.get("cores_per_rank", [])),
                    "oversubscribed": ranks * threads > a.cores, "budget_s": a.budget,
                    "load1_before": round(load, 2), "wall_s": round(wall, 2), "design_s": round(m["seconds"], 2), "error": m["error"],
                    "error_held_out": m.get("error_held_out", ""),
                    "energy": m["energy"], "start_s": round(m["start"]["seconds"], 2),
                    "iterations_winner": m["iterations"],
                    "iterations_all": r.get("iterations_all_ranks", m["iterations"]),
                    "winner_rank": r.get("winner_rank", 0),
                    "swaps": (";".join(f'{p["accepted"]}/{p["proposed"]}' for p in pairs) or
                              (f'{r["merges"]} merges' if r.get("mode") == "domains" else "")),
                }
                shutil.rmtree(out, ignore_errors=True)  # the camera's outputs are megabytes a run
                rows.append(row)
                print(json.dumps(row), flush=True)
                with open(os.path.join(a.out, "runs.csv"), "w", newline="") as f:
                    w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
                    w.writeheader()
                    w.writerows(rows)
    summarize(rows, configs, a.out)


def read_rows(path):
    """runs.csv back into rows with the types the study wrote."""
    rows = []
    for r in csv.DictReader(open(path)):
        for k in ("seed", "ranks", "threads_per_rank", "iterations_winner", "iterations_all", "winner_rank"):
            r[k] = int(r[k])
        for k in ("budget_s", "load1_before", "wall_s", "design_s", "error", "energy", "start_s"):
            r[k] = float(r[k])
        r["ladder_ratio"] = float(r["ladder_ratio"]) if r["ladder_ratio"] else ""
        r["error_held_out"] = float(r["error_held_out"]) if r.get("error_held_out") else ""
        r["oversubscribed"] = r["oversubscribed"] == "True"
        rows.append(r)
    return rows


def config_rows(rows, scene, ranks, ratio):
    return [r for r in rows if r["scene"] == scene and r["ranks"] == ranks and
            (ranks == 1 or ratio is None or r["ladder_ratio"] == ratio)]


def paired(rows, configs, key="error"):
    """Seed by seed: each configuration against the first (1 rank), and each further
    ladder ratio against the first ratio of the same rank count; compares `key`."""
    pairs = [(configs[0], c) for c in configs[1:]]
    multi = [c for c in configs if c[0] > 1]
    pairs += [(a, b) for a in multi for b in multi if a[0] == b[0] and a is not b and multi.index(a) < multi.index(b)]
    def name(c):
        threads = next((r["threads_per_rank"] for r in rows if r["ranks"] == c[0]), "?")
        return f"{c[0]} x {threads}" + ("" if c[0] == 1 or c[1] is None else f", ratio {c[1]}")
    if any(r.get(key, "") == "" for r in rows):
        return []
    lines = ["", f"Seed by seed, {key} (ranks x threads; same scene and seed; lower wins):", "",
             "| scene | A | B | seeds | B lower | equal | B higher | median of B − A | median error A → B |",
             "|---|---|---|---|---|---|---|---|---|"]
    for scene in dict.fromkeys(r["scene"] for r in rows):
        for a, b in pairs:
            ea = {r["seed"]: r[key] for r in config_rows(rows, scene, *a)}
            eb = {r["seed"]: r[key] for r in config_rows(rows, scene, *b)}
            seeds = sorted(set(ea) & set(eb))
            if not seeds:
                continue
            d = [eb[s] - ea[s] for s in seeds]
            lines.append(f"| {scene} | {name(a)} | {name(b)} | {len(seeds)} | {sum(x < 0 for x in d)} | "
                         f"{sum(x == 0 for x in d)} | {sum(x > 0 for x in d)} | {statistics.median(d):+.4f} | "
                         f"{statistics.median(ea[s] for s in seeds):.4f} → {statistics.median(eb[s] for s in seeds):.4f} |")
    return lines


def summarize(rows, configs, out):
    lines = ["| scene | ranks x threads | ladder ratio | runs | median error | errors (by seed) | median wall s | median start s | median iterations (all ranks) | winner ranks | swaps accepted/proposed (domains: merges) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for scene in dict.fromkeys(r["scene"] for r in rows):
        for ranks, ratio in configs:
            rs = config_rows(rows, scene, ranks, ratio)
            if not rs:
                continue
            over = " (oversubscribed)" if rs[0]["oversubscribed"] else ""
            lines.append(
                f'| {scene} | {ranks} x {rs[0]["threads_per_rank"]}{over} | {rs[0]["ladder_ratio"] or "-"} | {len(rs)} | '
                f'{statistics.median(r["error"] for r in rs):.4f} | '
                f'{", ".join("%.4f" % r["error"] for r in rs)} | '
                f'{statistics.median(r["wall_s"] for r in rs):.1f} | '
                f'{statistics.median(r["start_s"] for r in rs):.2f} | '
                f'{int(statistics.median(r["iterations_all"] for r in rs))} | '
                f'{",".join(str(r["winner_rank"]) for r in rs)} | {" ".join(r["swaps"] or "-" for r in rs)} |')
    lines += paired(rows, configs)
    lines += paired(rows, configs, "error_held_out")
    open(os.path.join(out, "summary.md"), "w").write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

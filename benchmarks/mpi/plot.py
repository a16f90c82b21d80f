#!/usr/bin/env python3
"""Error against wall-time budget for each ranks x threads configuration, from the
runs.csv files that benchmarks/mpi/study.py writes (any number of them, any budgets).

    /usr/bin/python3 benchmarks/mpi/plot.py --out OUT/error_vs_time.png \
        OUT/c10/runs.csv OUT/c30/runs.csv OUT/ranks124_40s/runs.csv

(OUT/c10 etc.: the folders given to benchmarks/mpi/study.py --out.)

One panel per scene; for each configuration the median over seeds at each budget, with
a bar from the lowest to the highest seed. Configurations are told apart by ranks,
threads per rank, mode and, where a file's directory name says so (c10, c30), the merge
coverage: rows of 2 ranks from a file named .../c10/runs.csv are labelled "coverage 10".
The held-out error (rays the design was not fitted to) is drawn dashed.
"""
import argparse
import csv
import os
import statistics

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def label(row, path):
    ranks, threads = int(row["ranks"]), int(row["threads_per_rank"])
    name = f"{ranks} rank{'s' if ranks > 1 else ''} x {threads} thread{'s' if threads > 1 else ''}"
    if ranks > 1:
        name += f", {row.get('mode') or 'tempering'}"
        tag = os.path.basename(os.path.dirname(path))
        if tag.startswith("c") and tag[1:].isdigit():
            name += f", coverage {tag[1:]}"
        if row.get("oversubscribed") == "True":
            name += " (oversubscribed)"
    return name


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("runs", nargs="+", help="runs.csv files")
    ap.add_argument("--out", required=True, help="PNG to write")
    a = ap.parse_args()
    data = {}  # scene -> label -> budget -> [(error, held_out)]
    for path in a.runs:
        for r in csv.DictReader(open(path)):
            held = float(r["error_held_out"]) if r.get("error_held_out") else None
            data.setdefault(r["scene"], {}).setdefault(label(r, path), {}).setdefault(float(r["budget_s"]), []).append(
                (float(r["error"]), held))
    scenes = sorted(data)
    fig, axes = plt.subplots(1, len(scenes), figsize=(6.5 * len(scenes), 4.8), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        for k, (name, by_budget) in enumerate(sorted(data[scene].items())):
            budgets = sorted(by_budget)
            color = f"C{k}"
            med = [statistics.median(e for e, _ in by_budget[b]) for b in budgets]
            lo = [min(e for e, _ in by_budget[b]) for b in budgets]
            hi = [max(e for e, _ in by_budget[b]) for b in budgets]
            n = [len(by_budget[b]) for b in budgets]
            shift = [b * (1 + 0.012 * (k - 2)) for b in budgets]  # keep the bars apart
            ax.errorbar(shift, med, yerr=[[m - l for m, l in zip(med, lo)], [h - m for h, m in zip(hi, med)]],
                        marker="o", color=color, capsize=3,
                        label=f"{name} ({'/'.join(str(x) for x in n)} seeds)")
            held = [[h for _, h in by_budget[b] if h is not None] for b in budgets]
            if all(held):
                ax.plot(shift, [statistics.median(h) for h in held], linestyle="--", marker="x", color=color,
                        alpha=0.7)
        ax.set_title(f"{scene}: error against wall-time budget, 2 cores")
        ax.set_xlabel("time budget (s)")
        ax.set_ylabel("L1 error (median; bars: seed range; dashed: held-out rays)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(a.out, dpi=110)
    print("wrote", a.out)


if __name__ == "__main__":
    main()

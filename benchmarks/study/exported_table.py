#!/usr/bin/env python3
"""Design error against the error of the exported mesh, per case and method, from a
study's run files (issue 13: what the milled part does, next to what was optimised).

    /usr/bin/python3 benchmarks/study/exported_table.py [RESULTS_DIR]   (default
    benchmarks/results/model13)

Prints a Markdown table: runs, budget, median design error, median exported error
(study_run's final.error_exported: the exported mesh at the "auto" subdivision, or a
lens's closed solid, traced as flat triangles with Embree), the largest |difference|,
the median subdivision k, and the relative standard deviation over seeds of the error.
"""
import json
import statistics
import sys
from pathlib import Path


def main():
    root = Path(sys.argv[1] if len(sys.argv) > 1 else "benchmarks/results/model13") / "runs"
    if not root.is_dir():
        sys.exit("exported_table.py: no runs directory under %s" % root.parent)
    rows = []
    for case_dir in sorted(p for p in root.iterdir() if p.is_dir()):
        for method_dir in sorted(p for p in case_dir.iterdir() if p.is_dir()):
            runs = [json.loads(f.read_text()) for f in sorted(method_dir.glob("*.json"))]
            runs = [r for r in runs if "error_exported" in r.get("final", {})]
            if not runs:
                continue
            err = [r["final"]["error"] for r in runs]
            exp = [r["final"]["error_exported"] for r in runs]
            ks = [r["final"].get("export_subdivisions", 0) for r in runs]
            budget = statistics.median(r.get("time_budget") or 0 for r in runs)
            rsd = statistics.pstdev(err) / statistics.mean(err) if len(err) > 1 else 0.0
            rows.append((case_dir.name, method_dir.name, len(runs), budget, statistics.median(err),
                         statistics.median(exp), max(abs(a - b) for a, b in zip(err, exp)),
                         statistics.median(ks), rsd))
    print("| case | method | runs | budget s | error (median) | exported (median) | max abs diff | k | rel. sd |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for c, m, n, b, e, x, d, k, s in rows:
        print("| %s | %s | %d | %g | %.4f | %.4f | %.4f | %g | %.1f %% |" % (c, m, n, b, e, x, d, k, 100 * s))


if __name__ == "__main__":
    main()

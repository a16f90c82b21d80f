#!/usr/bin/env python3
"""Tables of issue 11, parts 3 and 4, from the study's run files.

    /usr/bin/python3 benchmarks/study/issue11_tables.py fixed [STABILITY_DIR [TIME_BUDGET_DIR]]
        (defaults benchmarks/results/stability_fixed_cal, benchmarks/results/model13)
    /usr/bin/python3 benchmarks/study/issue11_tables.py mesh [MESH_RULE_DIR]
        (default benchmarks/results/mesh_rule)

fixed: per simple case, the final error of `ours-iters` (a fixed iteration count, no time
limit) over its seeds, next to the same statistics of `ours` at the study's time budgets
(the time-budget runs of TIME_BUDGET_DIR), each column labelled; and whether the repeat of
the first seed (`ours-iters-repeat`) ended with the same heights bit for bit.

mesh: per case, `ours-mesh-auto` (the "auto" mesh rule) against `ours-mesh-auto-x2` (twice
as many vertices per side) at equal time: median design and exported error, per-seed wins,
relative sd, iterations.

Relative sd is the sample standard deviation over the mean (statistics.stdev, n - 1), as
in the study's stability.csv. Prints Markdown.
"""
from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path

SIMPLE = ["E", "V", "at", "headlight", "point", "lens"]
NEW = ["R", "amp", "ring", "checker", "gradient"]
NAMES = {"at": "@", "amp": "&"}


def load(root: Path, case: str, method: str) -> dict:
    """seed -> run JSON."""
    out = {}
    for f in sorted((root / "runs" / case / method).glob("*.json")):
        r = json.loads(f.read_text())
        if "final" in r:
            out[r["seed"]] = r
    return out


def stats(errors):
    n = len(errors)
    mean = statistics.fmean(errors)
    sd = statistics.stdev(errors) if n > 1 else 0.0
    return {"n": n, "median": statistics.median(errors), "mean": mean, "sd": sd, "rsd": sd / mean,
            "min": min(errors), "max": max(errors)}


def pct(x):
    return f"{100 * x:.1f} %"


def fixed(stab: Path, timed: Path) -> str:
    out = []
    print = out.append  # noqa: A001 (the table as lines)
    print("| case | mesh | iterations | seeds | fixed iterations: median | min–max | sd | **rel. sd (fixed iterations)** "
          "| time budget | seeds | time budget: median | **rel. sd (time budget)** | repeat of seed 101 |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    for c in SIMPLE:
        runs = load(stab, c, "ours-iters")
        if not runs:
            continue
        its = sorted({r["iterations"] for r in runs.values()})
        s = stats([r["final"]["error"] for r in runs.values()])
        t_runs = load(timed, c, "ours")
        t = stats([r["final"]["error"] for r in t_runs.values()]) if t_runs else None
        budget = statistics.median(r["time_budget"] for r in t_runs.values()) if t_runs else None
        t_mesh = "/".join(sorted({"×".join(map(str, r["model"]["mesh"])) for r in t_runs.values()}))
        t_mesh = f" (mesh {t_mesh})" if t_mesh and t_mesh != "/".join(sorted({"×".join(map(str, r["model"]["mesh"]))
                                                                           for r in runs.values()})) else ""
        rep = load(stab, c, "ours-iters-repeat")
        same = "—"
        if rep:
            seed = min(rep)
            a, b = runs.get(seed), rep[seed]
            if a:
                same = ("same heights bit for bit" if a["final"]["heights_fingerprint"] == b["final"]["heights_fingerprint"]
                        else "**differs**") + f" ({a['seconds']:.1f} s / {b['seconds']:.1f} s)"
        mesh_ = "/".join(sorted({"×".join(map(str, r["model"]["mesh"])) for r in runs.values()}))
        print(f"| {NAMES.get(c, c)} | {mesh_} | {'/'.join(map(str, its))} | {s['n']} | {s['median']:.4f} | "
              f"{s['min']:.4f}–{s['max']:.4f} | {s['sd']:.5f} | **{pct(s['rsd'])}** | "
              + (f"{budget:g} s{t_mesh} | {t['n']} | {t['median']:.4f} | **{pct(t['rsd'])}** | " if t else "— | — | — | — | ")
              + same + " |")
    return "\n".join(out) + "\n"


def mesh(root: Path) -> str:
    out = []
    print = out.append  # noqa: A001
    print("| case | mesh auto → ×2 | seeds | auto: median error | ×2: median error | ×2 − auto | ×2 better "
          "(same seed) | auto: exported | ×2: exported | start alone auto / ×2 | rel. sd auto / ×2 "
          "| iterations auto / ×2 |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    tally = {"old": [0, 0], "new": [0, 0]}
    for c in SIMPLE + NEW:
        a, b = load(root, c, "ours-mesh-auto"), load(root, c, "ours-mesh-auto-x2")
        seeds = sorted(set(a) & set(b))
        if not seeds:
            continue
        ea = [a[s]["final"]["error"] for s in seeds]
        eb = [b[s]["final"]["error"] for s in seeds]
        xa = [a[s]["final"].get("error_exported", float("nan")) for s in seeds]
        xb = [b[s]["final"].get("error_exported", float("nan")) for s in seeds]
        sa, sb = stats(ea), stats(eb)
        wins = sum(y < x for x, y in zip(ea, eb))
        ma, mb = a[seeds[0]]["model"]["mesh"], b[seeds[0]]["model"]["mesh"]
        st_a = statistics.median(a[s]["start"]["error"] for s in seeds)
        st_b = statistics.median(b[s]["start"]["error"] for s in seeds)
        ia = statistics.median(a[s]["iterations"] for s in seeds)
        ib = statistics.median(b[s]["iterations"] for s in seeds)
        group = "new" if c in NEW else "old"
        tally[group][0] += sb["median"] < sa["median"]
        tally[group][1] += 1
        print(f"| {NAMES.get(c, c)}{' (new)' if c in NEW else ''} | {ma[0]}×{ma[1]} → {mb[0]}×{mb[1]} | {len(seeds)} "
              f"| {sa['median']:.4f} | {sb['median']:.4f} | {sb['median'] - sa['median']:+.4f} | {wins}/{len(seeds)} "
              f"| {statistics.median(xa):.4f} | {statistics.median(xb):.4f} | {st_a:.4f} / {st_b:.4f} "
              f"| {pct(sa['rsd'])} / {pct(sb['rsd'])} "
              f"| {ia:.0f} / {ib:.0f} |")
    for g, (w, n) in tally.items():
        if n:
            print(f"\n×2 has the lower median error on {w} of {n} {'example' if g == 'old' else 'new'} targets.")
    return "\n".join(out) + "\n"


def header(out_dir: Path) -> str:
    """What made the runs: study.json's passes (when, commit, command, load)."""
    try:
        meta = json.loads((out_dir / "study.json").read_text())
    except (OSError, json.JSONDecodeError):
        return ""
    lines = [f"Machine: {meta.get('cpu')}, {meta.get('cores')} cores; {meta.get('threads')} thread(s) per run, runs "
             f"one at a time.", ""]
    for p in meta.get("passes") or []:
        lines.append(f"- pass {p.get('started')} → {p.get('finished')}: {p.get('runs_done')} runs, commit "
                     f"`{(p.get('commit') or '')[:10]}`{' (with uncommitted changes)' if p.get('dirty') else ''}: "
                     f"`{p.get('command')}`")
    if any(p.get("dirty") for p in meta.get("passes") or []):
        lines += ["", "The passes marked \"with uncommitted changes\" ran from a clean clone of that commit with "
                  "this plan's study scripts (`benchmarks/study/*.py`) added before they were committed; the library "
                  "and `study_run` were the commit's."]
    return "\n".join(lines) + "\n"


FIXED_TEXT = """# Stability at a fixed iteration count (issue 11, part 3)

`ours` (the library's default: transport start, then annealing) stopped at a fixed
iteration count per case (`optimise.max_iterations`, the median iterations of the
time-budget runs of `benchmarks/results/model13`, rounded to 500; the time budget, 3600 s,
is only a safety cap that no stage reaches: every stage stopped on `max_iterations`),
10 seeds per simple case. Nothing in such a run depends on the clock (the stages'
temperatures come from 48 trial moves, not from a timed calibration, and the iteration
budgets from the plan), so for a given build its result is the same under any load and
on any machine: the repeat of seed 101 (`ours-iters-repeat`) checks it on every case.
Builds with other instruction sets (FREEFORM_ARCH) may differ in the last bits (the
transport start) and then follow another trajectory. The columns marked
"time budget" are `ours` at the study's budgets (12 s, headlight 5 s, 2 threads) from
`benchmarks/results/model13`, the same cases and seeds. Relative sd: sample sd / mean.

Tables: `/usr/bin/python3 benchmarks/study/issue11_tables.py fixed`.

"""

MESH_TEXT = """# The "auto" mesh rule against a mesh twice as fine (issue 11, part 4)

`ours-mesh-auto`: ours with `surface.mesh` "auto" (the rule of `plan_levels`; on the
example scenes with an explicit mesh it gives that same mesh); `ours-mesh-auto-x2`: the
same on (n − 1)·2 + 1 vertices per side. Both from the transport start, at the same
time budget (20 s, the start included), one thread, 10 seeds, runs interleaved
(auto, ×2, auto, ×2, ...) so that the other work on the shared machine meets both alike.
Every design is judged at the case's receiver with the case's light (seed 1); "exported"
is the exported mesh traced as flat triangles (a lens as its closed solid). The new
targets (marked "new") are on the setups of the example scenes, only the target replaced
(`study_plan.py`, images by `benchmarks/study/make_targets.py`): R on letter-e, & on
point-light, ring on headlight, checker on lens, gradient (photographic) on camera.

Tables: `/usr/bin/python3 benchmarks/study/issue11_tables.py mesh`.

"""


def write_report(kind: str, out_dir: Path, timed: Path | None = None) -> Path:
    if kind == "fixed":
        body = FIXED_TEXT + fixed(out_dir, timed or out_dir.parent / "model13")
    else:
        body = MESH_TEXT + mesh(out_dir)
    path = out_dir / "REPORT.md"
    path.write_text(body + "\n" + header(out_dir))
    return path


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1] not in ("fixed", "mesh"):
        sys.exit(__doc__)
    if sys.argv[1] == "fixed":
        print(fixed(Path(sys.argv[2] if len(sys.argv) > 2 else "benchmarks/results/stability_fixed_cal"),
                    Path(sys.argv[3] if len(sys.argv) > 3 else "benchmarks/results/model13")), end="")
    else:
        print(mesh(Path(sys.argv[2] if len(sys.argv) > 2 else "benchmarks/results/mesh_rule")), end="")


if __name__ == "__main__":
    main()

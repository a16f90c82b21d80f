"""Aggregation, charts and REPORT.md of the speed/accuracy study (the physical measure).

build(out_dir, meta, quick) reads every run in out_dir/runs (.json.gz, or the plain .json of
an earlier checkout: run_files.py), writes runs.csv, summary.json, figures/*.png and
REPORT.md, and returns the report's path. Every error here is `error_physical`
(docs/measures.md): the exported mesh traced as flat triangles, nearest
deposit, at the receiver's resolution, with rays enough that doubling them changes it by
less than 0.001. The optimisers' own figure (fitted rays, bilinear deposit) appears only
where it is named: the fitted-against-physical table and the trace chart.
It copes with whatever is on disk: a missing run is counted and reported as missing.
"""
from __future__ import annotations

import csv
import json
import math
import statistics
import subprocess
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
import numpy as np  # noqa: E402

import run_files  # noqa: E402
import study_plan as plan  # noqa: E402

FAIL_FACTOR = 1.5   # a run fails when its error_physical exceeds this times ours' median on the case
FAIL_ENERGY = 0.9   # ... or when less than this share of the light reaches the receiver
RSD_GOAL = 0.05
# Issue 22's goals: (case, seconds, error_physical at most), read at the ladder's 2B runs.
GOALS = [("E", 20.0, 0.025), ("camera", 60.0, 0.030)]

COLORS = {"ours": "#000000", "transport-only": "#d4a017", "sa-plain": "#d62728", "spsa": "#1f77b4",
          "pagmo-sa": "#ff7f0e", "pagmo-cmaes": "#2ca02c", "nlopt-bobyqa": "#9467bd"}


# ------------------------------------------------------------------------------ loading

def load_runs(out_dir: Path) -> list[dict]:
    runs = []
    for f in run_files.files(out_dir / "runs"):
        try:
            r = run_files.read(f)
        except (OSError, ValueError):
            continue
        s, fin = r.get("study"), r.get("final") or {}
        if not s or "error_physical" not in fin:
            continue
        rows = np.array(r["trace"]["rows"], dtype=float) if r["trace"]["rows"] else np.zeros((0, 6))
        runs.append({
            "case": s["case"], "method": s["method"], "purpose": s["purpose"], "budget": float(s["budget"]),
            "seed": s["seed"], "phys": fin["error_physical"], "energy": fin.get("energy_physical", fin["energy"]),
            "fitted": fin["error"], "exported": fin.get("error_exported"), "rpc": fin.get("physical_rays_per_cell"),
            "fingerprint": fin.get("heights_fingerprint"), "seconds": r["seconds"], "iterations": r["iterations"],
            "eps": r.get("evaluations_per_second", r["iterations_per_second"]), "trace": rows,
            "levels": r["trace"]["levels"], "threads": r["threads"], "start": r.get("start") or {},
            "model": r.get("model") or {}, "max_iterations": r.get("max_iterations", 0), "pass": s.get("pass"),
        })
    return runs


def med(xs):
    xs = [x for x in xs if x is not None and not (isinstance(x, float) and math.isnan(x))]
    return statistics.median(xs) if xs else float("nan")


def spread(values: list[float]) -> dict:
    n = len(values)
    mean = statistics.fmean(values) if n else float("nan")
    sd = statistics.stdev(values) if n > 1 else float("nan")
    return {"n": n, "median": med(values), "min": min(values, default=float("nan")),
            "max": max(values, default=float("nan")), "mean": mean, "sd": sd,
            "rsd": sd / mean if n > 1 and mean > 0 else float("nan")}


def f3(x, digits=3):
    if x is None or (isinstance(x, float) and (math.isnan(x) or math.isinf(x))):
        return "–"
    return f"{x:.{digits}f}"


def fnum(x):
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    return f"{x:.3g}" if x < 1e5 else f"{x:.2e}"


def pct(x):
    return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:.1f} %"


def table(header: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join(" --- " for _ in header) + "|"]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(out)


def med_range(s: dict, digits=4) -> str:
    if not s["n"]:
        return "–"
    if s["n"] == 1:
        return f"{f3(s['median'], digits)} (n=1)"
    return f"{f3(s['median'], digits)} ({f3(s['min'], digits)}–{f3(s['max'], digits)}, n={s['n']})"


# ------------------------------------------------------------------------------ the study

class Study:
    def __init__(self, out_dir: Path, meta: dict, quick: bool):
        self.out_dir, self.meta, self.quick = out_dir, meta, quick
        self.runs = load_runs(out_dir)
        self.groups: dict[tuple, list[dict]] = defaultdict(list)
        for r in self.runs:
            self.groups[(r["case"], r["method"], r["purpose"], r["budget"])].append(r)
        order = plan.PUBLIC_CASES + plan.STRESS_CASES
        self.cases = [c for c in order if any(r["case"] == c for r in self.runs)]
        self.public = [c for c in self.cases if c in plan.PUBLIC_CASES]
        self.main_purpose = "quick" if quick else "main"

    def budget(self, case: str) -> float:
        c = plan.CASES[case]
        return c.quick_budget if self.quick else c.budget

    def select(self, case, method, purpose=None, budget=None) -> list[dict]:
        purpose = purpose or self.main_purpose
        return [r for r in self.runs if r["case"] == case and r["method"] == method and r["purpose"] == purpose
                and (budget is None or abs(r["budget"] - budget) < 1e-9)]

    def main(self, case, method) -> list[dict]:
        # transport-only takes no budget: every main run of it counts
        b = None if method == "transport-only" else self.budget(case)
        return self.select(case, method, budget=b)

    def ours_ladder(self, case) -> list[tuple[float, list[dict]]]:
        """(budget, runs) of ours at every budget measured, shortest first."""
        out = defaultdict(list)
        for r in self.runs:
            if r["case"] == case and r["method"] == "ours" and r["purpose"] in (self.main_purpose, "ladder"):
                out[r["budget"]].append(r)
        return sorted(out.items())

    def methods(self, case) -> list[str]:
        names = plan.MAIN_METHODS
        return [m for m in names if self.main(case, m)]

    def ours_median(self, case) -> float:
        return med([r["phys"] for r in self.main(case, "ours")])

    def failed(self, r: dict) -> bool:
        ref = self.ours_median(r["case"])
        return (not math.isnan(ref) and r["phys"] > FAIL_FACTOR * ref) or r["energy"] < FAIL_ENERGY

    def save(self, fig, name: str, dpi=110) -> str:
        (self.out_dir / "figures").mkdir(parents=True, exist_ok=True)
        path = self.out_dir / "figures" / f"{name}.png"
        fig.savefig(path, dpi=dpi, bbox_inches="tight")
        plt.close(fig)
        return f"figures/{name}.png"

    # -------------------------------------------------------------------------- figures

    def _panels(self, cases):
        n = len(cases)
        cols = min(4, n)
        rows = math.ceil(n / cols)
        fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False)
        for ax in axes.flat[n:]:
            ax.axis("off")
        return fig, list(axes.flat[:n])

    def _plot_ladder(self, ax, case, label):
        ladder = self.ours_ladder(case)
        if ladder:
            t = [med([r["seconds"] for r in rs]) for _, rs in ladder]
            m = [med([r["phys"] for r in rs]) for _, rs in ladder]
            lo = [min(r["phys"] for r in rs) for _, rs in ladder]
            hi = [max(r["phys"] for r in rs) for _, rs in ladder]
            ax.errorbar(t, m, yerr=[np.subtract(m, lo), np.subtract(hi, m)], color=COLORS["ours"], marker="o",
                        ms=4, lw=1.6, capsize=3, label=label)

    def _plot_method(self, ax, case, method, label):
        rs = self.main(case, method)
        if not rs:
            return
        if method == "transport-only":  # at the start's own time
            t = med([r["start"].get("seconds") or r["seconds"] for r in rs])
        else:
            t = med([r["seconds"] for r in rs])
        e = [r["phys"] for r in rs]
        mm = med(e)
        ax.errorbar([t], [mm], yerr=[[mm - min(e)], [max(e) - mm]], color=COLORS.get(method, "#888"),
                    marker="D" if method == "transport-only" else "s", ms=5, capsize=3, ls="none", label=label)

    @staticmethod
    def _legend(fig, axes, **kw):
        handles, labels = [], []
        for ax in axes:
            for h, lab in zip(*ax.get_legend_handles_labels()):
                if lab not in labels:
                    handles.append(h)
                    labels.append(lab)
        fig.legend(handles, labels, loc="lower right", fontsize=8, **kw)

    def fig_overview(self) -> str | None:
        if not self.public:
            return None
        fig, axes = self._panels(self.public)
        for ax, case in zip(axes, self.public):
            self._plot_ladder(ax, case, "ours")
            for method in self.methods(case):
                if method != "ours":
                    self._plot_method(ax, case, method, method)
            ax.set_xscale("log")
            ax.set_yscale("log")
            for axis in (ax.xaxis, ax.yaxis):
                axis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
                axis.set_minor_formatter(matplotlib.ticker.NullFormatter())
            ax.set_title(f"{case} (B = {self.budget(case):g} s)", fontsize=10)
            ax.set_xlabel("wall seconds (2 cores)", fontsize=8)
            ax.set_ylabel("error_physical", fontsize=8)
            ax.grid(True, which="both", alpha=0.3)
            ax.tick_params(labelsize=7)
        self._legend(fig, axes, ncol=2 if len(self.public) % 4 == 0 else 1)
        fig.suptitle("error_physical against time: median and min–max over seeds (ours at B/2, B, 2B; "
                     "baselines at B; the transport start at its own time)", fontsize=10)
        fig.tight_layout()
        return self.save(fig, "overview")

    def fig_ours_time(self) -> str | None:
        """Ours and its start alone, on a linear axis: the overview's log axis, spanning the
        baselines, flattens what more time buys."""
        if not self.public:
            return None
        fig, axes = self._panels(self.public)
        for ax, case in zip(axes, self.public):
            self._plot_ladder(ax, case, "ours (B/2, B, 2B)")
            self._plot_method(ax, case, "transport-only", "transport start alone")
            for gcase, seconds, goal in GOALS:
                if gcase == case:
                    ax.plot([seconds], [goal], marker="_", ms=18, mew=2, color="#d62728", ls="none",
                            label="issue 22's goal")
            ax.set_title(f"{case} (B = {self.budget(case):g} s)", fontsize=10)
            ax.set_xlabel("wall seconds (2 cores)", fontsize=8)
            ax.set_ylabel("error_physical", fontsize=8)
            ax.grid(True, alpha=0.3)
            ax.tick_params(labelsize=7)
        self._legend(fig, axes)
        fig.suptitle("Ours against time (linear axis): median and min–max over seeds", fontsize=10)
        fig.tight_layout()
        return self.save(fig, "ours_time")

    def fig_traces(self) -> str | None:
        if not self.public:
            return None
        fig, axes = self._panels(self.public)
        for ax, case in zip(axes, self.public):
            for method in self.methods(case):
                if method == "transport-only":
                    continue
                rs = [r for r in self.main(case, method) if len(r["trace"])]
                if not rs:
                    continue
                end = max(r["trace"][-1, 0] for r in rs)
                grid = np.geomspace(0.05, max(end, 0.1), 120)
                vals = []
                for r in rs:
                    tr = r["trace"][r["trace"][:, 2] == r["levels"] - 1] if r["levels"] > 1 else r["trace"]
                    if not len(tr):
                        continue
                    idx = np.searchsorted(tr[:, 0], grid, side="right") - 1
                    vals.append(np.where(idx >= 0, tr[np.clip(idx, 0, None), 3], np.nan))
                if vals:
                    ax.plot(grid, np.nanmedian(np.array(vals), axis=0), color=COLORS.get(method, "#888"), lw=1.3,
                            label=method)
                    ax.plot([med([r["seconds"] for r in rs])], [med([r["phys"] for r in rs])], marker="*", ms=8,
                            color=COLORS.get(method, "#888"), ls="none")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_title(case, fontsize=10)
            ax.set_xlabel("wall seconds", fontsize=8)
            ax.set_ylabel("optimiser's own error", fontsize=8)
            ax.grid(True, which="both", alpha=0.3)
            ax.tick_params(labelsize=7)
        self._legend(fig, axes)
        fig.suptitle("What each optimiser saw: its own error (fitted rays, bilinear deposit; final level only) at the "
                     "case's budget B, median over seeds; ★ = error_physical at the end", fontsize=10)
        fig.tight_layout()
        return self.save(fig, "traces")

    def fig_stability(self) -> str | None:
        cases = [c for c in self.public if self.select(c, "ours-iters", "stability")]
        if not cases:
            return None
        fig, ax = plt.subplots(figsize=(1.3 * len(cases) + 2, 3.6))
        for i, case in enumerate(cases):
            ref = self.ours_median(case)
            timed = [r["phys"] / ref for r in self.main(case, "ours")]
            fixed = [r["phys"] / ref for r in self.select(case, "ours-iters", "stability")]
            ax.plot(np.full(len(timed), i - 0.12), timed, "o", color="#000", ms=4, alpha=0.7,
                    label="fixed time B" if i == 0 else None)
            ax.plot(np.full(len(fixed), i + 0.12), fixed, "^", color="#1f77b4", ms=4, alpha=0.7,
                    label="fixed iterations" if i == 0 else None)
        ax.axhline(1.0, color="#888", lw=0.8)
        ax.set_xticks(range(len(cases)))
        ax.set_xticklabels(cases)
        ax.set_ylabel("error_physical / median at B")
        ax.set_title("ours over 10 seeds: at a fixed time and at a fixed iteration count", fontsize=10)
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        return self.save(fig, "stability")

    # -------------------------------------------------------------------------- sections

    def glance(self) -> str:
        methods = [m for m in plan.MAIN_METHODS if any(self.main(c, m) for c in self.public)]
        rows = []
        for case in self.public:
            best = min((med([r["phys"] for r in self.main(case, m)]) for m in methods if self.main(case, m)),
                       default=float("nan"))
            row = [case, f"{self.budget(case):g} s"]
            for m in methods:
                rs = self.main(case, m)
                v = med([r["phys"] for r in rs])
                cell = f3(v, 4) if rs else "–"
                row.append(f"**{cell}**" if rs and v == best else cell)
            ref = plan.CASES[case].reference
            row.append(f"{ref['error']:.3f} in {ref['seconds']:g} s" if "error" in ref else "–")
            rows.append(row)
        return table(["case", "budget B"] + methods + ["reference (its own measure, GPU)"], rows)

    def verdict(self) -> list[str]:
        out = []
        wins = 0
        for case in self.public:
            ours = self.ours_median(case)
            others = {m: med([r["phys"] for r in self.main(case, m)]) for m in self.methods(case) if m != "ours"}
            lower = {m: v for m, v in others.items() if v < ours}
            base = {m: v for m, v in others.items() if m in plan.BASELINES}
            best_base = min(base.items(), key=lambda kv: kv[1]) if base else None
            tr = others.get("transport-only")
            bits = [f"**{case}**: ours {f3(ours, 4)} at {self.budget(case):g} s"]
            if tr is not None and not math.isnan(tr):
                bits.append(f"the start alone {f3(tr, 4)} (annealing removes {pct(1 - ours / tr)} of it)")
            if best_base:
                bits.append(f"best baseline {best_base[0]} {f3(best_base[1], 4)} ({best_base[1] / ours:.1f}× ours)")
            if lower:
                bits.append("**lower than ours: " + ", ".join(f"{m} {f3(v, 4)}" for m, v in lower.items()) + "**")
            else:
                wins += 1
            out.append("- " + "; ".join(bits) + ".")
        out.insert(0, f"Ours has the lowest median error_physical on {wins} of {len(self.public)} cases.")
        return out

    def time_section(self) -> str:
        rows, never_worse, checked = [], 0, 0
        for case in self.public:
            ladder = self.ours_ladder(case)
            if not ladder:
                continue
            cells = [f"{b:g} s: {f3(med([r['phys'] for r in rs]), 4)} (n={len(rs)})" for b, rs in ladder]
            meds = [med([r["phys"] for r in rs]) for _, rs in ladder]
            falls = all(b <= a for a, b in zip(meds, meds[1:]))
            checked += 1
            never_worse += falls
            rows.append([case, " → ".join(cells), "yes" if falls else "**no**"])
        text = (f"More time never worse (median error_physical falls from each budget to the next): "
                f"{never_worse} of {checked} cases.\n\n")
        return text + table(["case", "ours: median error_physical at each budget", "falls with time"], rows)

    def goals_section(self) -> str:
        rows = []
        for case, seconds, goal in GOALS:
            rs = [r for r in self.runs if r["case"] == case and r["method"] == "ours" and abs(r["budget"] - seconds) < 1e-9]
            if not rs:
                rows.append([case, f"{seconds:g} s", "not run", f"≤ {goal}", "–"])
                continue
            s = spread([r["phys"] for r in rs])
            rows.append([case, f"{seconds:g} s", med_range(s), f"≤ {goal}", "met" if s["median"] <= goal else "**not met**"])
        return table(["case", "budget", "ours: error_physical", "goal (issue 22)", ""], rows)

    def stability_section(self) -> str:
        rows = []
        for case in self.public:
            timed = self.main(case, "ours")
            fixed = self.select(case, "ours-iters", "stability")
            rep = self.select(case, "ours-iters-repeat", "stability")
            if not fixed and not timed:
                continue
            st, sf = spread([r["phys"] for r in timed]), spread([r["phys"] for r in fixed])
            same = "–"
            if rep and fixed:
                first = [r for r in fixed if r["seed"] == rep[0]["seed"]]
                same = ("identical heights" if first and first[0]["fingerprint"] == rep[0]["fingerprint"]
                        else "**differs**")
            its = fixed[0]["max_iterations"] if fixed else None
            rows.append([case, med_range(st), pct(st["rsd"]),
                         pct((st["max"] - st["min"]) / st["median"]) if st["n"] > 1 else "–",
                         f"{its:,}" if its else "–", med_range(sf), pct(sf["rsd"]),
                         pct((sf["max"] - sf["min"]) / sf["median"]) if sf["n"] > 1 else "–",
                         f3(med([r["seconds"] for r in fixed]), 1) if fixed else "–", same])
        return table(["case", f"fixed time B: error_physical", "rel. sd", "range / median", "fixed iterations",
                      "fixed iterations: error_physical", "rel. sd", "range / median", "seconds (fixed its)",
                      "repeat of seed 101"], rows)

    def fitted_section(self) -> str:
        rows = []
        for case in self.public:
            for m in self.methods(case):
                rs = self.main(case, m)
                fit, phys = med([r["fitted"] for r in rs]), med([r["phys"] for r in rs])
                rows.append([case, m, f3(fit, 4), f3(med([r["exported"] for r in rs]), 4), f3(phys, 4),
                             f"{phys / fit:.2f}" if fit > 0 else "–", fnum(med([r["rpc"] for r in rs]))])
        return table(["case", "method", "surface model, bilinear", "exported mesh, bilinear", "error_physical",
                      "physical / model", "rays per cell (physical)"], rows)

    def failure_section(self) -> str:
        rows = []
        for case in self.public:
            ref = self.ours_median(case)
            for m in self.methods(case):
                rs = self.main(case, m)
                bad = [r for r in rs if self.failed(r)]
                low = sum(r["energy"] < FAIL_ENERGY for r in rs)
                rows.append([case, m, f"{len(bad)}/{len(rs)}", f3(FAIL_FACTOR * ref, 4), str(low),
                             f3(min(r["energy"] for r in rs), 3)])
        by_method = defaultdict(lambda: [0, 0])
        for row in rows:
            a, b = row[2].split("/")
            by_method[row[1]][0] += int(a)
            by_method[row[1]][1] += int(b)
        summary = "; ".join(f"{m} {a}/{b}" for m, (a, b) in by_method.items())
        return (f"A run fails when its error_physical exceeds {FAIL_FACTOR} × ours' median on the case, or when less "
                f"than {FAIL_ENERGY} of the light reaches the receiver. Failures over the public cases: {summary}.\n\n"
                + table(["case", "method", "failures", "threshold", "energy < 0.9", "lowest energy"], rows))

    def stress_section(self) -> str:
        rows, notes = [], []
        for case in [c for c in self.cases if c in plan.STRESS_CASES]:
            c = plan.CASES[case]
            cells = []
            for m in ["ours", "transport-only", "sa-plain"]:
                rs = self.select(case, m, "stress")
                cells.append(f"{f3(med([r['phys'] for r in rs]), 4)} / {f3(med([r['energy'] for r in rs]), 3)}"
                             if rs else "–")
            rows.append([case, c.title] + cells)
            ours = self.select(case, "ours", "stress")
            tr = [r["start"].get("transport") or {} for r in ours]
            facts = []
            if tr:
                exc = med([t.get("height_excess") for t in tr])
                rng = med([t.get("height_range") for t in tr])
                if rng == rng:
                    facts.append(f"transport surface's height range {1000 * rng:.1f} mm, "
                                 f"{1000 * exc:.1f} mm over the bounds")
                used = sum((r["start"].get("used") == "transport") for r in ours)
                facts.append(f"transport start used in {used}/{len(ours)} runs")
                facts.append(f"ours took {med([r['seconds'] for r in ours]):.1f} s of its {self.budget(case):g} s "
                             f"budget, the start alone {med([r['start'].get('seconds') for r in ours]):.1f} s")
                facts.append(f"ours' moves/s {fnum(med([r['eps'] for r in ours]))} "
                             f"(E at B: {fnum(med([r['eps'] for r in self.main('E', 'ours')]))})")
            notes.append(f"- **{case}** — {c.stress}. Measured: " + ("; ".join(facts) if facts else "–") + ".")
        if not rows:
            return "_No stress runs on disk._"
        return (table(["case", "what", "ours: error_physical / energy", "transport-only", "sa-plain"], rows)
                + "\n\n" + "\n".join(notes))

    def speed_section(self) -> str:
        rows = []
        for case in self.public:
            row = [case]
            for m in plan.MAIN_METHODS:
                rs = self.main(case, m)
                if m == "transport-only":
                    row.append(f3(med([r["start"].get("seconds") for r in rs]), 2) + " s" if rs else "–")
                else:
                    row.append(fnum(med([r["eps"] for r in rs])) if rs else "–")
            rows.append(row)
        return ("Evaluations per second at the case's budget B (moves judged for the annealers, full objectives for "
                "the other baselines), median over seeds; for the transport start its seconds (two OT grids, the fit "
                "and the exact tracer's check).\n\n" + table(["case"] + plan.MAIN_METHODS, rows))

    def cases_section(self) -> str:
        rows = []
        for case in self.cases:
            c = plan.CASES[case]
            ours = self.main(case, "ours") or self.select(case, "ours", "stress")
            model = ours[0]["model"] if ours else {}
            levels = " → ".join(f"{lv['mesh'][0]}×{lv['mesh'][1]} @ {lv['resolution'][0]}×{lv['resolution'][1]}"
                                for lv in model.get("levels", []))
            grid = (ours[0]["start"].get("transport") or {}).get("grid") if ours else None
            rows.append([case, c.title, f"{self.budget(case):g} s", levels or "–",
                         f"{grid[0]}×{grid[1]}" if grid else "–"])
        return table(["case", "what", "budget B", "ours' levels (mesh @ receiver)", "transport grid"], rows)


# ------------------------------------------------------------------------------ writing

def write_data(st: Study) -> None:
    with open(st.out_dir / "runs.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["case", "method", "purpose", "budget_s", "seed", "threads", "error_physical", "energy_physical",
                    "error_fitted", "error_exported", "physical_rays_per_cell", "seconds", "iterations",
                    "evaluations_per_s", "heights_fingerprint"])
        for r in st.runs:
            w.writerow([r["case"], r["method"], r["purpose"], r["budget"], r["seed"], r["threads"], r["phys"],
                        r["energy"], r["fitted"], r["exported"], r["rpc"], r["seconds"], r["iterations"], r["eps"],
                        r["fingerprint"]])
    groups = {}
    for (c, m, p, b), rs in sorted(st.groups.items()):
        groups[f"{c}/{m}/{p}/{b:g}"] = spread([r["phys"] for r in rs]) | {
            "energy_median": med([r["energy"] for r in rs]), "seconds": med([r["seconds"] for r in rs])}
    (st.out_dir / "summary.json").write_text(json.dumps({"meta": st.meta, "groups": groups}, indent=1,
                                                        default=str) + "\n")


def header(st: Study) -> list[str]:
    meta, quick = st.meta, st.quick
    md = [f"# freeform speed/accuracy study — {'QUICK' if quick else 'FULL'} run", ""]
    if quick:
        md += ["> **A QUICK run** (`make bench QUICK=1`): two cases, short budgets, two seeds. It shows that the "
               "pipeline works end to end; its numbers are not the study's results (`benchmarks/results/REPORT.md`).",
               ""]
    planned = plan.quick_plan() if quick else plan.full_plan()
    on_disk = {(r["case"], r["method"], r["budget"], r["seed"]) for r in st.runs}
    missing = [r for r in planned if (r.case, r.method, r.budget, r.seed) not in on_disk]
    if missing:
        md += [f"> **Incomplete**: {len(missing)} of the {len(planned)} planned runs are not on disk (first missing: "
               f"`{missing[0].key}`). Statistics cover the runs that exist.", ""]
    passes = meta.get("passes") or []
    owned = defaultdict(int)  # runs on disk per pass (1-based, as run_study.py numbers them)
    for r in st.runs:
        owned[r["pass"]] += 1
    live = [(i + 1, p) for i, p in enumerate(passes) if owned.get(i + 1)]
    rows = [
        ["date", f"{(live[0][1].get('started') if live else None) or meta.get('started', '?')} → "
                 f"{meta.get('finished') or 'stopped part-way'}"],
        ["machine", f"{meta.get('cpu')}, {meta.get('cores')} cores, {meta.get('memory_gb')} GB, {meta.get('os')}"],
        ["threads per run", str(meta.get("threads"))],
        ["runs", f"{len(st.runs)} on disk of {len(planned)} planned, {len(meta.get('runs_failed', []))} failed"],
    ]
    for n, p in live:
        minutes = f"{p['wall_seconds'] / 60:.1f} min, " if p.get("wall_seconds") else ""
        rows.append([f"pass {n}", f"{p.get('finished') or '?'}: {owned[n]} of its {p.get('runs_done') or 0} runs "
                     f"on disk, {minutes}commit `{(p.get('commit') or '?')[:10]}`"
                     + dirt(p) + f", `{p.get('command', '')}`"])
    rows.append(["build", same_build([p.get("commit") for _, p in live])])
    md += [table(["", ""], rows), ""]
    return md


def dirt(p: dict) -> str:
    """What a pass's uncommitted changes were, as far as it recorded."""
    if not p.get("dirty"):
        return ""
    compiled = p.get("dirty_compiled")
    if compiled is None:
        return " (with uncommitted changes; which files, not recorded)"
    return " (with uncommitted changes to **compiled sources**)" if compiled else \
        " (with uncommitted changes to scripts or documents only)"


def same_build(commits: list) -> str:
    """Whether the passes' commits differ in what study_run is compiled from (asks git)."""
    commits = list(dict.fromkeys(c for c in commits if c))
    if len(commits) < 2:
        return "one pass, one build"
    root = Path(__file__).resolve().parents[2]
    try:
        changed = [c for c in commits[1:] if subprocess.run(
            ["git", "diff", "--quiet", commits[0], c, "--", *plan.COMPILED_SOURCES], cwd=root).returncode != 0]
    except OSError:
        return "not checked (no git)"
    if changed:
        return "**the compiled sources differ** between passes: " + ", ".join(f"`{c[:10]}`" for c in changed)
    return (f"every pass built from the same sources ({', '.join(f'`{c[:10]}`' for c in commits)} differ only "
            f"in scripts and documents: `git diff --quiet` over {', '.join(plan.COMPILED_SOURCES[:6])})")


def build(out_dir: Path, meta: dict, quick: bool) -> Path:
    st = Study(out_dir, meta, quick)
    write_data(st)
    overview, traces, stab, ours_time = st.fig_overview(), st.fig_traces(), st.fig_stability(), st.fig_ours_time()
    md = header(st)
    md += ["Every error in this report is **error_physical** (docs/measures.md): the design's exported mesh traced as "
           "flat triangles, each ray deposited in the receiver cell it lands in, at the receiver's resolution, with "
           "rays enough that doubling them changes the error by less than 0.001 — what a camera or light meter with "
           "the receiver's pixels records. Error is Σ|R − T| / 2N (0 identical, 1 disjoint), energy the share of the "
           "light on the receiver. Each run optimises with its own seed (101…) and is judged with the case's seed; "
           "runs are sequential, each on the threads above, every method of a case with the same wall-clock budget. "
           "Methods: [benchmarks/study/README.md](../study/README.md).", ""]
    md += ["## At a glance", "", "Median error_physical at the case's budget B (ours and the transport start over 10 "
           "and 3 seeds, the baselines over 2 in the full run); lowest in bold. The reference's figures are its own "
           "measure (fitted, on a GPU, minutes), quoted for scale, not compared.", "", st.glance(), ""]
    if overview:
        md += [f"![error_physical against time]({overview})", ""]
    md += ["## Verdict", ""] + st.verdict() + [""]
    md += ["### Issue 22's goals", "", st.goals_section(), "", "### Error against time", "", st.time_section(), ""]
    if ours_time:
        md += [f"![ours against time]({ours_time})", ""]
    md += ["## Stability over seeds", "", "Ours on 10 seeds at the case's budget B (a clock decides when it stops, "
           "so a loaded machine gives fewer iterations) and at a fixed iteration count (the median of those runs' "
           "iterations; no clock decides anything), and seed 101 repeated at that count.", "",
           st.stability_section(), ""]
    if stab:
        md += [f"![stability]({stab})", ""]
    md += ["## Where methods fail, and why", "", st.failure_section(), "", "### Cases made to fail", "",
           "Ours, the start alone and plain SA, 2 seeds each: error_physical / energy (medians).", "",
           st.stress_section(), ""]
    md += ["## The optimisers' kind of figure against what a camera sees", "", "Median at B: the design's surface "
           "model (Phong patches) rendered the way the optimisers of issue 22's time judged (bilinear deposit, the "
           "case's 16 rays per receiver cell, the case's seed), its exported mesh rendered the same way, and "
           "error_physical. A ratio far above 1 would mean the design fills the scales the bilinear deposit cannot "
           "see (before issue 22: 2–4×).", "", st.fitted_section(), ""]
    if traces:
        md += [f"![optimiser traces]({traces})", ""]
    md += ["## Speed", "", st.speed_section(), "", "## Cases", "", st.cases_section(), "",
           "## Methods", "", table(["method", "what"], [[m, plan.METHODS[m].title] for m in plan.MAIN_METHODS
                                                        + list(plan.ITERATION_METHODS)]), ""]
    md += ["## Reproduce", "", "```", "make bench            # micro-benchmarks, then this study (resumes from the runs "
           "on disk)", "make bench STUDY_ARGS=--fresh   # every run again",
           "/usr/bin/python3 benchmarks/study/run_study.py --report-only   # this report from the runs on disk",
           "```", ""]
    path = out_dir / "REPORT.md"
    path.write_text("\n".join(md))
    return path

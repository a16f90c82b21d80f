#!/usr/bin/env python3
"""The speed/accuracy study of freeform: runs study_run over cases x methods x seeds,
then aggregates, plots and writes REPORT.md (see benchmarks/study/README.md).

  run_study.py --quick          a few minutes: E and headlight, ours and the baselines, 2 seeds,
                                short budgets -> benchmarks/results/quick/
  run_study.py                  the full study (about 1 h 50 min on 2 cores) -> benchmarks/results/
  run_study.py --report-only    re-aggregate the runs already on disk

Runs are sequential (each with --threads, recorded) and resumable: a run whose result file
exists with the same configuration is not repeated (--fresh repeats everything). Each run's
result is OUT/runs/<case>/<method>/b<B>-s<S>.json.gz (study_run's JSON with a "study" block,
gzip-compressed, the same bytes for the same result: run_files.py); plain .json runs of an
earlier checkout are read and reused as well.
Use /usr/bin/python3 (Debian's matplotlib).
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.dont_write_bytecode = True  # keep the source tree free of __pycache__
HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))

import run_files  # noqa: E402
import study_plan as plan  # noqa: E402

# Seconds per run on top of its budget (start-up, target rendering, the final renders and
# error_physical), measured on the 2-core development machine; the camera case traces 512
# rays per cell for error_physical, and under grazing light our designer overshoots its budget
# (each full trace of the incremental index takes seconds there: docs/performance.md, "The
# speed/accuracy study").
OVERHEAD = {"camera": 10.0, "grazing": 14.0, "headlight": 3.0}
DEFAULT_OVERHEAD = 8.0


def machine_info(threads: int) -> dict:
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem_gb = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                mem_gb = round(int(line.split()[1]) / 1024 / 1024, 1)
    except OSError:
        pass

    def git(*args):
        try:
            return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()
        except (OSError, subprocess.CalledProcessError):
            return ""

    commit = git("rev-parse", "HEAD")
    # The study's own results are tracked and rewritten while it runs: they do not make the code dirty.
    dirty = bool(git("status", "--porcelain", "--untracked-files=no", "--", ".", ":!benchmarks/results"))
    # ... and whether those changes reach the binary (or only scripts and documents).
    dirty_compiled = bool(git("status", "--porcelain", "--untracked-files=no", "--", *plan.COMPILED_SOURCES))
    load = None
    try:
        load = os.getloadavg()
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "memory_gb": mem_gb, "os": platform.platform(),
            "python": platform.python_version(), "commit": commit or "unknown", "dirty": dirty,
            "dirty_compiled": dirty_compiled, "threads": threads, "load_at_start": load}


def run_command(binary: Path, run: plan.Run, threads: int, out_file: Path, image_prefix: Path | None) -> list[str]:
    case, method = plan.CASES[run.case], plan.METHODS[run.method]
    cmd = [str(binary), "--scene", str(ROOT / case.scene), "--engine", method.engine, "--label", method.name,
           "--seed", str(run.seed), "--time-budget", f"{run.budget:g}", "--threads", str(threads),
           "--out", str(out_file)]
    if case.case_patch:
        cmd += ["--case-patch", json.dumps(case.case_patch, separators=(",", ":"))]
    patch = method.patch_for(run.case)
    if patch:
        cmd += ["--patch", json.dumps(patch, separators=(",", ":"))]
    cmd += list(method.options)
    if image_prefix is not None:
        cmd += ["--save-images", str(image_prefix)]
    return cmd


def config_of(cmd: list[str]) -> list[str]:
    # What identifies a run's configuration: the command without the paths of this checkout.
    out, skip = [], False
    for a in cmd[1:]:
        if skip:
            skip = False
            continue
        if a in ("--out", "--save-images"):
            skip = True
            continue
        out.append(a.replace(str(ROOT) + "/", ""))
    return out


PASS_KEYS = ("started", "finished", "commit", "dirty", "dirty_compiled", "command", "wall_seconds", "runs_done", "runs_reused")


def estimate(runs: list[plan.Run]) -> float:
    return sum(plan.expected_seconds(r) + OVERHEAD.get(r.case, DEFAULT_OVERHEAD) for r in runs)


def median_iterations(out_dir: Path, case: str) -> int | None:
    """The median iterations of ours' runs at the case's budget on disk (purpose main)."""
    its = []
    for f in run_files.files(out_dir / "runs" / case / "ours", recursive=False):
        try:
            res = run_files.read(f)
        except (OSError, ValueError):
            continue
        if res.get("study", {}).get("purpose") == "main" and "iterations" in res:
            its.append(int(res["iterations"]))
    return int(statistics.median(its)) if its else None


def fmt_duration(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}h{(s % 3600) // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="the quick subset (about 7 minutes)")
    ap.add_argument("--bin", type=Path, default=ROOT / "build/release/bin", help="where study_run is")
    ap.add_argument("--out", type=Path, help="results directory (default benchmarks/results[/quick])")
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1, help="threads per run (default: all cores)")
    ap.add_argument("--cases", help="comma-separated subset of cases")
    ap.add_argument("--methods", help="comma-separated subset of methods")
    ap.add_argument("--purposes", help="comma-separated subset of purposes (main, ladder, stability, stress; "
                    "quick mode: quick)")
    ap.add_argument("--seeds", type=int, help="at most this many seeds per group (a cheaper, less certain study)")
    ap.add_argument("--fresh", action="store_true", help="repeat runs whose results exist")
    ap.add_argument("--report-only", action="store_true", help="only aggregate the runs on disk")
    ap.add_argument("--dry-run", action="store_true", help="print the plan and its estimated duration")
    ap.add_argument("--fixed-iterations", help="CASE=N,... iteration caps of the stability methods (default: the "
                    "median iterations of ours' main runs of the case on disk)")
    args = ap.parse_args()

    for item in (args.fixed_iterations or "").split(","):
        if item:
            case, _, n = item.partition("=")
            if case not in plan.CASES or not n.isdigit():
                ap.error(f"--fixed-iterations: expected CASE=N with CASE one of {sorted(plan.CASES)}, got {item!r}")
            plan.FIXED_ITERATIONS[case] = int(n)  # the methods hold this dict: they see the change

    mode = "quick" if args.quick else "full"
    out_dir = args.out or (ROOT / "benchmarks/results" / ("quick" if args.quick else ""))
    out_dir = out_dir.resolve()
    runs = plan.quick_plan() if args.quick else plan.full_plan()
    if args.cases:
        keep = set(args.cases.split(","))
        runs = [r for r in runs if r.case in keep]
    if args.methods:
        keep = set(args.methods.split(","))
        runs = [r for r in runs if r.method in keep]
    if args.seeds:
        keep = set(plan.SEEDS[:args.seeds])
        runs = [r for r in runs if r.seed in keep]
    if args.purposes:
        keep = set(args.purposes.split(","))
        runs = [r for r in runs if r.purpose in keep]

    print(f"study ({mode}): {len(runs)} runs, estimated {fmt_duration(estimate(runs))} on 2 cores "
          f"-> {out_dir.relative_to(ROOT) if out_dir.is_relative_to(ROOT) else out_dir}", flush=True)
    if args.dry_run:
        by_purpose = {}
        for r in runs:
            by_purpose.setdefault(r.purpose, []).append(r)
        for p, rs in by_purpose.items():
            print(f"  {p:9s} {len(rs):4d} runs  {fmt_duration(estimate(rs))}")
        return 0

    binary = args.bin / "study_run"
    meta_file = out_dir / "study.json"
    if not args.report_only:
        if not binary.exists():
            print(f"run_study.py: {binary} not found; build it first (make build, or cmake --build with "
                  f"FREEFORM_BUILD_BENCHMARKS=ON) or pass --bin", file=sys.stderr)
            return 1
        out_dir.mkdir(parents=True, exist_ok=True)
        meta = machine_info(args.threads)
        meta.update({"mode": mode, "started": dt.datetime.now().astimezone().isoformat(timespec="seconds"),
                     "finished": None, "command": " ".join(shlex.quote(a) for a in [sys.executable, *sys.argv]),
                     "planned_runs": len(runs), "estimated_seconds": estimate(runs)})
        # A study is often run in several passes (resumed, more seeds, some methods repeated with
        # --fresh): keep what each earlier pass did; the report lists those that still own runs.
        passes = []
        if meta_file.exists():
            try:
                old = json.loads(meta_file.read_text())
                passes = old.get("passes") or [{k: old.get(k) for k in PASS_KEYS}]
            except (OSError, json.JSONDecodeError):
                pass
        start = time.monotonic()
        unavailable: dict[str, str] = {}
        failed: list[dict] = []
        done = skipped = 0

        def save_meta(finished: bool) -> None:
            # Written after every run, so that a study stopped part-way still says what it did.
            now = dt.datetime.now().astimezone().isoformat(timespec="seconds")
            meta.update({"finished": now if finished else None, "wall_seconds": time.monotonic() - start,
                         "runs_done": done, "runs_reused": skipped, "runs_failed": failed,
                         "engines_unavailable": unavailable})
            this = {k: meta.get(k) for k in PASS_KEYS} | {"finished": now, "interrupted": not finished}
            meta["passes"] = passes + [this]
            meta_file.write_text(json.dumps(meta, indent=1) + "\n")
        runs_dir = out_dir / "runs"
        for k, r in enumerate(runs):
            method = plan.METHODS[r.method]
            # study_run writes plain JSON to a temporary file beside the result (*.tmp: ignored by
            # git and by the readers); what is kept is the .json.gz that run_files.write makes of it.
            out_file = runs_dir / (r.key + ".json.tmp")
            image_prefix = out_dir / "images" / f"{r.case}-{r.method}" if r.save_images else None
            if method.engine in unavailable:
                continue
            if r.method in plan.ITERATION_METHODS and r.case not in plan.FIXED_ITERATIONS:
                n = median_iterations(out_dir, r.case)
                if n is None:
                    failed.append({"run": r.key, "why": "no main runs of ours to take the iteration count from"})
                    print(f"  {r.key}: no main runs of ours on disk, skipped", flush=True)
                    continue
                plan.FIXED_ITERATIONS[r.case] = n
                print(f"  {r.case}: fixed iteration count {n} (median of ours' main runs)", flush=True)
            cmd = run_command(binary, r, args.threads, out_file, image_prefix)
            cfg = config_of(cmd)
            stored = run_files.existing(runs_dir, r.key)
            if stored is not None and not args.fresh:
                try:
                    old = run_files.read(stored)
                    if old.get("study", {}).get("config") == cfg and (image_prefix is None or Path(
                            str(image_prefix) + "-irradiance.pfm").exists()):
                        skipped += 1
                        continue
                except (OSError, ValueError):
                    pass
            elapsed = time.monotonic() - start
            left = estimate(runs[k:])
            print(f"[{k + 1}/{len(runs)} {fmt_duration(elapsed)} elapsed, ~{fmt_duration(left)} left] {r.key}",
                  flush=True)
            timeout = 3 * plan.expected_seconds(r) + 180
            out_file.unlink(missing_ok=True)
            try:
                p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout)
            except subprocess.TimeoutExpired:
                out_file.unlink(missing_ok=True)
                failed.append({"run": r.key, "why": f"timed out after {timeout:.0f} s"})
                print(f"  timed out after {timeout:.0f} s", flush=True)
                continue
            if p.returncode != 0:
                out_file.unlink(missing_ok=True)
            if p.returncode == 3:
                unavailable[method.engine] = p.stderr.strip()
                print(f"  {method.engine} not available: {p.stderr.strip()}", flush=True)
                continue
            if p.returncode != 0:
                failed.append({"run": r.key, "why": f"exit {p.returncode}: {p.stderr.strip()[-500:]}"})
                print(f"  failed (exit {p.returncode}): {p.stderr.strip()[-300:]}", flush=True)
                continue
            print("  " + p.stdout.strip().splitlines()[-1], flush=True)
            res = json.loads(out_file.read_text())
            res["study"] = {"case": r.case, "method": r.method, "purpose": r.purpose, "budget": r.budget,
                            "seed": r.seed, "config": cfg, "pass": len(passes) + 1,
                            "finished": dt.datetime.now().astimezone().isoformat(timespec="seconds")}
            run_files.write(runs_dir, r.key, res)
            out_file.unlink()
            done += 1
            save_meta(False)
        save_meta(True)
        print(f"study runs finished in {fmt_duration(meta['wall_seconds'])}: {done} run, {skipped} reused, "
              f"{len(failed)} failed", flush=True)

    if not meta_file.exists():
        print(f"run_study.py: no study in {out_dir} (run it first)", file=sys.stderr)
        return 1
    import study_report  # matplotlib is needed only from here on

    report = study_report.build(out_dir, json.loads(meta_file.read_text()), quick=(mode == "quick"))
    print(f"report: {report}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

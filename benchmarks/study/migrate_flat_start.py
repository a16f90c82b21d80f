#!/usr/bin/env python3
"""One-off migration of the committed study runs to the plan of the transport start (issue 9).

Every run committed before commit 66d6687 that went through freeform::design() started from
a flat surface, the default then. The transport start is now the default, so study_plan.py
gives those methods the patch {"surface": {"initial": "flat"}} (FLAT_START), names the former
"ours" "ours-flat-start", and names the lens case of those runs "lens-5mm" (the example's
bounds were widened from +-5 mm to +-12 mm and its thickness from 1 to 1.5 cm in 33929ba;
"lens-5mm" is the example with the former values as a case patch).

run_study.py reuses a committed run only when its recorded configuration (the study_run
command line without paths: label, patch, case patch, ...) equals the one the plan makes
now. This script rewrites, for each such run:
  - study.case / study.method and the file's place (runs/<case>/<method>/...),
  - study.config: the command the plan makes now,
and keeps the configuration it was made with in study.migrated (with the reason). It
checks, run by run, that the new command differs from the recorded one only by the label,
the flat-start patch and the lens case patch (anything else stops the script), so that
re-running a migrated run would make the same run: a flat-start patch reproduces the old
default bit for bit (checked on headlight/ours-fixed seed 101: same heights fingerprint).
The result files' own fields (label, patch, case_patch as study_run wrote them) are kept as
they were written. Images (PFM, untracked) are not moved: a first-seed run whose image is
missing is run again by run_study.py anyway.

  /usr/bin/python3 benchmarks/study/migrate_flat_start.py [--dry-run] [--out benchmarks/results]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.dont_write_bytecode = True
HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))

import run_study  # noqa: E402
import study_plan as plan  # noqa: E402

RENAME_METHOD = {"ours": "ours-flat-start"}
RENAME_CASE = {"lens": "lens-5mm"}
WHY = ("made with the flat start (the default before 66d6687); method 'ours' renamed 'ours-flat-start', case 'lens' "
       "(the example's former +-5 mm bounds, 1 cm thickness) renamed 'lens-5mm'; config rewritten to the command the "
       "plan makes now (flat-start patch, label, lens case patch), which makes the same run")


def pairs_removed(cfg: list[str], option: str) -> list[str]:
    out, k = [], 0
    while k < len(cfg):
        if cfg[k] == option:
            k += 2
            continue
        out.append(cfg[k])
        k += 1
    return out


def without_flat(cfg: list[str]) -> list[str]:
    """The configuration with the flat-start part of --patch taken out (what it was before)."""
    out = list(cfg)
    if "--patch" not in out:
        return out
    k = out.index("--patch")
    patch = json.loads(out[k + 1])
    surface = patch.get("surface", {})
    if surface.get("initial") != "flat":
        return out
    del surface["initial"]
    if not surface:
        del patch["surface"]
    if patch:
        out[k + 1] = json.dumps(patch, separators=(",", ":"))
    else:
        del out[k:k + 2]
    return out


def migrate(out_dir: Path, runs: list[plan.Run], dry: bool) -> int:
    by_key = {r.key: r for r in runs}
    moved = rewritten = untouched = 0
    for f in sorted((out_dir / "runs").rglob("*.json")):
        res = json.loads(f.read_text())
        s = res.get("study")
        if not s or "migrated" in s:
            untouched += 1
            continue
        case, method = s["case"], s["method"]
        if plan.METHODS.get(RENAME_METHOD.get(method, method), plan.METHODS["spsa"]).engine != "design" and \
                case not in RENAME_CASE:
            untouched += 1
            continue
        new_case, new_method = RENAME_CASE.get(case, case), RENAME_METHOD.get(method, method)
        key = f"{new_case}/{new_method}/b{float(s['budget']):g}-s{s['seed']}"
        run = by_key.get(key)
        if run is None:
            raise SystemExit(f"{f}: {key} is not in the plan")
        old_cfg = s["config"]
        threads = int(old_cfg[old_cfg.index("--threads") + 1])
        prefix = Path("images") / f"{run.case}-{run.method}" if run.save_images else None
        cmd = run_study.run_command(Path("bin/study_run"), run, threads, Path("out.json"), prefix)
        new_cfg = run_study.config_of(cmd)
        # The new command, with the label, the flat-start patch and the lens case patch taken
        # back out, must be exactly the recorded one.
        back = without_flat(new_cfg)
        back[back.index("--label") + 1] = method
        if case in RENAME_CASE:
            back = pairs_removed(back, "--case-patch")
        if back != old_cfg:
            raise SystemExit(f"{f}: the plan's command differs by more than the migration:\n  old {old_cfg}\n  new "
                             f"{new_cfg}")
        if new_cfg == old_cfg:
            untouched += 1
            continue
        s["migrated"] = {"from_case": case, "from_method": method, "config": old_cfg, "why": WHY}
        s["case"], s["method"], s["config"] = new_case, new_method, new_cfg
        dest = out_dir / "runs" / (key + ".json")
        if not dry:
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_text(json.dumps(res, indent=1) + "\n")
            if dest != f:
                f.unlink()
        moved += dest != f
        rewritten += 1
    print(f"{out_dir}: {rewritten} runs rewritten ({moved} moved), {untouched} unchanged" + (" (dry run)" if dry else ""))
    for d in sorted((out_dir / "runs").rglob("*"), reverse=True):
        if d.is_dir() and not any(d.iterdir()) and not dry:
            d.rmdir()
    return rewritten


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results")
    ap.add_argument("--quick", action="store_true", help="the quick study's runs (benchmarks/results/quick)")
    ap.add_argument("--dry-run", action="store_true")
    args = ap.parse_args()
    migrate(args.out.resolve(), plan.quick_plan() if args.quick else plan.full_plan(), args.dry_run)
    return 0


if __name__ == "__main__":
    sys.exit(main())

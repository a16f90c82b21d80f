#!/usr/bin/env python3
"""Spread of error_physical over seeds (issue 22, part 3): one scene designed with seeds
1..N at a fixed time budget (`freeform design SCENE --time-budget T --seed S`), and at a
fixed iteration count (the median iterations of the timed runs, `optimise.max_iterations`,
so the result depends on the seed alone). The figure is error_physical, the cell-mean
error of the exported mesh (docs/measures.md).

  physical_stability.py [--bin build/release/bin/freeform] [--scene examples/scenes/letter-e.json]
                        [--budget 20] [--seeds 10] [--out benchmarks/results/physical_stability]

Runs are sequential (2 threads each) and resumable (runs/<mode>-s<S>.json); table.md is
rewritten at the end. Use /usr/bin/python3.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.dont_write_bytecode = True
ROOT = Path(__file__).resolve().parents[2]


def design(binary: str, scene: Path, seed: int, budget: float, iterations: int, threads: int) -> dict:
    """One design; returns the figures that matter from its metrics.json."""
    with tempfile.TemporaryDirectory() as tmp:
        run_scene = scene
        if iterations > 0:
            text = json.loads(_strip_comments(scene.read_text()))
            text.setdefault("optimise", {})["max_iterations"] = iterations
            run_scene = Path(tmp) / scene.name
            # Relative paths in the scene (target images) stay relative to the original.
            for block in text.values():
                if isinstance(block, dict) and isinstance(block.get("image"), str):
                    block["image"] = str((scene.parent / block["image"]).resolve())
            run_scene.write_text(json.dumps(text))
        out = Path(tmp) / "out"
        cmd = [binary, "design", str(run_scene), "--out", str(out), "--seed", str(seed), "--threads", str(threads),
               "--quiet", "--time-budget", str(budget if iterations == 0 else 100000)]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        m = json.loads((out / "metrics.json").read_text())
    return {"seed": seed, "error_physical": m["error_physical"], "error": m["error"],
            "iterations": m["iterations"], "seconds": m["seconds"]}


def _strip_comments(text: str) -> str:
    return "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("//"))


def summary(rows: list[dict]) -> str:
    e = sorted(r["error_physical"] for r in rows)
    med = statistics.median(e)
    spread = (e[-1] - e[0]) / med if med > 0 else 0.0
    return (f"{len(e)} | {med:.4f} | {e[0]:.4f} – {e[-1]:.4f} | {100 * spread:.1f} % | "
            f"{statistics.pstdev(e) / med * 100:.1f} % | {statistics.median(r['iterations'] for r in rows):,.0f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=str(ROOT / "build/release/bin/freeform"))
    ap.add_argument("--scene", default=str(ROOT / "examples/scenes/letter-e.json"))
    ap.add_argument("--budget", type=float, default=20)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/physical_stability"))
    a = ap.parse_args()
    scene, out = Path(a.scene), Path(a.out)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    results: dict[str, list[dict]] = {"time": [], "iterations": []}
    for mode in ("time", "iterations"):
        fixed = 0
        if mode == "iterations":
            fixed = int(statistics.median(r["iterations"] for r in results["time"]))
        for seed in range(1, a.seeds + 1):
            f = out / "runs" / f"{mode}-s{seed}.json"
            if f.exists():
                results[mode].append(json.loads(f.read_text()))
                continue
            r = design(a.bin, scene, seed, a.budget, fixed, a.threads)
            f.write_text(json.dumps(r, indent=1) + "\n")
            results[mode].append(r)
            print(f"{mode} seed {seed}: error_physical {r['error_physical']:.4f} ({r['iterations']} iterations)",
                  flush=True)
    lines = [f"# error_physical over seeds: {scene.name}", "",
             f"`/usr/bin/python3 benchmarks/study/physical_stability.py --scene {scene.relative_to(ROOT)} "
             f"--budget {a.budget:g} --seeds {a.seeds}` ({a.threads} threads per run, one run at a time).", "",
             "| runs | seeds | median | range | range / median | std / median | median iterations |",
             "|---|---:|---:|---:|---:|---:|---:|",
             f"| time budget {a.budget:g} s | " + summary(results["time"]) + " |",
             f"| fixed iterations | " + summary(results["iterations"]) + " |", ""]
    (out / "table.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())

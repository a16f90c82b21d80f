#!/usr/bin/env python3
"""error_physical against time budget (issue 22): every example scene, and targets that are
not examples, designed with `freeform design SCENE --time-budget T` under variants of the
defaults; the figure judged is error_physical, the cell-mean error of the exported mesh
(docs/measures.md).

  physical_study.py [--bin build/release/bin/freeform] [--out benchmarks/results/physical]
                    [--variants old,new] [--cases E,camera,...] [--seed 1] [--plot-only]

Variants are scene patches applied on top of each case:
  new      today's defaults (fine_bilinear deposit, export facets within 0.05 cells and 2M
           triangles, a mesh that follows the receiver, 32 rays per mesh cell at least)
  old      the defaults before issue 22: bilinear deposit, export tolerance 0.25 cells, no
           ray floor, photographs on a 401² mesh
  floor64  today's defaults with 64 rays per mesh cell at least (instead of 32)
  r16      today's defaults without the ray floor (16 rays per receiver cell)
  mesh-2r  r16 with a 401² mesh (photographs' former rule)
  prev     today's defaults as an earlier checkout has them: its binary (--prev-bin) and its
           example scenes (--prev-root), run interleaved with `new` at every point

Runs are sequential (2 threads each, the machine's cores), resumable (a run whose JSON exists
is not repeated) and write runs/<case>/<variant>-t<T>.json with the metrics that matter.
Then runs.csv, the chart error_physical_vs_time.png and table.md are (re)written.
Use /usr/bin/python3 (Debian's matplotlib, numpy).
"""
from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.dont_write_bytecode = True
HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
TARGETS = HERE / "targets"

VARIANTS = {
    "new": {},
    # Before issue 22; photographs (the cases in PHOTOS) also had a 401² mesh then.
    "old": {"receiver": {"deposit": "bilinear"},
            "optimise": {"export_tolerance": 0.25, "export_max_triangles": 100_000_000,
                         "min_rays_per_mesh_cell": 0}},
    # The ray floor at 64 rays per mesh cell instead of 32.
    "floor64": {"optimise": {"min_rays_per_mesh_cell": 64}},
    # Today's defaults without the ray floor (the light's 16 rays per receiver cell).
    "r16": {"optimise": {"min_rays_per_mesh_cell": 0}},
    # ... and with the photographs' former 401² mesh.
    "mesh-2r": {"surface": {"mesh": [401, 401]}, "optimise": {"min_rays_per_mesh_cell": 0}},
    # An earlier checkout's defaults: its binary and scenes (--prev-bin, --prev-root).
    "prev": {},
}
PREV = {"bin": None, "root": None}  # set from the command line
PHOTOS = {"camera", "gradient"}  # "auto" mesh, photographic targets on a 200² receiver

# name: (scene, patch, budgets in seconds, example?)
CASES = {
    "E": ("examples/scenes/letter-e.json", {}, [10, 20, 40], True),
    "V": ("examples/scenes/letter-v.json", {}, [10, 20, 40], True),
    "at": ("examples/scenes/letter-at.json", {}, [10, 20, 40], True),
    "headlight": ("examples/scenes/headlight.json", {}, [5, 10, 20], True),
    "point": ("examples/scenes/point-light.json", {}, [10, 20, 40], True),
    "lens": ("examples/scenes/lens.json", {}, [10, 20, 40], True),
    "camera": ("examples/scenes/camera.json", {}, [15, 30, 60], True),
    # Not examples: a letter on the E's setup, the study's smooth grey landscape on the
    # camera's, and a synthetic photograph through the lens (make_targets.py draws both).
    "R": ("examples/scenes/letter-e.json", {"target": {"text": "R"}}, [10, 20, 40], False),
    "gradient": ("examples/scenes/camera.json", {"target": {"image": str(TARGETS / "gradient.png")}},
                 [15, 30, 60], False),
    "photo-lens": ("examples/scenes/lens.json", {"target": {"image": str(TARGETS / "street.png")}},
                   [15, 30, 60], False),
}


def merge(base: dict, patch: dict) -> dict:
    out = dict(base)
    for k, v in patch.items():
        out[k] = merge(out.get(k, {}), v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def scene_for(case: str, variant: str) -> dict:
    path, patch, _, _ = CASES[case]
    root = Path(PREV["root"]) if variant == "prev" else ROOT
    scene = json.loads((root / path).read_text())
    target = scene.get("target", {})
    if "image" in target and not Path(target["image"]).is_absolute():
        target["image"] = str((root / path).parent / target["image"])
    if "text" in patch.get("target", {}) or "image" in patch.get("target", {}):
        scene["target"] = {k: v for k, v in target.items() if k in ("font", "margin")} if "text" in patch["target"] else {}
    scene = merge(merge(scene, patch), VARIANTS[variant])
    if variant == "old" and case in PHOTOS:
        scene = merge(scene, {"surface": {"mesh": [401, 401]}})
    return scene


def run_one(binary: Path, case: str, variant: str, budget: float, seed: int, out_dir: Path) -> dict:
    result_file = out_dir / "runs" / case / f"{variant}-t{budget:g}-s{seed}.json"
    if result_file.exists():
        return json.loads(result_file.read_text())
    with tempfile.TemporaryDirectory() as tmp:
        scene_file = Path(tmp) / "scene.json"
        scene_file.write_text(json.dumps(scene_for(case, variant)))
        design_dir = Path(tmp) / "design"
        t0 = time.monotonic()
        cmd = [str(binary), "design", str(scene_file), "--out", str(design_dir), "--time-budget", f"{budget:g}",
               "--seed", str(seed), "--threads", "2", "--quiet"]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.monotonic() - t0
        if proc.returncode != 0:
            raise SystemExit(f"{case}/{variant}/{budget}: exit {proc.returncode}\n{proc.stderr}")
        m = json.loads((design_dir / "metrics.json").read_text())
    row = {"case": case, "variant": variant, "budget": budget, "seed": seed, "wall_seconds": wall,
           "example": CASES[case][3],
           "error_physical": m.get("error_physical"), "energy_physical": m.get("energy_physical"),
           "error": m["error"], "error_held_out": m.get("error_held_out"), "error_exported": m.get("error_exported"),
           "start_error": m["start"].get("error"), "iterations": m["iterations"], "seconds": m["seconds"],
           "mesh": m["mesh"], "export_subdivisions": m["export"]["subdivisions"],
           "triangles": m["export"]["triangles"], "cell_means": m.get("cell_means")}
    result_file.parent.mkdir(parents=True, exist_ok=True)
    result_file.write_text(json.dumps(row, indent=1) + "\n")
    return row


def write_outputs(rows: list[dict], out_dir: Path) -> None:
    keys = ["case", "variant", "budget", "seed", "example", "error_physical", "error", "error_held_out",
            "error_exported", "start_error", "iterations", "seconds", "wall_seconds", "export_subdivisions", "triangles"]
    with open(out_dir / "runs.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        for r in sorted(rows, key=lambda r: (r["case"], r["variant"], r["budget"])):
            w.writerow(r)
    cases = [c for c in CASES if any(r["case"] == c for r in rows)]
    variants = [v for v in VARIANTS if any(r["variant"] == v for r in rows)]
    lines = ["| case | example | budget s | " + " | ".join(f"{v}: error_physical" for v in variants) +
             " | new: fitted error | new: triangles |", "|---|---|---:|" + "---:|" * (len(variants) + 2)]
    for c in cases:
        for b in CASES[c][2]:
            got = {r["variant"]: r for r in rows if r["case"] == c and r["budget"] == b}
            if not got:
                continue
            cells = [f"{got[v]['error_physical']:.4f}" if v in got else "—" for v in variants]
            new = got.get("new")
            lines.append(f"| {c} | {'yes' if CASES[c][3] else 'no'} | {b:g} | " + " | ".join(cells) +
                         (f" | {new['error']:.4f} | {new['triangles']:,} |" if new else " | — | — |"))
    (out_dir / "table.md").write_text("\n".join(lines) + "\n")
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib missing: no chart (use /usr/bin/python3)")
        return
    n = len(cases)
    cols = min(5, n)
    rows_n = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows_n, cols, figsize=(3.2 * cols, 2.8 * rows_n), squeeze=False)
    style = {"new": ("tab:blue", "o", "-"), "old": ("tab:gray", "s", "--"), "r16": ("tab:green", "^", ":"), "floor64": ("tab:purple", "D", "-."),
             "mesh-2r": ("tab:orange", "v", ":")}
    for ax, c in zip(axes.flat, cases):
        for v in variants:
            pts = sorted((r["budget"], r["error_physical"]) for r in rows if r["case"] == c and r["variant"] == v)
            if pts:
                col, mk, ls = style.get(v, ("k", "x", ":"))
                ax.plot([p[0] for p in pts], [p[1] for p in pts], color=col, marker=mk, linestyle=ls, label=v)
        ax.set_title(c + ("" if CASES[c][3] else " (not an example)"), fontsize=9)
        ax.set_xlabel("time budget (s)", fontsize=8)
        ax.set_ylabel("error_physical", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    labels = {}
    for ax in axes.flat:
        for h, l in zip(*ax.get_legend_handles_labels()):
            labels.setdefault(l, h)
    fig.legend(list(labels.values()), list(labels.keys()), loc="upper right", fontsize=8, ncol=len(labels))
    fig.suptitle("error_physical (cell means of the exported mesh) against time budget, 2 cores, seed 1", fontsize=10,
                 x=0.3)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(out_dir / "error_physical_vs_time.png", dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=str(ROOT / "build/release/bin/freeform"))
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/physical"))
    ap.add_argument("--variants", default="new,old")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--plot-only", action="store_true")
    ap.add_argument("--prev-bin", help="binary of an earlier checkout (variant prev)")
    ap.add_argument("--prev-root", help="that checkout's root, for its example scenes (variant prev)")
    a = ap.parse_args()
    if "prev" in a.variants.split(",") and not a.plot_only and not (a.prev_bin and a.prev_root):
        ap.error("variant prev needs --prev-bin and --prev-root")
    PREV["bin"], PREV["root"] = a.prev_bin, a.prev_root
    out_dir = Path(a.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    if not (TARGETS / "street.png").exists():
        subprocess.run([sys.executable, str(HERE / "make_targets.py"), "--out", str(TARGETS)], check=True)
    rows = []
    if not a.plot_only:
        t0 = time.monotonic()
        for case in a.cases.split(","):
            for budget in CASES[case][2]:
                for variant in a.variants.split(","):
                    binary = Path(a.prev_bin) if variant == "prev" else Path(a.bin)
                    r = run_one(binary, case, variant, budget, a.seed, out_dir)
                    print(f"{case:10s} {variant:4s} {budget:4g} s: error_physical {r['error_physical']:.4f} "
                          f"(fitted {r['error']:.4f}, {r['wall_seconds']:.0f} s wall)", flush=True)
        print(f"study wall time {time.monotonic() - t0:.0f} s")
    for f in sorted((out_dir / "runs").glob("*/*.json")):
        rows.append(json.loads(f.read_text()))
    write_outputs(rows, out_dir)
    print(f"results in {out_dir}/ (table.md, runs.csv, error_physical_vs_time.png)")


if __name__ == "__main__":
    main()

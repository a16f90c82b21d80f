#!/usr/bin/env python3
"""How a design's cost grows with the receiver's resolution (issue 34, part 4).

Designs one photograph (matplotlib's Grace Hopper sample, centre-cropped square and
resampled to R x R) as a mirror in the camera example's geometry (10 cm mirror, 20 cm
receiver 0.5 m away, collimated light, mesh "auto", 16 rays per cell and the default
floor of 32 per mesh cell) for each receiver size R, at one time budget, and records:

  moves/s     iterations per second of the final level's stages (annealing only)
  level s     seconds per level (start, each annealed level, the finish)
  memory      the process's peak resident memory (GNU time's maximum RSS)
  error       error_physical, the exported part's cell-mean error (docs/measures.md)

Usage (from the repository root, after a release build):

  /usr/bin/python3 benchmarks/scale/scale.py --bin build/release/bin/freeform \\
      [--sizes 200,400,512,1024] [--budget 60] [--threads 2] [--device cpu|cuda] [--append] \\
      [--out benchmarks/results/scale]

It writes scale.csv, scale.json and scale.png (the four figures against R, one line per
device) into --out, and keeps each design's metrics.json and comparison.png under
--out/runs/R/ (runs/R-cuda/ for the GPU). `--device cuda` designs with the GPU
(`freeform design --device cuda`: a build with CUDA on a machine with a device,
docs/cuda.md); `--append` keeps scale.json's other rows, so that the GPU's are added to
the CPU's. Timing needs an idle machine.
"""
import argparse
import csv
import json
import re
import subprocess
import sys
from pathlib import Path

HOPPER = Path("/usr/share/matplotlib/mpl-data/sample_data/grace_hopper.jpg")


def target_png(size: int, out: Path) -> Path:
    from PIL import Image
    img = Image.open(HOPPER).convert("L")
    w, h = img.size
    s = min(w, h)
    img = img.crop(((w - s) // 2, (h - s) // 2, (w - s) // 2 + s, (h - s) // 2 + s))
    img = img.resize((size, size), Image.LANCZOS)
    p = out / f"hopper-{size}.png"
    img.save(p)
    return p


def scene_for(size: int, target: Path, budget: float) -> dict:
    return {
        "name": f"scale-{size}",
        "description": f"Grace Hopper on a {size} x {size} receiver (benchmarks/scale/scale.py)",
        "light": {"type": "collimated", "direction": [0, 0, -1], "rays_per_cell": 16},
        "surface": {"material": "mirror", "center": [0, 0, 0], "normal": [0, 0, 1], "up": [0, 1, 0],
                    "size": [0.1, 0.1], "mesh": "auto", "height_bounds": [-0.005, 0.005], "aperture": "rect"},
        "receiver": {"center": [0, 0, 0.5], "normal": [0, 0, -1], "up": [0, 1, 0], "size": [0.2, 0.2],
                     "resolution": [size, size]},
        "target": {"image": str(target.resolve())},
        "optimise": {"time_budget": budget, "seed": 1},
    }


def run_one(binary: str, size: int, budget: float, threads: int, device: str, out: Path) -> dict:
    run_dir = out / "runs" / (str(size) if device == "cpu" else f"{size}-{device}")
    run_dir.mkdir(parents=True, exist_ok=True)
    scene = run_dir / "scene.json"
    scene.write_text(json.dumps(scene_for(size, target_png(size, run_dir), budget), indent=1))
    design = run_dir / "design"
    cmd = ["/usr/bin/time", "-v", binary, "design", str(scene), "--out", str(design), "--threads", str(threads),
           "--device", device, "--quiet"]
    p = subprocess.run(cmd, capture_output=True, text=True)
    (run_dir / "log.txt").write_text(p.stdout + p.stderr)
    if p.returncode != 0:
        sys.exit(f"scale: the {size} design failed (exit {p.returncode}); see {run_dir / 'log.txt'}")
    rss_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr).group(1))
    wall = re.search(r"Elapsed \(wall clock\) time.*: (\S+)", p.stderr).group(1)
    parts = [float(x) for x in wall.split(":")]
    wall_s = sum(v * 60 ** (len(parts) - 1 - k) for k, v in enumerate(parts))
    m = json.loads((design / "metrics.json").read_text())
    stages = m["levels"]
    last = max(s["level"] for s in stages) if stages else -1
    final = [s for s in stages if s["level"] == last]
    it, sec = sum(s["iterations"] for s in final), sum(s["seconds"] for s in final)
    # Seconds of each annealed level, coarsest first ({mesh: seconds}, in order).
    per_level = {}
    for s in sorted(stages, key=lambda s: s["level"]):
        key = f"{s['mesh'][0]}x{s['mesh'][1]}"
        per_level[key] = per_level.get(key, 0.0) + s["seconds"]
    return {
        "receiver": size,
        "mesh": m["mesh"],
        "rays": m["rays"],
        "moves_per_second_final_level": it / sec if sec > 0 else 0.0,
        "iterations": m["iterations"],
        "start_seconds": m["start"].get("seconds", 0.0),
        "level_seconds": per_level,
        "design_seconds": m["seconds"],
        "finish_seconds": m["finish_seconds"],
        "wall_seconds": wall_s,
        "peak_memory_gib": rss_kb / 2 ** 20,
        "error_physical": m.get("error_physical"),
        "error": m["error"],
        "device": m.get("device", "cpu"),
        "threads": threads,
        "budget": budget,
    }


def series(rows: list) -> dict:
    """The rows of each device, in receiver order: {label: rows}, the CPU first."""
    out = {}
    for row in sorted(rows, key=lambda row: (row.get("device", "cpu") != "cpu", row["receiver"])):
        device = row.get("device", "cpu")
        label = f"CPU, {row['threads']} threads" if device == "cpu" else f"GPU, {device[len('cuda ('):-1]}" \
            if device.startswith("cuda (") else device
        out.setdefault(label, []).append(row)
    return out


def chart(rows: list, out: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    by_device = series(rows)
    rows = [row for group in by_device.values() for row in group]  # the bars' order: each device's sizes
    r = sorted({row["receiver"] for row in rows})
    fig, ax = plt.subplots(2, 2, figsize=(10, 7.5))
    for label, group in by_device.items():
        style = "o-" if label.startswith("CPU") else "s--"
        annealed = [row for row in group if row["moves_per_second_final_level"] > 0]
        ax[0][0].plot([row["receiver"] for row in annealed], [row["moves_per_second_final_level"] for row in annealed],
                      style, label=label)
        ax[1][0].plot([row["receiver"] for row in group], [row["peak_memory_gib"] for row in group], style,
                      label=label)
        ax[1][1].plot([row["receiver"] for row in group], [row["error_physical"] for row in group], style,
                      label=label)
    for row in rows:
        if row["moves_per_second_final_level"] <= 0:
            # The budget could not afford the level's trace: the design is its start.
            ax[0][0].annotate("not annealed:\nthe start only", (row["receiver"], 0), xycoords=("data", "axes fraction"),
                              xytext=(0, 12), textcoords="offset points", ha="center", fontsize=8)
    ax[0][0].set_ylabel("moves / s (final level)")
    if any(row["moves_per_second_final_level"] > 0 for row in rows):
        ax[0][0].set_yscale("log")
    # One bar per design: the start, each annealed level (finest last), the finish (the
    # final traces, the export and its cell means) and the rest of the wall time (writing
    # the files, the process itself).
    x = list(range(len(rows)))
    bottom = [0.0] * len(rows)

    def stack(values, label, colour=None):
        ax[0][1].bar(x, values, bottom=bottom, label=label, color=colour)
        for k, v in enumerate(values):
            bottom[k] += v

    stack([row["start_seconds"] for row in rows], "start (transport)", "tab:blue")
    depth = max(len(row["level_seconds"]) for row in rows)
    shades = ["#fdd49e", "#fc8d59", "#d7301f"]
    for k in range(depth):
        # Level k counted from the finest, so that every design's final level has one colour.
        stack([list(row["level_seconds"].values())[::-1][depth - 1 - k]
               if depth - 1 - k < len(row["level_seconds"]) else 0.0 for row in rows],
              "final level" if k == depth - 1 else f"level final-{depth - 1 - k}", shades[k - depth + 3])
    stack([max(0.0, row["design_seconds"] - row["start_seconds"] - sum(row["level_seconds"].values()))
           for row in rows], "levels' set-up (full traces, held-out checks)", "#fee8c8")
    stack([row["finish_seconds"] for row in rows], "finish (traces, export, cell means)", "tab:green")
    stack([max(0.0, row["wall_seconds"] - row["design_seconds"] - row["finish_seconds"]) for row in rows],
          "writing files, process", "tab:grey")
    ax[0][1].set_xticks(list(x), [str(row["receiver"]) + ("" if row.get("device", "cpu") == "cpu" else "\nGPU")
                                  for row in rows])
    ax[0][1].set_ylabel("seconds")
    ax[0][1].legend(fontsize=8)
    ax[1][0].set_ylabel("peak memory (GiB, host)")
    before = [row for row in rows if "error_physical_before" in row]
    if before:
        # An earlier run of the same sizes, kept in scale.json for comparison (its label says which).
        ax[1][1].plot([row["receiver"] for row in before], [row["error_physical_before"] for row in before], "s--",
                      color="grey", label=before[0].get("before", "before"))
    ax[1][1].set_ylabel("error_physical at equal time")
    for a in (ax[0][0], ax[1][0], ax[1][1]):
        a.set_xlabel("receiver (pixels per side)")
        a.set_xticks(r)
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    ax[0][1].set_xlabel("receiver (pixels per side)")
    budget = rows[0]["budget"]
    devices = " and ".join(by_device)
    gpu = "" if len(by_device) > 1 else "; no GPU row measured yet"
    fig.suptitle(f"Cost against resolution: Grace Hopper as a mirror, {budget:g} s budget, {devices}{gpu}")
    fig.tight_layout()
    fig.savefig(out / "scale.png", dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bin", default="build/release/bin/freeform")
    ap.add_argument("--sizes", default="200,400,512,1024")
    ap.add_argument("--budget", type=float, default=60)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"], help="freeform design --device")
    ap.add_argument("--append", action="store_true", help="keep --out's scale.json rows of other sizes or devices")
    ap.add_argument("--out", default="benchmarks/results/scale")
    ap.add_argument("--chart-only", action="store_true", help="redraw scale.png from --out's scale.json")
    a = ap.parse_args()
    if a.chart_only:
        chart(json.loads((Path(a.out) / "scale.json").read_text()), Path(a.out))
        return
    if not HOPPER.exists():
        sys.exit(f"scale: {HOPPER} is missing (Debian's python3-matplotlib ships it)")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for size in [int(s) for s in a.sizes.split(",")]:
        print(f"scale: {size} x {size} on the {a.device} ...", flush=True)
        rows.append(run_one(a.bin, size, a.budget, a.threads, a.device, out))
        print(f"  mesh {rows[-1]['mesh']}, {rows[-1]['moves_per_second_final_level']:.0f} moves/s, "
              f"{rows[-1]['peak_memory_gib']:.2f} GiB, error_physical {rows[-1]['error_physical']}", flush=True)
    if a.append and (out / "scale.json").exists():
        new = {(row["receiver"], row["device"].split(" ")[0]) for row in rows}
        kept = [row for row in json.loads((out / "scale.json").read_text())
                if (row["receiver"], row.get("device", "cpu").split(" ")[0]) not in new]
        rows = kept + rows
    (out / "scale.json").write_text(json.dumps(rows, indent=1))
    with open(out / "scale.csv", "w", newline="") as f:
        keys = [k for k in rows[0] if k != "level_seconds"]
        w = csv.DictWriter(f, fieldnames=keys + ["level_seconds"])
        w.writeheader()
        for row in rows:
            w.writerow({**{k: row.get(k) for k in keys}, "level_seconds": json.dumps(row["level_seconds"])})
    chart(rows, out)
    print(f"scale: {out / 'scale.csv'}, {out / 'scale.png'}")


if __name__ == "__main__":
    main()

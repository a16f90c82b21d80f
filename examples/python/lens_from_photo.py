#!/usr/bin/env python3
"""Designs a lens that throws a photograph onto a screen, from Python (docs/python.md).

The scene is examples/scenes/lens.json (a 10 cm PMMA lens, the screen 0.5 m below it)
with its target replaced by a photograph given as a NumPy array. Writes the command
line's files (metrics.json, heightmap.pfm, surface.step, ...) and lens-from-photo.png:
target | result | difference, and the error against time.

    PYTHONPATH=build/release/python /usr/bin/python3 examples/python/lens_from_photo.py \\
        [--photo examples/data/camera-200.png] [--time-budget 60] [--out results/python-lens]
"""
import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display needed
import matplotlib.image
import matplotlib.pyplot as plt
import numpy as np

import freeform

EXAMPLES = Path(__file__).resolve().parent.parent


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--photo", default=str(EXAMPLES / "data" / "camera-200.png"))
    parser.add_argument("--scene", default=str(EXAMPLES / "scenes" / "lens.json"))
    parser.add_argument("--time-budget", type=float, default=60)
    parser.add_argument("--threads", type=int, default=0, help="0: every core")
    parser.add_argument("--out", default="results/python-lens")
    args = parser.parse_args()

    photo = matplotlib.image.imread(args.photo)  # floats in [0, 1], rows x columns (x channels)
    if photo.ndim == 3:
        photo = photo[..., :3].mean(axis=2)  # grey levels are relative irradiance
    scene = freeform.Scene.load(args.scene)

    def progress(iteration, seconds, error):  # at most twice a second
        print(f"\r{seconds:6.1f} s  iteration {iteration:8d}  error {error:.4f}", end="", flush=True)

    d = freeform.design(scene, photo, time_budget=args.time_budget, threads=args.threads, progress=progress)
    print(f"\nerror_physical {d.metrics['error_physical']:.4f} ({d.metrics['error_physical_form']}), "
          f"{d.metrics['iterations']} iterations in {d.metrics['seconds']:.1f} s")
    out = Path(args.out)
    d.write(out)

    # Irradiance and target are cell means of the exported part, scaled to the same total;
    # shown as fractions of the target's brightest cell.
    peak = d.target.max()
    target, result = d.target / peak, d.irradiance / peak
    fig, axes = plt.subplots(1, 4, figsize=(16, 4), gridspec_kw={"width_ratios": [1, 1, 1.2, 1.3]})
    for ax, image, title in ((axes[0], target, "target"), (axes[1], result, "result")):
        ax.imshow(image, cmap="gray", vmin=0, vmax=1)
        ax.set_title(title)
    shown = axes[2].imshow(result - target, cmap="RdBu_r", vmin=-0.5, vmax=0.5)
    axes[2].set_title("result - target (red: too much light)")
    fig.colorbar(shown, ax=axes[2], fraction=0.046)
    for ax in axes[:3]:
        ax.set_xticks([])
        ax.set_yticks([])
    c, start = d.convergence, d.metrics["start"]
    axes[3].plot(c["seconds"], c["error"], lw=1, label="annealing")
    if "error" in start:
        axes[3].plot([start["seconds"]], [start["error"]], "o", label="start (%s)" % start["used"])
    axes[3].set_xlabel("seconds")
    axes[3].set_ylabel("error with the design's rays")
    axes[3].set_title("error_physical of the part: %.4f" % d.metrics["error_physical"])
    axes[3].legend()
    axes[3].grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "lens-from-photo.png", dpi=100)
    print(f"results in {out}/ (lens-from-photo.png, metrics.json, surface.step, ...)")


if __name__ == "__main__":
    main()

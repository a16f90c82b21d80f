#!/usr/bin/env python3
"""Sunlight and Fresnel losses (issue 24): what the sun's disc and the glass's reflections
do to a lens design, and what designing for them gains.

    /usr/bin/python3 benchmarks/study/sunlight.py [--budget 60] [--threads 2]
        [--freeform build/release/bin/freeform] [--out benchmarks/results/sunlight]

From examples/scenes/sunlit-lens.json (a PMMA lens, the sun, Fresnel, 1 m throw) three
designs are made with `freeform design --time-budget B`:
  sun       the scene as it is: designed under the sun's disc with Fresnel losses;
  parallel  designed under exactly parallel light (angular_radius 0), Fresnel on;
  lossless  designed under the sun without Fresnel losses.
Each design's heightmap is then rendered (`freeform render --heightmap`) under the
light it will really meet (the sun, Fresnel on) and under parallel light, and the
cell-mean error `error_physical` of each render is tabulated (docs/measures.md), with
the renders' speed with and without Fresnel on one heightmap in one session (a ratio).
Writes OUT/table.md, OUT/runs.json and OUT/irradiance.png (matplotlib).
"""
import argparse
import copy
import json
import os
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))


def run(cmd, log):
    t0 = time.time()
    with open(log, "w") as f:
        r = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT)
    if r.returncode != 0:
        sys.exit("sunlight.py: %s failed (exit %d), see %s" % (" ".join(cmd), r.returncode, log))
    return time.time() - t0


def read_pfm(path):
    with open(path, "rb") as f:
        kind = f.readline().strip()
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        data = np.fromfile(f, dtype="<f4" if scale < 0 else ">f4")
    channels = 3 if kind == b"PF" else 1
    img = data.reshape(h, w, channels)[:, :, 0] if channels == 3 else data.reshape(h, w)
    return np.flipud(img)


def plot(out, work, runs):
    def e(name, judge):
        return runs["renders"]["%s / %s" % (name, judge)]["error_physical"]

    tag = {"under the sun": "sun", "under parallel light": "parallel"}
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        panels = [("parallel", "under parallel light"), ("parallel", "under the sun"), ("sun", "under the sun")]
        fig, axes = plt.subplots(1, 3, figsize=(12, 4.4))
        for ax, (name, judge) in zip(axes, panels):
            img = read_pfm(os.path.join(work, "render-%s-%s" % (name, tag[judge]), "irradiance.pfm"))
            ax.imshow(img, cmap="inferno")
            ax.set_title("made for %s\n%s: %.3f" % ("parallel light" if name == "parallel" else "the sun", judge,
                                                   e(name, judge)), fontsize=10)
            ax.axis("off")
        fig.tight_layout(rect=(0, 0, 1, 0.97))
        fig.savefig(os.path.join(out, "irradiance.png"), dpi=90)
    except ImportError:
        print("sunlight.py: matplotlib missing, no irradiance.png", file=sys.stderr)



def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--budget", type=float, default=60)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--freeform", default=os.path.join(ROOT, "build", "release", "bin", "freeform"))
    ap.add_argument("--out", default=os.path.join(ROOT, "benchmarks", "results", "sunlight"))
    ap.add_argument("--plot-only", action="store_true", help="redraw irradiance.png from OUT/runs.json and OUT/work")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    work = os.path.join(args.out, "work")
    os.makedirs(work, exist_ok=True)

    if args.plot_only:
        plot(args.out, work, json.load(open(os.path.join(args.out, "runs.json"))))
        return
    base = json.load(open(os.path.join(ROOT, "examples", "scenes", "sunlit-lens.json")))

    def variant(name, angular_radius, fresnel):
        s = copy.deepcopy(base)
        s["light"]["angular_radius"] = angular_radius
        s["trace"] = {"fresnel": fresnel}
        path = os.path.join(work, name + ".json")
        json.dump(s, open(path, "w"), indent=1)
        return path

    sun = base["light"]["angular_radius"]
    scenes = {
        "sun": variant("sun", sun, True),
        "parallel": variant("parallel", 0.0, True),
        "lossless": variant("lossless", sun, False),
    }
    judges = {"under the sun": scenes["sun"], "under parallel light": scenes["parallel"]}
    tag = {"under the sun": "sun", "under parallel light": "parallel"}
    runs = {"budget": args.budget, "threads": args.threads, "designs": {}, "renders": {}}
    for name, scene in scenes.items():
        out = os.path.join(work, "design-" + name)
        if not os.path.exists(os.path.join(out, "metrics.json")):  # OUT/work keeps designs: delete it to redo
            print("design %s (%g s) ..." % (name, args.budget), flush=True)
            run([args.freeform, "design", scene, "--out", out, "--time-budget", str(args.budget), "--threads",
                 str(args.threads), "--quiet"], out + ".log")
        runs["designs"][name] = json.load(open(os.path.join(out, "metrics.json")))
        for judge, judge_scene in judges.items():
            rout = os.path.join(work, "render-%s-%s" % (name, tag[judge]))
            run([args.freeform, "render", judge_scene, "--heightmap", os.path.join(out, "heightmap.pfm"), "--out",
                 rout, "--threads", str(args.threads)], rout + ".log")
            runs["renders"]["%s / %s" % (name, judge)] = json.load(open(os.path.join(rout, "metrics.json")))

    # Fresnel's cost in tracing speed: one heightmap, Fresnel on and off, three renders each,
    # alternating, in this one session; the median rays per second of each.
    speed = {True: [], False: []}
    for rep in range(3):
        for fresnel in (True, False):
            rout = os.path.join(work, "speed-%s-%d" % ("on" if fresnel else "off", rep))
            run([args.freeform, "render", variant("speed", sun, fresnel), "--heightmap",
                 os.path.join(work, "design-sun", "heightmap.pfm"), "--out", rout, "--threads",
                 str(args.threads)], rout + ".log")
            speed[fresnel].append(json.load(open(os.path.join(rout, "metrics.json")))["rays_per_second"])
    runs["rays_per_second"] = {"fresnel": speed[True], "no_fresnel": speed[False]}
    json.dump(runs, open(os.path.join(args.out, "runs.json"), "w"), indent=1)

    def e(name, judge):
        return runs["renders"]["%s / %s" % (name, judge)]["error_physical"]

    def energy(name, judge):
        return runs["renders"]["%s / %s" % (name, judge)]["energy"]

    ratio = float(np.median(speed[True]) / np.median(speed[False]))
    lines = [
        "# Sunlight and Fresnel losses: examples/scenes/sunlit-lens.json",
        "",
        "Command: `/usr/bin/python3 benchmarks/study/sunlight.py --budget %g --threads %d` "
        "(each design `freeform design --time-budget %g`, seed 1; renders `freeform render --heightmap`)."
        % (args.budget, args.threads, args.budget),
        "",
        "`error_physical` (cell means of the surface, docs/measures.md) of each design, rendered under",
        "the light it will meet (the sun, 0.266°, with Fresnel losses) and under parallel light:",
        "",
        "| design made for | under the sun | under parallel light | energy under the sun |",
        "|---|---:|---:|---:|",
    ]
    labels = {"sun": "the sun, Fresnel (the scene)", "parallel": "parallel light, Fresnel",
              "lossless": "the sun, no Fresnel"}
    for name in scenes:
        lines.append("| %s | %.4f | %.4f | %.4f |" % (labels[name], e(name, "under the sun"),
                                                    e(name, "under parallel light"), energy(name, "under the sun")))
    lines += [
        "",
        "Tracing with Fresnel losses runs at %.2f× the speed without (median rays per second of three"
        " renders each, alternating, one heightmap, one session)." % ratio,
        "",
    ]
    open(os.path.join(args.out, "table.md"), "w").write("\n".join(lines))
    print("\n".join(lines))

    plot(args.out, work, runs)

if __name__ == "__main__":
    main()

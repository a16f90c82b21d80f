#!/usr/bin/env python3
"""Independent validation of freeform's tracer with POV-Ray 3.7 photon mapping (make validate).

For every case: design it with freeform (a short budget) or reuse a design directory,
render the exported mesh (mirror sheet or lens solid) in POV-Ray with photon mapping
onto a diffuse receiver seen by an orthographic camera, read the picture back as
irradiance, and compare it with freeform's own trace of the same design. The cases
include a mirror under the sun's disc (light.angular_radius) and a lens with Fresnel
losses (trace.fresnel), each also rendered without them. Before the designs, known
answers check the pipeline itself: a flat mirror's footprint, a paraboloid's focus under
parallel light and under the sun, and a glass slab's Fresnel transmittance. Outputs: benchmarks/results/validation.md, per-case PNGs under
benchmarks/results/validation/, work files under build/validate/.

Error definitions: both images are normalised to unit total, and
L1(a, b) = sum |a - b| / 2 (freeform's error, reference eq. 3.3, when all light reaches
the receiver: 0 identical, 1 disjoint).
"""
import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import imageio  # noqa: E402
import povray_scene  # noqa: E402

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))

# key (for --cases), name, scene file, comparison bin factor (scene receiver pixels per
# compared pixel), changes to the scene (merged into its JSON; the design is made for them)
CASES = [
    ("E", "E", "examples/scenes/letter-e.json", 2, None),
    ("F", "F (point light)", "examples/scenes/point-light.json", 2, None),
    ("L", "L (lens)", "examples/scenes/lens.json", 2, None),
    ("headlight", "headlight", "examples/scenes/headlight.json", 1, None),
    # The sun's disc (0.266 degrees' radius) on a mirror: POV-Ray sees it as --sun-lights
    # parallel lights spread over the disc.
    ("E-sun", "E (sunlit)", "examples/scenes/letter-e.json", 2, {"light": {"angular_radius": 0.266}}),
    # Fresnel losses at every face of the lens, designed with them.
    ("L-fresnel", "L (lens, Fresnel)", "examples/scenes/lens.json", 2, {"trace": {"fresnel": True}}),
]


def merged(base, changes):
    """base with changes merged in, key by key (nested objects merged, other values replaced)."""
    out = json.loads(json.dumps(base))
    for k, v in (changes or {}).items():
        out[k] = merged(out.get(k, {}), v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def scene_variant(scene_path, changes, work):
    """The scene file to design: the example itself, or a copy with the changes written to
    the work directory (a relative target image made absolute so it still resolves)."""
    if not changes:
        return scene_path
    with open(scene_path) as f:
        scene = merged(json.load(f), changes)
    image = scene.get("target", {}).get("image")
    if image and not os.path.isabs(image):
        scene["target"]["image"] = os.path.join(os.path.dirname(scene_path), image)
    path = os.path.join(work, "scene.json")
    with open(path, "w") as f:
        json.dump(scene, f, indent=1)
    return path


def light_power(scene):
    """Power a collimated light of unit irradiance sends through the aperture (scene units:
    square metres), None for other lights: POV-Ray's irradiance is in the same unit."""
    light, surf = scene["light"], scene["surface"]
    if light["type"] != "collimated":
        return None
    area = float(surf["size"][0]) * float(surf["size"][1])
    if surf.get("aperture", "rect") == "ellipse":
        area *= np.pi / 4
    _, _, _, w = povray_scene.frame(surf["center"], surf["normal"], surf["up"])
    return area * abs(float(np.dot(povray_scene.unit(light["direction"]), w)))


def l1(a, b):
    a = a / a.sum()
    b = b / b.sum()
    return 0.5 * float(np.abs(a - b).sum())


def bin_image(img, f):
    if f == 1:
        return img
    h, w = img.shape
    return img[: h - h % f, : w - w % f].reshape(h // f, f, w // f, f).sum(axis=(1, 3))


def run(cmd, log, **kw):
    t0 = time.time()
    with open(log, "w") as f:
        f.write("$ " + " ".join(cmd) + "\n")
        f.flush()
        r = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, **kw)
    if r.returncode != 0:
        sys.exit("validate: command failed (%d), see %s: %s" % (r.returncode, log, " ".join(cmd)))
    return time.time() - t0


def freeform_render(args, scene, work, mesh=None, heightmap=None, tag="freeform", material=None):
    """freeform's irradiance of the same geometry with many rays and nearest deposit (cell
    integrals, no bilinear blur), at the scene's receiver resolution."""
    sc = json.loads(json.dumps(scene))
    sc["light"].pop("rays", None)
    sc["light"]["rays_per_cell"] = args.freeform_rays_per_cell
    sc["receiver"]["deposit"] = "nearest"
    sc["surface"]["initial"] = "flat"  # the heightmap or mesh replaces it
    sc.pop("optimise", None)
    path = os.path.join(work, tag + "-scene.json")
    with open(path, "w") as f:
        json.dump(sc, f, indent=1)
    out = os.path.join(work, tag)
    cmd = [args.freeform, "render", path, "--out", out, "--threads", str(args.threads)]
    if mesh:
        cmd += ["--mesh", mesh]
    if material:
        cmd += ["--material", material]
    if heightmap:
        cmd += ["--heightmap", heightmap]
    seconds = run(cmd, os.path.join(work, tag + ".log"))
    img = imageio.read_pfm(os.path.join(out, "irradiance.pfm"))
    with open(os.path.join(out, "metrics.json")) as f:
        metrics = json.load(f)
    return img, seconds, metrics


def povray_render(args, scene, mesh, work, supersample, photons):
    w, h = scene["receiver"]["resolution"]
    W, H = w * supersample, h * supersample
    pov = os.path.join(work, "scene.pov")
    info = povray_scene.write_scene(pov, scene, mesh, W, H, photons, gather=(args.gather_min, args.gather_max),
                                    sun_lights=args.sun_lights)
    info["width"], info["height"] = W, H
    hdr = os.path.join(work, "povray.hdr")
    log = os.path.join(work, "povray.log")
    cmd = [args.povray, "-D", "+WT%d" % args.threads, "+W%d" % W, "+H%d" % H, "-A", "+FH", "-V", "+GS", "+GR",
           "+I" + pov, "+O" + hdr]
    seconds = run(cmd, log, cwd=work)
    text = open(log, errors="replace").read()
    m = re.search(r"Number of photons shot:\s+(\d+)", text)
    info["photons_shot"] = int(m.group(1)) if m else None
    m = re.search(r"Surface photons stored:\s+(\d+)", text)
    info["photons_stored"] = int(m.group(1)) if m else None
    img = imageio.read_hdr(hdr).mean(axis=2)
    # Share of the light's power on the receiver: mean irradiance times the receiver's area.
    power = light_power(scene)
    size = scene["receiver"]["size"]
    info["energy"] = float(img.mean()) * size[0] * size[1] / power if power else None
    return bin_image(img, supersample), seconds, info


def save_png(path, img, cmap="inferno", vmin=None, vmax=None):
    import matplotlib.pyplot as plt

    plt.imsave(path, img, cmap=cmap, vmin=vmin, vmax=vmax)


def panel(path, images, titles, suptitle=None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(images)
    fig, axes = plt.subplots(1, n, figsize=(3.2 * n, 3.5))
    for ax, img, title in zip(np.atleast_1d(axes), images, titles):
        if title.startswith("difference"):
            lim = float(np.abs(img).max()) or 1.0
            ax.imshow(img, cmap="RdBu_r", vmin=-lim, vmax=lim, interpolation="nearest")
        else:
            ax.imshow(img / (img.max() or 1.0), cmap="inferno", vmin=0, vmax=1, interpolation="nearest")
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    if suptitle:
        fig.suptitle(suptitle, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def target_image(scene_file, design_dir, scene, factor):
    """The target at the compared resolution: the scene's image (linear grey levels), or the
    design's target.png (text targets, written with gamma 2.2 by freeform) linearised."""
    import matplotlib.image as mpimg

    w, h = scene["receiver"]["resolution"]
    tgt = scene.get("target", {})
    if "image" in tgt:
        src = tgt["image"]
        if not os.path.isabs(src):
            src = os.path.join(os.path.dirname(scene_file), src)
        img = mpimg.imread(src).astype(float)
        if img.ndim == 3:
            img = img[..., :3].mean(axis=2)
        fy, fx = img.shape[0] // h, img.shape[1] // w
        img = img.reshape(h, fy, w, fx).mean(axis=(1, 3))
    else:
        img = mpimg.imread(os.path.join(design_dir, "target.png")).astype(float)
        if img.ndim == 3:
            img = img[..., :3].mean(axis=2)
        img = img ** 2.2
    return bin_image(img, factor)


def centroid_and_extent(img, cell):
    """Centroid (pixels, col/row) and the bounding box of pixels above half the median lit value."""
    tot = img.sum()
    rows, cols = np.indices(img.shape)
    c = ((img * cols).sum() / tot, (img * rows).sum() / tot)
    # Width and height of a uniform rectangle with the same row and column profiles
    # (sub-pixel: a partly lit edge pixel counts by its share).
    cols_sum, rows_sum = img.sum(axis=0), img.sum(axis=1)
    return c, cols_sum.sum() / cols_sum.max() * cell[0], rows_sum.sum() / rows_sum.max() * cell[1]


# ---------------------------------------------------------------------------------------
# Known answers


def write_grid_obj(path, nx, ny, size, height, center=(0, 0, 0)):
    xs = np.linspace(-size[0] / 2, size[0] / 2, nx) + center[0]
    ys = np.linspace(-size[1] / 2, size[1] / 2, ny) + center[1]
    X, Y = np.meshgrid(xs, ys)
    Z = height(X - center[0], Y - center[1]) + center[2]
    with open(path, "w") as f:
        f.write("# written by scripts/validate/validate.py\n")
        for x, y, z in zip(X.ravel(), Y.ravel(), Z.ravel()):
            f.write("v %.12g %.12g %.12g\n" % (x, y, z))
        for j in range(ny - 1):
            for i in range(nx - 1):
                a = j * nx + i + 1
                f.write("f %d %d %d\n" % (a, a + 1, a + nx + 1))
                f.write("f %d %d %d\n" % (a, a + nx + 1, a + nx))


def check_scene(center, size, receiver_res=(100, 100)):
    return {
        "name": "check",
        "light": {"type": "collimated", "direction": [0, 0, -1], "rays_per_cell": 16},
        "surface": {"material": "mirror", "center": list(center), "normal": [0, 0, 1], "up": [0, 1, 0],
                    "size": list(size), "mesh": [41, 41], "height_bounds": [-0.005, 0.005]},
        "receiver": {"center": [0, 0, 0.5], "normal": [0, 0, -1], "up": [0, 1, 0], "size": [0.2, 0.2],
                     "resolution": list(receiver_res)},
    }


def known_answers(args, results_dir, rows):
    lines = []
    # 1. A flat mirror off centre: its footprint is the mirror's rectangle, seen from the
    # receiver's front (u = -x), uniform.
    work = os.path.join(args.work, "check-flat")
    os.makedirs(work, exist_ok=True)
    center, size = (0.02, 0.01, 0.0), (0.08, 0.05)
    scene = check_scene(center, size)
    obj = os.path.join(work, "flat.obj")
    write_grid_obj(obj, 41, 41, size, lambda x, y: 0 * x, center)
    ff, ff_s, _ = freeform_render(args, scene, work, mesh=obj)
    pv, pv_s, info = povray_render(args, scene, obj, work, args.supersample, args.check_photons)
    cell = (0.2 / 100, 0.2 / 100)
    expect_col = (-center[0] + 0.1) / cell[0]  # u = -x, column 0 at u = -0.1
    expect_row = (0.1 - center[1]) / cell[1]   # row 0 at v = +0.1
    res = {}
    for name, img in (("freeform", ff), ("POV-Ray", pv)):
        (cx, cy), wx, wy = centroid_and_extent(img, cell)
        inside = img[int(expect_row - 0.5 * size[1] / cell[1]) + 2: int(expect_row + 0.5 * size[1] / cell[1]) - 2,
                     int(expect_col - 0.5 * size[0] / cell[0]) + 2: int(expect_col + 0.5 * size[0] / cell[0]) - 2]
        res[name] = (cx + 0.5, cy + 0.5, wx, wy, inside.std() / inside.mean())
    d = l1(ff, pv)
    lines.append("| flat mirror %g x %g mm at (%g, %g) mm | expected: centre (%.1f, %.1f) px, %g x %g mm, uniform | "
                 % (size[0] * 1e3, size[1] * 1e3, center[0] * 1e3, center[1] * 1e3, expect_col, expect_row,
                    size[0] * 1e3, size[1] * 1e3)
                 + " | ".join("%s: centre (%.1f, %.1f) px, %.1f x %.1f mm, std/mean %.3f" % (k, v[0], v[1], v[2] * 1e3,
                                                                                         v[3] * 1e3, v[4])
                              for k, v in res.items()) + " | %.4f |" % d)
    panel(os.path.join(results_dir, "check-flat.png"), [ff, pv, pv / pv.sum() - ff / ff.sum()],
          ["freeform", "POV-Ray", "difference (POV-Ray - freeform)"], "flat mirror footprint")
    rows.append(("check: flat mirror", d, None, None, ff_s, pv_s, "100 x 100", info))

    # 2. A paraboloid h = r^2 / 4f, f = 0.5 m, under collimated light: a spot at the focus,
    # the receiver's centre. Its second moment measures the focus (ideal: the facets' blur).
    work = os.path.join(args.work, "check-paraboloid")
    os.makedirs(work, exist_ok=True)
    f = 0.5
    size = (0.1, 0.1)
    scene = check_scene((0, 0, 0), size, (200, 200))
    scene["receiver"]["size"] = [0.02, 0.02]  # 0.1 mm pixels around the focus
    obj = os.path.join(work, "paraboloid.obj")
    write_grid_obj(obj, 201, 201, size, lambda x, y: (x * x + y * y) / (4 * f))
    ff, ff_s, ffm = freeform_render(args, scene, work, mesh=obj)
    pv, pv_s, info = povray_render(args, scene, obj, work, 1, args.check_photons)
    cell = 0.02 / 200
    res = {}
    for name, img in (("freeform", ff), ("POV-Ray", pv)):
        tot = img.sum()
        rows_i, cols_i = np.indices(img.shape)
        cx, cy = (img * cols_i).sum() / tot + 0.5, (img * rows_i).sum() / tot + 0.5
        rms = np.sqrt((img * ((cols_i + 0.5 - cx) ** 2 + (rows_i + 0.5 - cy) ** 2)).sum() / tot) * cell
        res[name] = ((cx - 100) * cell, (cy - 100) * cell, rms, tot)
    d = l1(ff, pv)
    lines.append("| paraboloid f = 500 mm, receiver at 500 mm (20 mm window, 0.1 mm pixels) | expected: spot at the "
                 "centre | " + " | ".join("%s: centre offset (%.3f, %.3f) mm, rms radius %.3f mm" % (
                     k, v[0] * 1e3, v[1] * 1e3, v[2] * 1e3) for k, v in res.items()) + " | %.4f |" % d)
    panel(os.path.join(results_dir, "check-paraboloid.png"), [ff, pv, pv / pv.sum() - ff / ff.sum()],
          ["freeform", "POV-Ray", "difference (POV-Ray - freeform)"], "paraboloid focus (20 mm window)")
    rows.append(("check: paraboloid focus", d, None, None, ff_s, pv_s, "200 x 200 (20 mm)", info))

    # 3. The same paraboloid under the sun's disc (angular radius 0.266 degrees): the focal
    # spot becomes a uniform disc of radius R = f tan(theta) (blurred by the facets' 0.2 mm),
    # so the shares within 0.5, 0.7, 1.0 and 1.1 R are 0.25, 0.49, 1 and 1.
    sun = json.loads(json.dumps(scene))
    sun["light"]["angular_radius"] = 0.266
    work = os.path.join(args.work, "check-sun")
    os.makedirs(work, exist_ok=True)
    ff, ff_s, _ = freeform_render(args, sun, work, mesh=obj)
    pv, pv_s, info = povray_render(args, sun, obj, work, 1, args.check_photons)
    radius = f * np.tan(np.radians(0.266))
    shares = (0.5, 0.7, 1.0, 1.1)
    res = {}
    for name, img in (("freeform", ff), ("POV-Ray", pv)):
        rows_i, cols_i = np.indices(img.shape)
        r = np.hypot(cols_i + 0.5 - 100, rows_i + 0.5 - 100) * cell
        res[name] = [img[r < a * radius].sum() / img.sum() for a in shares]
    d = l1(ff, pv)
    lines.append("| paraboloid f = 500 mm under the sun (0.266°; %d POV-Ray parallel lights): share of the light "
                 "within %s R, R = f tan θ = %.2f mm | expected: 0.25, 0.49, 1, 1 | " % (
                     args.sun_lights, ", ".join("%g" % a for a in shares), radius * 1e3)
                 + " | ".join("%s: %s" % (k, ", ".join("%.3f" % x for x in v)) for k, v in res.items())
                 + " | %.4f |" % d)
    panel(os.path.join(results_dir, "check-sun.png"), [ff, pv, pv / pv.sum() - ff / ff.sum()],
          ["freeform", "POV-Ray", "difference (POV-Ray - freeform)"], "paraboloid under the sun (20 mm window)")
    rows.append(("check: sun disc", d, None, None, ff_s, pv_s, "200 x 200 (20 mm)", info))

    # 4. A glass slab (n = 1.5, 15 mm) with Fresnel losses, at normal incidence and tilted
    # by 30 degrees: each face passes 1 - (R_s + R_p)/2 (Fresnel's equations, unpolarised;
    # at normal incidence 1 - ((n - 1)/(n + 1))^2 = 0.96), the slab the square of that (the
    # light reflected inside dropped, as freeform does; following it would add 0.0015).
    for tilt in (0.0, 30.0):
        work = os.path.join(args.work, "check-slab-%g" % tilt)
        os.makedirs(work, exist_ok=True)
        obj = os.path.join(work, "slab.obj")
        write_box_obj(obj, (0.1, 0.1), -0.015, 0.0, tilt)
        slab = check_scene((0, 0, 0), (0.1, 0.1))
        slab["surface"]["material"] = {"refractive": 1.5, "thickness": 0.015}
        slab["receiver"].update({"center": [0, 0, -0.5], "normal": [0, 0, 1]})
        energies = {}
        for fresnel in (False, True):
            slab["trace"] = {"fresnel": fresnel}
            tag = "fresnel" if fresnel else "plain"
            ff, ff_s, ffm = freeform_render(args, slab, work, mesh=obj, material="refractive:1.5",
                                            tag="freeform-" + tag)
            pwork = os.path.join(work, tag)
            os.makedirs(pwork, exist_ok=True)
            pv, pv_s, info = povray_render(args, slab, obj, pwork, 2, args.check_photons)
            energies[tag] = (ffm["energy"], info["energy"], l1(ff, pv))
        expected = slab_transmittance(1.5, np.radians(tilt))
        lines.append("| glass slab n = 1.5, 15 mm, tilted %g°, Fresnel: energy on the receiver (without Fresnel → "
                     "with; ratio) | expected: 1 → %.4f | freeform: %.4f → %.4f (%.4f) | POV-Ray: %.4f → %.4f "
                     "(%.4f) | %.4f |" % (tilt, expected, energies["plain"][0], energies["fresnel"][0],
                                          energies["fresnel"][0] / energies["plain"][0], energies["plain"][1],
                                          energies["fresnel"][1], energies["fresnel"][1] / energies["plain"][1],
                                          energies["fresnel"][2]))
        rows.append(("check: Fresnel slab %g°" % tilt, energies["fresnel"][2], None, None, ff_s, pv_s, "100 x 100",
                     info))
    return lines


def slab_transmittance(n, incidence):
    """Unpolarised Fresnel transmittance of a slab's two parallel faces (no internal reflections)."""
    c1 = np.cos(incidence)
    c2 = np.sqrt(1 - (np.sin(incidence) / n) ** 2)
    r_s = ((c1 - n * c2) / (c1 + n * c2)) ** 2
    r_p = ((n * c1 - c2) / (n * c1 + c2)) ** 2
    return (1 - 0.5 * (r_s + r_p)) ** 2


def write_box_obj(path, size, z0, z1, tilt_deg=0.0):
    """A closed box (outward-facing triangles): size[0] x size[1] across, from z0 to z1,
    turned by tilt_deg about the x axis."""
    x, y = size[0] / 2, size[1] / 2
    c, s = np.cos(np.radians(tilt_deg)), np.sin(np.radians(tilt_deg))
    corners = [(sx * x, c * sy * y - s * z, s * sy * y + c * z) for z in (z0, z1) for sy in (-1, 1) for sx in (-1, 1)]
    faces = [(0, 2, 1), (1, 2, 3), (4, 5, 6), (5, 7, 6), (0, 1, 5), (0, 5, 4),
             (2, 6, 7), (2, 7, 3), (0, 4, 6), (0, 6, 2), (1, 3, 7), (1, 7, 5)]
    with open(path, "w") as f:
        f.write("# written by scripts/validate/validate.py\n")
        for c in corners:
            f.write("v %.12g %.12g %.12g\n" % c)
        for t in faces:
            f.write("f %d %d %d\n" % tuple(i + 1 for i in t))


# ---------------------------------------------------------------------------------------


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--freeform", default=os.path.join(ROOT, "build/release/bin/freeform"))
    p.add_argument("--povray", default=shutil.which("povray") or "povray")
    p.add_argument("--work", default=os.path.join(ROOT, "build/validate"))
    p.add_argument("--results", default=os.path.join(ROOT, "benchmarks/results"))
    p.add_argument("--reuse", metavar="DIR", help="reuse designs in DIR/<scene name>/ when present")
    p.add_argument("--time-budget", type=float, default=15, help="seconds per design (default 15)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--photons", type=int, default=4_000_000, help="POV-Ray photon count per case")
    p.add_argument("--check-photons", type=int, default=1_000_000)
    p.add_argument("--gather-min", type=int, default=100)
    p.add_argument("--gather-max", type=int, default=400)
    p.add_argument("--supersample", type=int, default=2, help="least POV-Ray pixels per receiver pixel, each way")
    p.add_argument("--picture", type=int, default=400,
                   help="least POV-Ray pixels along the receiver's longer side (raises --supersample)")
    p.add_argument("--freeform-rays-per-cell", type=float, default=256)
    p.add_argument("--cases", default="all",
                   help="comma-separated case keys (%s) or all" % ", ".join(c[0] for c in CASES))
    p.add_argument("--sun-lights", type=int, default=512,
                   help="parallel POV-Ray lights standing in for a light with an angular radius (default 512)")
    p.add_argument("--skip-plain", action="store_true",
                   help="do not render the sunlit and Fresnel cases' parts again without the sun or Fresnel")
    p.add_argument("--skip-checks", action="store_true")
    args = p.parse_args()

    t_start = time.time()
    if not shutil.which(args.povray):
        sys.exit("validate: povray not found (scripts/install-deps.sh validate installs it)")
    if not os.path.exists(args.freeform):
        sys.exit("validate: %s not found (build it: cmake --build --preset release --target freeform_cli)" % args.freeform)
    os.makedirs(args.work, exist_ok=True)
    results_dir = os.path.join(args.results, "validation")
    os.makedirs(results_dir, exist_ok=True)

    rows = []
    check_lines = [] if args.skip_checks else known_answers(args, results_dir, rows)

    case_lines = []
    variant_lines = []
    figure = []
    for key, name, scene_file, factor, changes in CASES:
        if args.cases != "all" and key not in args.cases.split(","):
            continue
        base = os.path.splitext(os.path.basename(scene_file))[0] + ("-" + key.split("-", 1)[1] if "-" in key else "")
        work = os.path.join(args.work, base)
        os.makedirs(work, exist_ok=True)
        scene_path = scene_variant(os.path.join(ROOT, scene_file), changes, work)
        design = os.path.join(args.reuse, base) if args.reuse else os.path.join(work, "design")
        design_s = None
        if not os.path.exists(os.path.join(design, "metrics.json")):
            design_s = run([args.freeform, "design", scene_path, "--out", design, "--time-budget", str(args.time_budget),
                            "--threads", str(args.threads), "--quiet"], os.path.join(work, "design.log"))
        with open(os.path.join(design, "metrics.json")) as f:
            dm = json.load(f)
        scene = dm["effective_scene"]
        mesh = os.path.join(design, "surface.obj")
        lens = isinstance(scene["surface"]["material"], dict)
        # freeform's trace of the same part: the exported mesh as flat triangles (render
        # --mesh), the lens as its closed solid of the scene's index (--material refractive).
        if lens:
            ior = scene["surface"]["material"]["refractive"]
            ff, ff_s, ffm = freeform_render(args, scene, work, mesh=mesh, material="refractive:%.17g" % ior)
        else:
            ff, ff_s, ffm = freeform_render(args, scene, work, mesh=mesh)
        # POV-Ray point-samples the photon map (one ray per pixel, each estimate a disc of
        # about 1 mm or less); freeform integrates over whole cells. Enough POV-Ray pixels
        # per cell (--picture on the longer side) make both cell averages of the same thing.
        w, h = scene["receiver"]["resolution"]
        supersample = max(args.supersample, -(-args.picture // max(w, h)))
        pv, pv_s, info = povray_render(args, scene, mesh, work, supersample, args.photons)
        info["supersample"] = supersample
        tgt = target_image(scene_path, design, scene, factor)
        ffb, pvb = bin_image(ff, factor), bin_image(pv, factor)
        d = l1(ffb, pvb)
        e_ff, e_pv = l1(ffb, tgt), l1(pvb, tgt)
        d_full = l1(ff, pv)
        w, h = scene["receiver"]["resolution"]
        res = "%d x %d" % (w // factor, h // factor)
        imageio.write_pfm(os.path.join(work, "povray-irradiance.pfm"), pv.astype(np.float32))
        panel(os.path.join(results_dir, base + ".png"),
              [tgt, ffb, pvb, pvb / pvb.sum() - ffb / ffb.sum()],
              ["target", "freeform (error %.3f)" % e_ff, "POV-Ray (error %.3f)" % e_pv,
               "difference (POV-Ray - freeform)"],
              "%s: L1(freeform, POV-Ray) = %.3f at %s" % (name, d, res))
        save_png(os.path.join(results_dir, base + "-povray.png"), pvb / pvb.max(), vmin=0, vmax=1)
        save_png(os.path.join(results_dir, base + "-freeform.png"), ffb / ffb.max(), vmin=0, vmax=1)
        figure.append((name, tgt, ffb, pvb))
        rows.append((name, d, e_ff, e_pv, ff_s, pv_s, res, info))
        case_lines.append((name, d, d_full, e_ff, e_pv, dm.get("error"), dm.get("error_exported"), design_s, ff_s,
                           pv_s, res, "%d x %d" % (w, h), info, ffm.get("energy"), lens))
        if changes and not args.skip_plain:
            # What the variant changes, seen by both renderers: the same part rendered without it.
            plain = merged(scene, {"light": {"angular_radius": 0.0}, "trace": {"fresnel": False}})
            pwork = os.path.join(work, "plain")
            os.makedirs(pwork, exist_ok=True)
            ffp, _, ffpm = freeform_render(args, plain, pwork, mesh=mesh,
                                           material=("refractive:%.17g" % scene["surface"]["material"]["refractive"])
                                           if lens else None)
            pvp, _, pinfo = povray_render(args, plain, mesh, pwork, supersample, args.photons)
            variant_lines.append((name, l1(bin_image(ff, factor), bin_image(ffp, factor)),
                                  l1(bin_image(pv, factor), bin_image(pvp, factor)), ffm.get("energy"),
                                  info.get("energy"), ffpm.get("energy"), pinfo.get("energy"), res))
        print("validate: %-16s L1(freeform, POV-Ray) %.4f at %s (%.4f at %dx%d); error vs target: freeform %.4f, "
              "POV-Ray %.4f; POV-Ray %.0f s, %s photons stored" % (name, d, res, d_full, w, h, e_ff, e_pv, pv_s,
                                                                    info["photons_stored"]), flush=True)

    if figure:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(len(figure), 3, figsize=(7.5, 2.5 * len(figure)))
        axes = np.atleast_2d(axes)
        for r, (name, tgt, ffb, pvb) in enumerate(figure):
            for c, (img, title) in enumerate(((tgt, "target"), (ffb, "freeform"), (pvb, "POV-Ray"))):
                ax = axes[r, c]
                ax.imshow(img / img.max(), cmap="inferno", vmin=0, vmax=1, interpolation="nearest")
                ax.set_xticks([])
                ax.set_yticks([])
                if r == 0:
                    ax.set_title(title, fontsize=10)
                if c == 0:
                    ax.set_ylabel(name, fontsize=10)
        fig.tight_layout()
        fig.savefig(os.path.join(results_dir, "validation.png"), dpi=90)
        plt.close(fig)

    total = time.time() - t_start
    write_report(args, check_lines, case_lines, variant_lines, total)
    print("validate: %s written (%.0f s)" % (os.path.join(args.results, "validation.md"), total))
    bad = [c for c in case_lines if c[1] > 0.05]
    if bad:
        print("validate: goal L1 <= 0.05 missed by: " + ", ".join("%s (%.4f)" % (c[0], c[1]) for c in bad))


NOTES = """## How POV-Ray is set up, and what remains

- Compared resolution: the scene's receiver binned 2 × 2 (2 mm cells; the headlight at its own 50 × 50, 4 mm cells). There both sides are converged to within the goal: at the scene's full resolution the L1 rises (photon noise and the photon-gather blur of about 1 mm act per cell), and what is left at the compared resolution is photon noise plus that blur along the sharp edges and the fine facet caustics (streaks in the difference pictures), not a shift or a scale: the known-answer checks put the footprint and the focus where they belong to 0.003 mm.
- Photons: `count` 4,000,000 per case (POV-Ray shoots about 2 × that over the target's bounding disc and stores those that land), `autostop 0`, `jitter 0.4`, gather 100–400 photons per estimate; on E (design reused) `--photons 1000000` gives L1 0.030 at 100 × 100 (0.048 at 200 × 200) and POV-Ray's error against the target 0.0355, 4 M give 0.021 (0.036) and 0.034: the error against the target has settled, the L1 between the two still falls with more photons (pure noise would fall to 0.015), so photon noise is most of what remains. Render times are on the shared 2-core machine.
- The receiver does not shadow the light: the light is placed between the surface and the receiver (docs/architecture.md §1 and docs/scene.md, "Conventions": the receiver is transparent to incoming light), and the receiver sits in a `light_group` with `global_lights off`, so it is lit by photons only (no direct term, as freeform records only light that has left the surface). The surface has neither `no_shadow` nor `no_image` (either flag makes POV-Ray 3.7 store no photons from it); the orthographic camera starts between the surface and the receiver, so the surface is never in the picture. A parallel light's position and `point_at` must lie on the axis through the target's middle (off that axis POV-Ray stored no photons).
- Lens: the exported closed solid (`inside_vector`), `pigment rgbf 1` (all light transmitted), `ior` 1.49, no `fade_distance` (no absorption). Both sides trace the same closed solid with total internal reflection followed (`render --mesh surface.obj --material refractive:1.49` on freeform's side); the design's own lens model counts the light that leaves through the solid's side walls as lost, which both renderers here let through.
- Fresnel (`trace.fresnel`, the case "L (lens, Fresnel)" and the slab checks): POV-Ray's lens gets `reflection { 0, 1 fresnel on } conserve_energy` (what a face reflects is taken from what it passes) and its photons do not follow the reflection, as freeform drops the reflected part (docs/scene.md). Without `trace.fresnel` neither side has a Fresnel loss (mirror `reflection 1`; lens `reflection 0`). At normal incidence POV-Ray's slab passes within 0.002 of the closed form; at oblique incidence POV-Ray 3.7 loses more than Fresnel's equations say (the 30° slab above: 0.888 against 0.919), while freeform matches them (tests/test_refract.cpp checks 10°, 30°, 45° faces to 1e-7; the tilted slab here passes 0.9164, not 0.9187, because the light that reaches a side wall of the 100 × 15 mm slab crosses it at other angles). That is why POV-Ray's Fresnel lens delivers about 1.5 % less light than freeform's (0.908 against 0.924): the faces' slopes reach 20°. By Fresnel's equations the loss is nearly uniform on this lens (7.6 %, varying by 0.0002 between 0° and 20°), so freeform's picture keeps its shape (L1 0.0000 between its renders with and without Fresnel); POV-Ray's stronger oblique loss takes more from the steeper patches and moves its picture by 0.018 from its own render without Fresnel, which is most of the L1 of 0.019 between the two renderers on this case (0.008 without Fresnel), still within the goal of 0.05.
- Sun (`light.angular_radius`, the case "E (sunlit)" and the paraboloid check): POV-Ray has no light with an angular size whose photons leave from every direction of a disc (`area_light` moves the origin, and photons leave from its centre), so the sun is `--sun-lights` (512) parallel lights of power 1/512 each, spread evenly over the disc's solid angle by a golden-angle spiral of equal-area rings: a discretisation made apart from freeform's own sampler (8 directions per aperture point, 2 rings × 4 sectors, turned and jittered per point). Both put the paraboloid's light where the closed form says (shares within 0.5/0.7 R: 0.25/0.49), and both see the same change from parallel light on the E design. With 64 lights POV-Ray's focal disc was 64 separate dots at 0.1 mm pixels (L1 0.150 against freeform's smooth disc, the shares unchanged); 512 lights cost the same photons and 5 s.
- Energy on the receiver (POV-Ray: the picture's mean irradiance times the receiver's area over the light's power through the aperture): the cases read within 0.7 % of freeform (slab 0.9985, E 0.995, lens 0.998, headlight 1.007, sunlit E 0.997 in the run of 2026-11-26). Photon-map density estimates with an adaptive gather radius do not conserve energy where the light is spiky: the E under exactly parallel light (sharp facet caustics) reads about 1.05 in POV-Ray (measured on the sunlit E's part rendered without the sun; gather 20–50 gives 1.04), while both sides agree on its shape.
"""


def fmt(x):
    return "%.4f" % x if x is not None else "–"


def write_report(args, check_lines, case_lines, variant_lines, total):
    out = []
    out.append("# Independent validation with POV-Ray 3.7\n")
    out.append("Written by `make validate` (`scripts/validate/validate.py`, %s, %.0f s in all on this machine, "
               "%d threads). Each case is designed with freeform (%g s budget), its exported part is rendered by "
               "POV-Ray with photon mapping onto a diffuse receiver seen by an orthographic camera, and the picture "
               "is compared with freeform's trace of the same design. Images are normalised to unit total; "
               "L1(a, b) = Σ|a − b| / 2 (0 identical, 1 disjoint).\n" % (time.strftime("%Y-%m-%d"), total,
                                                                          args.threads, args.time_budget))
    out.append("## Known answers (the pipeline checked on itself)\n")
    if check_lines:
        out.append("| check | expected | freeform | POV-Ray | L1(freeform, POV-Ray) |")
        out.append("|---|---|---|---|---|")
        out += check_lines
    else:
        out.append("(skipped)")
    out.append("\n## Cases\n")
    out.append("| case | compared at | L1(freeform, POV-Ray) | same at the scene's resolution | error vs target: "
               "freeform | error vs target: POV-Ray | energy on the receiver: freeform / POV-Ray | design error "
               "(metrics.json: design / exported) | freeform render | POV-Ray render | POV-Ray picture | photons shot "
               "/ stored | triangles |")
    out.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for (name, d, d_full, e_ff, e_pv, err, err_exp, design_s, ff_s, pv_s, res, full_res, info, energy,
         lens) in case_lines:
        out.append("| %s | %s | **%.4f** | %.4f (%s) | %.4f | %.4f | %s / %s | %s / %s | %.1f s | %.0f s | %d x %d (%d x %d "
                   "per cell) | %s / %s | %d |" % (
                       name, res, d, d_full, full_res, e_ff, e_pv, fmt(energy), fmt(info.get("energy")), fmt(err),
                       fmt(err_exp), ff_s, pv_s, info["width"], info["height"], info["supersample"],
                       info["supersample"], "{:,}".format(info["photons_shot"] or 0),
                       "{:,}".format(info["photons_stored"] or 0), info["triangles"]))
    if variant_lines:
        out.append("\n## What the sun and Fresnel change, seen by both renderers\n")
        out.append("The same exported part rendered again without the variant (parallel light, no Fresnel): how far "
                   "the variant moves the picture (L1 between the two renders of one renderer) and the energy on the "
                   "receiver with and without it. Both renderers should see the same change.\n")
        out.append("| case | compared at | L1(with, without): freeform | L1(with, without): POV-Ray | energy with / "
                   "without: freeform | energy with / without: POV-Ray |")
        out.append("|---|---|---|---|---|---|")
        for name, d_ff, d_pv, e_ff, e_pv, e_ffp, e_pvp, res in variant_lines:
            out.append("| %s | %s | %.4f | %.4f | %s / %s | %s / %s |" % (
                name, res, d_ff, d_pv, fmt(e_ff), fmt(e_ffp), fmt(e_pv), fmt(e_pvp)))
    out.append("")
    out.append("freeform side: `freeform render` with %g rays per receiver cell and nearest-cell deposit (cell "
               "integrals, no bilinear blur); for mirrors the exported `surface.obj` traced as flat triangles "
               "(`--mesh`), the lens as its exported closed solid (`--mesh surface.obj --material refractive:IOR`: "
               "Snell at every crossing, total internal reflection followed). POV-Ray side: the exported mesh as `mesh2` (flat "
               "triangles), at least %d POV-Ray pixels along the receiver's longer side (one ray each, no "
               "anti-aliasing), summed into receiver cells, photon gather %d–%d photons per estimate. Pictures: `benchmarks/results/validation/`.\n"
               % (args.freeform_rays_per_cell, args.picture, args.gather_min, args.gather_max))
    out.append(NOTES)
    with open(os.path.join(args.results, "validation.md"), "w") as f:
        f.write("\n".join(out) + "\n")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Draws the study's own target images (benchmarks/study/targets/), used by the cases that
check the "auto" mesh rule on targets the earlier passes never saw (issue 11, part 4):

  ring.png      a bright annulus on black (binary, round edges); headlight setup, 50 x 50 px
  checker.png   a 4 x 4 checkerboard inside a dark margin (binary, many corners and
                cracks in the transport map); lens setup
  gradient.png  a smooth grey landscape (a ramp, two bright blobs, a dark hollow and a
                soft ripple): "photographic" by the designer's test, more than 25 % of its
                pixels grey; camera setup
  street.png    a synthetic photograph (a street at dusk: sky, sun, skyline with lit
                windows, road in perspective, grain) for the lens setup (issue 22's check
                on photographs that are not examples)

Plain Python (no numpy), deterministic: the committed PNGs are what this writes.

    python3 benchmarks/study/make_targets.py [--out benchmarks/study/targets]

8-bit grey PNGs, 200 x 200; grey levels are relative irradiance.
"""

import argparse
import math
import os
import struct
import zlib

SIZE = 200
SS = 4  # supersampling per axis (anti-aliased edges)


def smoothstep(t: float) -> float:
    t = min(1.0, max(0.0, t))
    return t * t * (3.0 - 2.0 * t)


def ring(x: float, y: float) -> float:
    r = math.hypot(x - 0.5, y - 0.5)
    return 1.0 if 0.22 <= r <= 0.36 else 0.0


def checker(x: float, y: float) -> float:
    margin = 0.1
    if not (margin <= x < 1 - margin and margin <= y < 1 - margin):
        return 0.0
    i = int((x - margin) / (1 - 2 * margin) * 4)
    j = int((y - margin) / (1 - 2 * margin) * 4)
    return 1.0 if (i + j) % 2 == 0 else 0.0


def gradient(x: float, y: float) -> float:
    ramp = 0.25 + 0.35 * (1.0 - y)  # brighter towards the top
    blob1 = 0.55 * math.exp(-((x - 0.30) ** 2 + (y - 0.35) ** 2) / (2 * 0.10 ** 2))
    blob2 = 0.40 * math.exp(-((x - 0.72) ** 2 + (y - 0.62) ** 2) / (2 * 0.07 ** 2))
    hollow = 0.30 * math.exp(-((x - 0.60) ** 2 + (y - 0.25) ** 2) / (2 * 0.08 ** 2))
    ripple = 0.08 * math.sin(2 * math.pi * 3 * (x + 0.5 * y))
    # A soft vignette: dark towards the corners, like a lit object on a dark ground.
    vignette = 1.0 - smoothstep((math.hypot(x - 0.5, y - 0.5) - 0.38) / 0.12)
    return max(0.0, (ramp + blob1 + blob2 - hollow + ripple) * vignette)


def _hash_noise(i: int, j: int) -> float:
    """Deterministic value noise in [0, 1) on an integer lattice."""
    h = (i * 374761393 + j * 668265263) & 0xFFFFFFFF
    h = ((h ^ (h >> 13)) * 1274126177) & 0xFFFFFFFF
    return ((h ^ (h >> 16)) & 0xFFFF) / 65536.0


def _texture(x: float, y: float, cells: int) -> float:
    """Smoothly interpolated value noise with `cells` lattice cells across the image."""
    u, v = x * cells, y * cells
    i, j = int(u), int(v)
    fu, fv = smoothstep(u - i), smoothstep(v - j)
    a, b = _hash_noise(i, j), _hash_noise(i + 1, j)
    c, d = _hash_noise(i, j + 1), _hash_noise(i + 1, j + 1)
    return (a * (1 - fu) + b * fu) * (1 - fv) + (c * (1 - fu) + d * fu) * fv


def street(x: float, y: float) -> float:
    """A synthetic photograph: a street at dusk. Sky gradient with a low sun, a skyline of
    blocks with lit windows, a road in perspective with lane marks, and grain: hard edges,
    smooth ramps and texture at several scales, as a real photograph has (issue 22)."""
    sky = 0.35 + 0.45 * y / 0.55 + 0.5 * math.exp(-((x - 0.7) ** 2 + (y - 0.42) ** 2) / (2 * 0.05 ** 2))
    # Skyline: block tops from a fixed list of (left, right, top) in image units.
    blocks = [(0.0, 0.14, 0.22), (0.12, 0.27, 0.30), (0.27, 0.36, 0.15), (0.36, 0.52, 0.34),
              (0.52, 0.61, 0.26), (0.61, 0.80, 0.38), (0.80, 0.92, 0.20), (0.92, 1.0, 0.31)]
    horizon = 0.58
    v = sky
    for left, right, top in blocks:
        if left <= x < right and top <= y < horizon:
            wall = 0.18 + 0.08 * _texture(x, y, 40)
            # Windows: a grid, some lit.
            gx, gy = (x - left) / 0.025, (y - top) / 0.035
            inside = 0.25 < gx % 1.0 < 0.75 and 0.3 < gy % 1.0 < 0.8
            lit = _hash_noise(int(gx) + int(left * 1000), int(gy)) > 0.55
            v = wall + (0.55 if inside and lit else 0.0)
            break
    if y >= horizon:
        depth = (y - horizon) / (1.0 - horizon)  # 0 at the horizon, 1 at the bottom
        road_half = 0.05 + 0.45 * depth
        if abs(x - 0.5) < road_half:
            v = 0.22 + 0.10 * depth + 0.06 * _texture(x, y, 60)
            lane = abs(x - 0.5) < 0.004 + 0.012 * depth and int(depth * 14) % 2 == 0
            if lane:
                v = 0.85
        else:
            v = 0.10 + 0.15 * _texture(x, y, 25)  # verges
    return max(0.0, v + 0.05 * (_texture(x, y, 90) - 0.5))


TARGETS = {"ring": ring, "checker": checker, "gradient": gradient, "street": street}


def render(f) -> list:
    rows = []
    for r in range(SIZE):
        row = []
        for c in range(SIZE):
            acc = 0.0
            for sy in range(SS):
                for sx in range(SS):
                    acc += f((c + (sx + 0.5) / SS) / SIZE, (r + (sy + 0.5) / SS) / SIZE)
            row.append(acc / (SS * SS))
        rows.append(row)
    peak = max(max(row) for row in rows)
    return [[v / peak for v in row] for row in rows]


def write_grey_png(path: str, rows: list) -> None:
    height, width = len(rows), len(rows[0])
    raw = bytearray()
    for row in rows:
        raw.append(0)  # filter type: none
        raw.extend(int(round(255 * min(1.0, max(0.0, v)))) for v in row)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n"
    png += chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))  # 8-bit grey
    png += chunk(b"IDAT", zlib.compress(bytes(raw), 9))
    png += chunk(b"IEND", b"")
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "wb") as f:
        f.write(png)


def grey_fraction(rows: list) -> float:
    """The share of grey pixels, in (0.1, 0.9) of the peak (the designer's photograph test until issue 22)."""
    vals = [v for row in rows for v in row]
    return sum(0.1 < v < 0.9 for v in vals) / len(vals)


def main() -> None:
    here = os.path.dirname(os.path.abspath(__file__))
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=os.path.join(here, "targets"), help="output directory")
    a = p.parse_args()
    for name, f in TARGETS.items():
        rows = render(f)
        path = os.path.join(a.out, name + ".png")
        write_grey_png(path, rows)
        print("wrote %s (%d x %d grey, %.0f %% grey pixels at full size)"
              % (os.path.normpath(path), SIZE, SIZE, 100 * grey_fraction(rows)))


if __name__ == "__main__":
    main()

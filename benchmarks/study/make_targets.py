#!/usr/bin/env python3
"""Draws the study's own target images (benchmarks/study/targets/), used by the cases that
check the "auto" mesh rule on targets the earlier passes never saw (issue 11, part 4):

  ring.png      a bright annulus on black (binary, round edges); headlight setup, 50 x 50 px
  checker.png   a 4 x 4 checkerboard inside a dark margin (binary, many corners and
                cracks in the transport map); lens setup
  gradient.png  a smooth grey landscape (a ramp, two bright blobs, a dark hollow and a
                soft ripple): "photographic" by the designer's test, more than 25 % of its
                pixels grey; camera setup

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


TARGETS = {"ring": ring, "checker": checker, "gradient": gradient}


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
    """The designer's photograph test (target_grey_fraction): pixels in (0.1, 0.9) of the peak."""
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

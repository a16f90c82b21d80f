#!/usr/bin/env python3
"""Draws the low-beam headlight target of examples/scenes/headlight.json.

The pattern is what an asymmetric (right-hand traffic) low beam throws on a wall in
front of the car, seen by the driver:

  - a horizontal cut-off line a little below the middle of the image: no light above it
    on the left (the oncoming lane), so that oncoming drivers are not dazzled;
  - right of the centre line the cut-off rises at 15 degrees (the "elbow"), lighting the
    kerb side further ahead, until it levels off again;
  - an evenly bright band under the cut-off that fades out smoothly further down (the
    road near the car) and has soft left and right ends.

Plain Python (no numpy needed), so any python3 can regenerate it:

    python3 scripts/make_headlight_target.py [--size 200] [--out examples/data/headlight-lowbeam.png]
    python3 scripts/make_headlight_target.py --mirror    # left-hand traffic: the step on the left

The output is an 8-bit grey PNG; grey levels are relative irradiance (freeform scales the
target so that only its shape matters).
"""

import argparse
import math
import os
import struct
import zlib

# Geometry, as fractions of the image width (x, left to right) and height (y, top to
# bottom). The image is what an observer facing the receiver sees (docs/scene.md).
CUTOFF_ROW = 0.42        # the horizontal cut-off (the left half)
ELBOW_X = 0.50           # where the 15-degree rise starts (the vertical centre line)
STEP_ANGLE_DEG = 15.0    # the rise of the cut-off on the kerb side
STEP_HEIGHT = 0.07       # how far the rising part climbs before it levels off
EDGE_SOFTNESS = 0.006    # half-width of the cut-off's transition (sharp, but not aliased)
BAND_DEPTH = 0.16        # depth of the evenly bright band under the cut-off
FALLOFF_DEPTH = 0.24     # below the band, the light fades to nothing over this depth
BAND_HALF_WIDTH = 0.40   # horizontal half-width of the band
SIDE_SOFTNESS = 0.06     # width of the fade at the band's left and right ends


def cutoff_row(x: float) -> float:
    """Row (fraction of the height) of the cut-off at column x."""
    rise = max(0.0, x - ELBOW_X) * math.tan(math.radians(STEP_ANGLE_DEG))
    return CUTOFF_ROW - min(rise, STEP_HEIGHT)


def smoothstep(t: float) -> float:
    t = min(1.0, max(0.0, t))
    return t * t * (3.0 - 2.0 * t)


def intensity(x: float, y: float) -> float:
    """Relative irradiance at (x, y), both in [0, 1].

    The band is evenly lit (a regulation low beam asks for a minimum everywhere in it,
    not for a peak), so the pattern is mostly two-level: freeform's mesh "auto" then
    treats it as a shape, not as a photograph, and picks a 53 x 53 mesh for a 50 x 50
    receiver (the reference used 13 x 13).
    """
    depth = y - cutoff_row(x)  # > 0 below the cut-off
    edge = smoothstep((depth + EDGE_SOFTNESS) / (2.0 * EDGE_SOFTNESS))
    # Vertical: full brightness in the band, then a smooth fade towards the car.
    vertical = 1.0 - smoothstep((depth - BAND_DEPTH) / FALLOFF_DEPTH)
    # Horizontal: flat with soft ends.
    side = 1.0 - smoothstep((abs(x - 0.5) - BAND_HALF_WIDTH) / SIDE_SOFTNESS + 0.5)
    return edge * vertical * side


def render(size: int, mirror: bool) -> list:
    rows = []
    ss = 4  # supersampling per axis, so the cut-off edges are anti-aliased
    for r in range(size):
        row = []
        for c in range(size):
            acc = 0.0
            for sy in range(ss):
                for sx in range(ss):
                    x = (c + (sx + 0.5) / ss) / size
                    y = (r + (sy + 0.5) / ss) / size
                    acc += intensity(1.0 - x if mirror else x, y)
            row.append(acc / (ss * ss))
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


def main() -> None:
    here = os.path.dirname(os.path.abspath(__file__))
    default_out = os.path.join(here, "..", "examples", "data", "headlight-lowbeam.png")
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--size", type=int, default=200, help="image width and height in pixels (default 200)")
    p.add_argument("--out", default=default_out, help="output PNG (default examples/data/headlight-lowbeam.png)")
    p.add_argument("--mirror", action="store_true", help="left-hand traffic: the rising step on the left")
    a = p.parse_args()
    if a.size < 8:
        p.error("--size: must be at least 8 pixels, got %d" % a.size)
    write_grey_png(a.out, render(a.size, a.mirror))
    print("wrote %s (%d x %d grey)" % (os.path.normpath(a.out), a.size, a.size))


if __name__ == "__main__":
    main()

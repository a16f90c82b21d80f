#!/usr/bin/python3
"""Writes the seed corpora of the fuzz targets, tests/fuzz/corpus/<reader>/, and their
libFuzzer dictionaries, tests/fuzz/dict/<reader>.dict.

Small valid and broken inputs: copies of the project's own test files and example
scenes, plus tiny files made here (STL, PFM, images in each format stb_image reads, and
command lines). JPEG, GIF, BMP, TGA and some PNG variants need Pillow; without it they
are left out (Debian's /usr/bin/python3 has it, package python3-pil). Run from
anywhere: /usr/bin/python3 tests/fuzz/make_seeds.py. Existing files are overwritten,
others are left alone (so a seed added by hand stays).
"""
import re
import struct
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
CORPUS = HERE / "corpus"


def put(reader, name, data):
    d = CORPUS / reader
    d.mkdir(parents=True, exist_ok=True)
    (d / name).write_bytes(data if isinstance(data, bytes) else data.encode())


def copy(reader, files):
    for f in files:
        put(reader, f.name, f.read_bytes())


# --- scene: every example scene and every scene of the CLI tests ---------------------
def scenes():
    copy("scene", sorted((ROOT / "examples/scenes").glob("*.json")))
    copy("scene", sorted((ROOT / "tests/data/cli").glob("*.json")))


# --- pfm -----------------------------------------------------------------------------
def pfm(magic, width, height, values, little=True):
    head = f"{magic}\n{width} {height}\n{-1.0 if little else 1.0}\n".encode()
    return head + struct.pack(("<" if little else ">") + "f" * len(values), *values)


def pfms():
    copy("pfm", [ROOT / "tests/data/cli/corrupt.pfm", ROOT / "tests/data/cli/nan.pfm"])
    put("pfm", "grey-le-3x2.pfm", pfm("Pf", 3, 2, [0.0, 0.5, 1.0, 1e-3, -2.0, 3.5]))
    put("pfm", "grey-be-2x2.pfm", pfm("Pf", 2, 2, [0.25, 0.5, 0.75, 1.0], little=False))
    put("pfm", "rgb-le-2x1.pfm", pfm("PF", 2, 1, [1, 0, 0, 0, 1, 0]))
    put("pfm", "truncated.pfm", pfm("Pf", 4, 4, [0.5] * 15))


# --- obj -----------------------------------------------------------------------------
TETRA = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
TETRA_FACES = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]  # outward, counter-clockwise


def objs():
    copy("obj", [ROOT / "tests/data/cli" / n for n in
                 ("triangle.obj", "prism.obj", "prism-high.obj", "prism-inside-out.obj", "corrupt.obj")])
    lines = ["# tetrahedron, closed and outward"] + [f"v {x} {y} {z}" for x, y, z in TETRA]
    put("obj", "tetra.obj", "\n".join(lines + [f"f {a+1} {b+1} {c+1}" for a, b, c in TETRA_FACES]) + "\n")
    # Negative indices, texture and normal references, a quad, comments, CRLF, extra records.
    put("obj", "quad-refs.obj",
        "o quad\r\nv 0 0 0\r\nv 1 0 0 1.0\r\nv 1 1 0\r\nv 0 1 0\r\nvt 0 0\r\nvn 0 0 1\r\n"
        "usemtl none\r\nf -4/1/1 -3/1/1 -2//1 -1//-1 # fan\r\ns off\r\n")
    put("obj", "normals.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 2\nvn 0 0 1\nf 1//1 2//2 3//1\n")
    put("obj", "bad-index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n")


# --- stl -----------------------------------------------------------------------------
def stl_binary(vertices, faces, header=b"freeform fuzz seed"):
    out = header.ljust(80, b" ") + struct.pack("<I", len(faces))
    for f in faces:
        out += struct.pack("<3f", 0, 0, 0)
        for v in f:
            out += struct.pack("<3f", *vertices[v])
        out += b"\0\0"
    return out


def stl_ascii(vertices, faces, name="tetra"):
    text = [f"solid {name}"]
    for f in faces:
        text += ["  facet normal 0 0 0", "    outer loop"]
        text += ["      vertex {} {} {}".format(*vertices[v]) for v in f]
        text += ["    endloop", "  endfacet"]
    return "\n".join(text + [f"endsolid {name}", ""])


def stls():
    put("stl", "tetra-binary.stl", stl_binary(TETRA, TETRA_FACES))
    put("stl", "tetra-ascii.stl", stl_ascii(TETRA, TETRA_FACES))
    # A binary file whose header starts with "solid", as some exporters write.
    put("stl", "solid-header-binary.stl", stl_binary(TETRA, TETRA_FACES, b"solid but binary"))
    put("stl", "open-ascii.stl", stl_ascii(TETRA, TETRA_FACES[:2], "open"))
    put("stl", "inside-out-ascii.stl", stl_ascii(TETRA, [(a, c, b) for a, b, c in TETRA_FACES], "inverted"))
    put("stl", "truncated-binary.stl", stl_binary(TETRA, TETRA_FACES)[:150])


# --- image ---------------------------------------------------------------------------
def hdr():
    flat = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 3\n" + bytes(
        [128, 64, 32, 129, 10, 20, 30, 128, 0, 0, 0, 0, 255, 255, 255, 127, 1, 2, 3, 130])
    # Width 8 uses the run-length scanlines: 2 2 width, then each component as runs.
    rle = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 8\n" + bytes([2, 2, 0, 8])
    rle += bytes([128 + 8, 100]) + bytes([4, 1, 2, 3, 4, 128 + 4, 9]) + bytes([128 + 8, 50]) + bytes([128 + 8, 129])
    return flat, rle


def psd(width, height, channels, planes):
    head = b"8BPS" + struct.pack(">H6xHIIHH", 1, channels, height, width, 8, 3 if channels >= 3 else 1)
    return head + struct.pack(">III", 0, 0, 0) + struct.pack(">H", 0) + bytes(planes)


def images():
    cli = ROOT / "tests/data/cli"
    copy("image", [cli / "black.png", cli / "corrupt.png", cli / "truncated.png",
                   ROOT / "examples/data/headlight-lowbeam.png"])
    put("image", "grey-3x2.pgm", b"P5\n3 2\n255\n" + bytes([0, 128, 255, 1, 2, 3]))
    put("image", "rgb-2x2.ppm", b"P6\n# comment\n2 2\n255\n" + bytes(range(12)))
    put("image", "grey16-2x1.pgm", b"P5\n2 1\n65535\n" + bytes([0, 1, 255, 255]))
    flat, rle = hdr()
    put("image", "flat-3x2.hdr", flat)
    put("image", "rle-8x1.hdr", rle)
    put("image", "rgb-2x2.psd", psd(2, 2, 3, range(12)))
    try:
        from PIL import Image
    except ImportError:
        print("make_seeds.py: no Pillow; JPEG, GIF, BMP, TGA and extra PNG seeds left out", file=sys.stderr)
        return
    import io

    def save(name, img, fmt, **options):
        buf = io.BytesIO()
        img.save(buf, fmt, **options)
        put("image", name, buf.getvalue())

    rgb = Image.new("RGB", (5, 4))
    rgb.putdata([(x * 50, y * 60, (x * y * 20) % 256) for y in range(4) for x in range(5)])
    grey = rgb.convert("L")
    save("rgb-5x4.png", rgb, "PNG")
    save("rgba-5x4.png", rgb.convert("RGBA"), "PNG")
    save("grey-alpha-5x4.png", rgb.convert("LA"), "PNG")
    save("palette-5x4.png", rgb.convert("P"), "PNG")
    save("grey16-5x4.png", grey.convert("I").point(lambda v: v * 257).convert("I;16"), "PNG")
    save("bilevel-5x4.png", grey.convert("1"), "PNG")
    save("baseline-16x8.jpg", rgb.resize((16, 8)), "JPEG", quality=80)
    save("progressive-16x8.jpg", rgb.resize((16, 8)), "JPEG", quality=60, progressive=True)
    save("grey-8x8.jpg", grey.resize((8, 8)), "JPEG", quality=90)
    save("subsampled-16x16.jpg", rgb.resize((16, 16)), "JPEG", quality=50, subsampling=2)
    save("palette-5x4.gif", rgb.convert("P"), "GIF")
    frames = [rgb.convert("P"), grey.convert("P")]
    save("animated-5x4.gif", frames[0], "GIF", save_all=True, append_images=frames[1:], duration=10)
    save("rgb-5x4.bmp", rgb, "BMP")
    save("palette-5x4.bmp", rgb.convert("P"), "BMP")
    save("rgb-5x4.tga", rgb, "TGA")
    save("rle-5x4.tga", rgb, "TGA", compression="tga_rle")
    save("grey-5x4.tga", grey, "TGA")


# --- cli: NUL-separated arguments after argv[0] -------------------------------------
def clis():
    lines = {
        "render.args": ["render", "scene.json", "--out", "o", "--limit", "pixels=4"],
        "render-mesh.args": ["render", "s.json", "--out", "o", "--mesh", "m.obj", "--material", "refractive:1.49",
                             "--mesh-normals", "--tracer", "embree", "--threads", "2", "--seed", "7"],
        "render-heightmap.args": ["render", "s.json", "--out=o", "--heightmap", "h.pfm", "--tracer=heightfield"],
        "design.args": ["design", "scene.json", "--out", "o", "--time-budget", "1.5", "--quiet", "--start-only",
                        "--limit", "memory_bytes=32GiB", "--limit", "json_depth=8"],
        "design-seed.args": ["design", "s.json", "--out", "o", "--seed", "12", "--threads", "0",
                             "--limit", "scene_file_bytes=1K", "--limit", "triangles=100"],
        "bad-limit.args": ["render", "s.json", "--out", "o", "--limit", "pixels"],
        "bad-material.args": ["render", "s.json", "--out", "o", "--material", "refractive:0.5"],
        "help.args": ["--help"],
        "render-help.args": ["render", "--help"],
        "version.args": ["--version"],
        "no-command.args": [],
        "unknown.args": ["frobnicate", "-x"],
    }
    for name, args in lines.items():
        put("cli", name, "\0".join(args))


# --- dictionaries: tokens libFuzzer splices into inputs (-dict) ----------------------
def dict_line(token):
    escaped = "".join(c if 32 <= ord(c) < 127 and c not in '"\\' else "\\x%02x" % ord(c) for c in token)
    return f'"{escaped}"'


def dicts():
    d = HERE / "dict"
    d.mkdir(exist_ok=True)
    # Every quoted word of the scene schema (keys and enum values), as JSON strings.
    schema = (ROOT / "include/freeform/io/scene_json.hpp").read_text()
    words = sorted(set(re.findall(r'"([a-z][a-z0-9_]*)"', schema)))
    scene = [f'"{w}"' for w in words] + ["{", "}", "[", "]", ":", ",", "true", "false", "null", "-1e308",
                                          "1e-320", "0.5", "//", "/*", "*/"]
    tokens = {
        "scene": scene,
        "obj": ["v ", "vn ", "vt ", "f ", "o ", "g ", "s ", "#", "/", "//", "-1", "1e308", "nan", "inf", "+1",
                "\r\n", "\n"],
        "stl": ["solid", "endsolid", "facet normal", "endfacet", "outer loop", "endloop", "vertex ", "1e38",
                "-0", "nan", "\n"],
        "pfm": ["Pf", "PF", "-1.0", "1.0", "\n", " ", "1048576", "4194304", "nan", "inf", "0x1p-1074"],
        "cli": ["render", "design", "--out", "--heightmap", "--mesh", "--material", "refractive:", "--mesh-normals",
                "--tracer", "auto", "embree", "heightfield", "--threads", "--seed", "--limit", "--time-budget",
                "--quiet", "--start-only", "--help", "--help-all", "--version", "--", "=", "json_depth=",
                "scene_file_bytes=", "data_file_bytes=", "pixels=", "triangles=", "memory_bytes=", "KiB", "GiB",
                "T", "\x00"],
    }
    for reader, items in tokens.items():
        lines = [f"# libFuzzer dictionary for fuzz_{reader} (written by tests/fuzz/make_seeds.py)"]
        for item in items:
            # Items above are written as they appear in text; decode the escapes first.
            lines.append(dict_line(item.encode().decode("unicode_escape")))
        (d / f"{reader}.dict").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    dicts()
    scenes()
    pfms()
    objs()
    stls()
    images()
    clis()
    total = sum(f.stat().st_size for f in CORPUS.rglob("*") if f.is_file())
    print(f"make_seeds.py: corpora in {CORPUS} ({total} bytes)")

#!/usr/bin/env python3
"""Hostile input and faults, run as a user (or a batch system) would run freeform.

    hostile.py FREEFORM SCENE_DIR WORK

1. Hostile inputs: each must exit with 2, print one line on stderr that names the file
   or key, stay under 100 MB of memory beyond what the program needs to reject a missing
   file, and create no output. The time each takes is printed, not asserted (speed is
   measured in benchmarks/, never asserted in tests); issue 25's goal of 1 s is read here.
2. Write failures (a file-size limit, as a full disk would give): exit non-zero, the
   message names the file, the previous results stay as they were, nothing is left over.
3. Killed while writing (SIGXFSZ at several points of the output, and SIGKILL at several
   moments of a run): no output folder ever reads as complete unless it is.

Standard library only (Debian's python3). Under AddressSanitizer (ASAN_OPTIONS set by the
sanitizer test preset) memory is not checked, only behaviour.
"""
import json
import os
import resource
import shutil
import signal
import struct
import subprocess
import sys
import time
import zlib

FREEFORM, SCENES, WORK = (os.path.abspath(a) for a in sys.argv[1:4])
SANITIZED = "ASAN_OPTIONS" in os.environ
failures = []


def fail(what):
    failures.append(what)
    print("FAILED: " + what)


def run(args, limit_file_bytes=None, ignore_xfsz=True, timeout=600):
    """Runs freeform; returns (exit code or -signal, stdout, stderr, seconds, peak RSS in MB)."""
    out_path, err_path = os.path.join(WORK, "stdout.txt"), os.path.join(WORK, "stderr.txt")

    def limits():
        if limit_file_bytes is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit_file_bytes, limit_file_bytes))
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN if ignore_xfsz else signal.SIG_DFL)

    with open(out_path, "wb") as out, open(err_path, "wb") as err:
        start = time.monotonic()
        p = subprocess.Popen([FREEFORM] + args, stdout=out, stderr=err, cwd=WORK, preexec_fn=limits)
        _, status, usage = os.wait4(p.pid, 0)
        seconds = time.monotonic() - start
    p.returncode = os.waitstatus_to_exitcode(status)
    with open(out_path, errors="replace") as f:
        stdout = f.read()
    with open(err_path, errors="replace") as f:
        stderr = f.read()
    return p.returncode, stdout, stderr, seconds, usage.ru_maxrss / 1024.0


def write(name, data):
    path = os.path.join(WORK, name)
    with open(path, "wb" if isinstance(data, bytes) else "w") as f:
        f.write(data)
    return path


def scene(name, **blocks):
    base = {"light": {"type": "collimated", "rays_per_cell": 4}, "surface": {"mesh": [21, 21]},
            "receiver": {"resolution": [40, 40]}}
    base.update(blocks)
    return write(name, json.dumps(base))


def png_announcing(width, height):
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)) +
            chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))


# ------------------------------------------------------------------ 1. hostile inputs
shutil.rmtree(WORK, ignore_errors=True)
os.makedirs(WORK)

rc, _, _, _, baseline_mb = run(["render", "no-such-scene.json", "--out", "out"])
assert rc == 2, "a missing scene must exit 2"

write("nested.json", "[" * 200000 + "]" * 200000)
write("wide.png", png_announcing(100000, 100000))
write("wider.png", png_announcing(20000, 20000))
write("forged.jpg", bytes.fromhex(
    "ffd8ffdb004300080606070605080707070909080a0c140d0c0b0b0c1912130f141d1a1f1e1d1a1c1c20242e2720222c231c1c28"
    "37292c30313434341f27393d38323c2e333432ffc0000b081f401f400101110000ffc4001f000001050101010101010000000000"
    "0000000102030405060708090a0bffc400b5100002010303020403050504040000017d01020300041105122131410613516107"
    "227114328191a1082342b1c11552d1f02433627282090a161718191a25262728292a3435363738393a434445464748494a5354"
    "55565758595a636465666768696a737475767778797a838485868788898a92939495969798999aa2a3a4a5a6a7a8a9aab2b3b4"
    "b5b6b7b8b9bac2c3c4c5c6c7c8c9cad2d3d4d5d6d7d8d9dae1e2e3e4e5e6e7e8e9eaf1f2f3f4f5f6f7f8f9faffda0008010100"
    "003f00fbd3ffd9"))
write("noise.ttf", bytes((k * 7919 + 13) % 256 for k in range(4096)))
write("short.ttf", b"\0\1\0\0\0\x40" + b"\0" * 10)
write("wide.pfm", b"Pf\n1000000 1000000\n-1\n" + b"\0" * 16)
write("long-key.json", json.dumps({"light": {"type": "collimated"}, "surface": {}, "receiver": {},
                                   "k" * 1000000: 1}))
write("newline-key.json", json.dumps({"light": {"type": "collimated"}, "surface": {}, "receiver": {},
                                      "a\nb\rc\td": 1}))
write("long-number.json", '{"light": {"type": "collimated", "rays_per_cell": ' + "9" * 100000 + "}}")
write("liar.stl", b" " * 80 + struct.pack("<I", 0xFFFFFFFF) + b"\0" * 50)
write("bad-index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4000000000\n")
write("garbage.json", bytes(range(256)) * 8)
write("big.json", "{" + " " * (17 << 20) + "}")
os.makedirs(os.path.join(WORK, "folder.json"), exist_ok=True)
stl_many = b" " * 80 + struct.pack("<I", 12) + b"\0" * (12 * 50)
write("twelve.stl", stl_many)

cases = [
    # (what, arguments, text the message must contain)
    ("200,000 nested brackets", ["render", "nested.json"], "json_depth"),
    ("a 17 MB scene file", ["render", "big.json"], "scene_file_bytes"),
    ("a scene that is binary garbage", ["render", "garbage.json"], "garbage.json: invalid JSON"),
    ("a megabyte-long key", ["render", "long-key.json"], "characters left out"),
    ("a key with a newline in it", ["render", "newline-key.json"], "a\\nb\\x0dc\\x09d"),
    ("a number of 100,000 digits", ["render", "long-number.json"], "number overflow"),
    ("a folder as the scene", ["render", "folder.json"], "not a regular file"),
    ("/dev/zero as the scene", ["render", "/dev/zero"], "/dev/zero"),
    ("a PNG target announcing 10^10 pixels",
     ["render", scene("png-target.json", target={"image": "wide.png"})], "wide.png"),
    ("a PNG target announcing 4 x 10^8 pixels",
     ["render", scene("png-target2.json", target={"image": "wider.png"})], "the limit pixels"),
    ("a 300-byte JPEG announcing 8000 x 8000 pixels",
     ["render", scene("jpg-target.json", target={"image": "forged.jpg"})], "forged.jpg"),
    ("a font that is noise", ["render", scene("font1.json", target={"text": "E", "font": "noise.ttf"})],
     "noise.ttf"),
    ("a font whose table directory runs past its end",
     ["render", scene("font2.json", target={"text": "E", "font": "short.ttf"})], "short.ttf"),
    ("a scene file as the font", ["render", scene("font3.json", target={"text": "E", "font": "font3.json"})],
     "font3.json"),
    ("a PFM target announcing 10^12 pixels",
     ["render", scene("pfm-target.json", target={"image": "wide.pfm"})], "wide.pfm"),
    ("a PFM start announcing 10^12 pixels",
     ["design", scene("pfm-start.json", target={"text": "E"}, surface={"mesh": [21, 21], "initial": "wide.pfm"})],
     "wide.pfm"),
    ("a --heightmap announcing 10^12 pixels", ["render", scene("plain.json"), "--heightmap", "wide.pfm"],
     "wide.pfm"),
    ("an STL announcing 4 billion triangles", ["render", scene("plain2.json"), "--mesh", "liar.stl"], "liar.stl"),
    ("an STL over --limit triangles", ["render", scene("plain3.json"), "--mesh", "twelve.stl",
                                       "--limit", "triangles=10"], "triangles = 10"),
    ("an OBJ with a vertex index of 4 billion", ["render", scene("plain4.json"), "--mesh", "bad-index.obj"],
     "bad-index.obj"),
    ("/dev/zero as a mesh", ["render", scene("plain5.json"), "--mesh", "/dev/zero"], "/dev/zero"),
    ("2^20 rays per cell on a 16384^2 receiver",
     ["render", scene("rays.json", light={"type": "collimated", "rays_per_cell": 1048576},
                      receiver={"resolution": [16384, 16384]})], "memory_bytes"),
    ("a design on a 16384^2 mesh",
     ["design", scene("mesh.json", surface={"mesh": [16384, 16384]}, receiver={"resolution": [16384, 16384]},
                      target={"text": "E"})], "memory_bytes"),
    ("4 billion rays", ["render", scene("rays2.json", light={"type": "collimated", "rays": 4294967296})],
     "memory_bytes"),
    ("a bad --limit", ["render", scene("plain6.json"), "--limit", "memory_bytes=lots"], "--limit"),
]
for what, args, needle in cases:
    out = os.path.join(WORK, "out-" + str(abs(hash(what)) % 100000))
    rc, stdout, stderr, seconds, peak_mb = run(args + ["--out", out])
    lines = stderr.strip().splitlines()
    if rc != 2:
        fail(f"{what}: exit {rc}, expected 2 ({stderr.strip()[:300]})")
    if len(lines) != 1 or needle not in stderr or len(stderr) > 1200:
        fail(f"{what}: expected one line naming '{needle}', got: {stderr.strip()[:400]}")
    if os.path.exists(out):
        fail(f"{what}: the output folder was created")
    if not SANITIZED and peak_mb - baseline_mb > 100:
        fail(f"{what}: peak memory {peak_mb:.0f} MB, {peak_mb - baseline_mb:.0f} MB over the baseline")
    print(f"ok   {what}: exit {rc} in {seconds:.2f} s, peak {peak_mb:.0f} MB (baseline {baseline_mb:.0f}): "
          f"{lines[0][:150] if lines else ''}")

# ------------------------------------------------------------------ 2. write failures
tiny = os.path.join(SCENES, "design-tiny.json")
DESIGN_FILES = ["metrics.json", "convergence.csv", "heightmap.pfm", "irradiance.pfm", "irradiance.png",
                "target.png", "comparison.png", "surface.obj", "surface.stl"]


def snapshot(folder):
    """Name -> bytes of every entry (a folder that is not an output counts as 'folder')."""
    if not os.path.isdir(folder):
        return {}
    result = {}
    for name in sorted(os.listdir(folder)):
        path = os.path.join(folder, name)
        result[name] = "folder" if os.path.isdir(path) else open(path, "rb").read()
    return result


def complete(folder, names):
    """'' when every file in `names` is there and whole, else what is wrong."""
    for name in names:
        path = os.path.join(folder, name)
        if not os.path.isfile(path):
            return name + " missing"
        data = open(path, "rb").read()
        if name.endswith(".json"):
            try:
                json.loads(data)
            except ValueError:
                return name + " is not whole JSON"
        elif name.endswith(".stl"):
            if len(data) < 84 or len(data) != 84 + 50 * struct.unpack("<I", data[80:84])[0]:
                return name + " is truncated"
        elif name.endswith(".png"):
            if not data.endswith(b"IEND\xaeB`\x82"):
                return name + " is truncated"
        elif name.endswith(".pfm"):
            header = data.split(b"\n", 3)
            w, h = (int(v) for v in header[1].split())
            if len(header) < 4 or len(header[3]) != 4 * w * h:
                return name + " is truncated"
        elif name.endswith(".obj") or name.endswith(".csv"):
            if not data.endswith(b"\n"):
                return name + " is truncated"
    return ""


design_out = os.path.join(WORK, "design-out")
rc, _, stderr, _, _ = run(["design", tiny, "--out", design_out, "--quiet"])
if rc != 0 or complete(design_out, DESIGN_FILES):
    fail(f"the reference design failed: exit {rc}, {complete(design_out, DESIGN_FILES)} {stderr[:300]}")
previous = snapshot(design_out)

for limit in (2_000, 20_000, 2_000_000):
    rc, _, stderr, _, _ = run(["design", tiny, "--out", design_out, "--quiet", "--seed", "9"],
                              limit_file_bytes=limit)
    if rc == 0:
        fail(f"write failure at {limit} bytes: exit 0")
    elif "cannot write '" + design_out not in stderr or ("File too large" not in stderr):
        fail(f"write failure at {limit} bytes: the message does not name the file and the reason: {stderr[:300]}")
    if snapshot(design_out) != previous:
        fail(f"write failure at {limit} bytes: the previous results changed")
    print(f"ok   write failure at {limit} bytes: exit {rc}, previous results intact: {stderr.strip()[:160]}")

# ------------------------------------------------------------------ 3. killed while writing
for limit in (1_000, 60_000, 300_000, 3_000_000):
    rc, _, _, _, _ = run(["design", tiny, "--out", design_out, "--quiet", "--seed", "11"],
                         limit_file_bytes=limit, ignore_xfsz=False)
    if rc != -signal.SIGXFSZ:
        fail(f"SIGXFSZ at {limit} bytes: expected death by SIGXFSZ, got exit {rc}")
    visible = {k: v for k, v in snapshot(design_out).items() if not k.startswith(".freeform-staging-")}
    if visible != previous:
        fail(f"killed at {limit} bytes of a file: the previous results changed")
    print(f"ok   killed by SIGXFSZ at {limit} bytes: previous results intact")
# The next run clears what the killed ones staged.
rc, _, _, _, _ = run(["design", tiny, "--out", design_out, "--quiet", "--seed", "11"])
left = [n for n in os.listdir(design_out) if n.startswith(".freeform-staging-")]
if rc != 0 or left or complete(design_out, DESIGN_FILES):
    fail(f"the run after the kills: exit {rc}, left {left}, {complete(design_out, DESIGN_FILES)}")
else:
    print("ok   the next run removed the killed runs' staging folders")

# SIGKILL at moments spread over a whole run (the write phase included): whenever
# metrics.json is there, all files are whole and from one run. Not under the sanitizers:
# these kills test how results are published (renames, not memory), they are timed to an
# unsanitized run's phases, and they are half of this test's design runs (the test took
# 232 s under ASan in CI, 47 s in release); the release run makes them.
if SANITIZED:
    print("skipped SIGKILL at moments of a run: under the sanitizers (the release run makes them)")
else:
    rc, _, _, full_seconds, _ = run(["design", tiny, "--out", os.path.join(WORK, "timing"), "--quiet"])
    for k in range(8):
        delay = full_seconds * (0.6 + 0.06 * k)
        with open(os.devnull, "wb") as null:
            p = subprocess.Popen([FREEFORM, "design", tiny, "--out", design_out, "--quiet", "--seed", str(20 + k)],
                                 stdout=null, stderr=null, cwd=WORK)
            time.sleep(delay)
            p.send_signal(signal.SIGKILL)
            p.wait()
        files = snapshot(design_out)
        if "metrics.json" in files and complete(design_out, DESIGN_FILES):
            fail(f"SIGKILL after {delay:.2f} s: metrics.json beside {complete(design_out, DESIGN_FILES)}")
        seeds = {json.loads(files["metrics.json"]).get("seed")} if "metrics.json" in files else set()
        print(f"ok   SIGKILL after {delay:.2f} s: {'complete results of seed ' + str(seeds) if seeds else 'no metrics.json'}")

print(f"{len(failures)} failure(s)")
sys.exit(1 if failures else 0)

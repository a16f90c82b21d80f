"""Shared set-up of the Python module's tests (ctest `python`; docs/python.md).

ctest sets PYTHONPATH to the built module and FREEFORM_CLI to the command line the tests
compare with. Run by hand from the repository root:

    PYTHONPATH=build/release/python FREEFORM_CLI=build/release/bin/freeform \
        /usr/bin/python3 -m pytest -q tests/python
"""
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
SCENES = HERE / "scenes"
REPO = HERE.parent.parent


def cli_path():
    path = os.environ.get("FREEFORM_CLI") or str(REPO / "build" / "release" / "bin" / "freeform")
    if not Path(path).is_file():
        pytest.fail("the command line is not at %s (set FREEFORM_CLI)" % path)
    return path


def run_cli(*args, expect=0, cwd=None):
    """Runs `freeform ARGS`; returns (stdout, stderr). An ASan build preloads the sanitizer's
    runtime into Python; the command line has its own, so the preload is dropped for it."""
    env = {k: v for k, v in os.environ.items() if k not in ("LD_PRELOAD", "PYTHONMALLOC")}
    done = subprocess.run([cli_path(), *map(str, args)], capture_output=True, text=True, env=env, cwd=cwd,
                          timeout=300)
    if expect is not None and done.returncode != expect:
        raise AssertionError("freeform %s: exit %d, expected %d\n%s%s" % (
            " ".join(map(str, args)), done.returncode, expect, done.stdout, done.stderr))
    return done.stdout, done.stderr


def cli_error(*args, cwd=None):
    """The one-line message the command line prints for bad input (exit code 2)."""
    _, err = run_cli(*args, expect=2, cwd=cwd)
    line = err.strip()
    assert line.startswith("freeform: "), err
    return line[len("freeform: "):]


def read_pfm(path):
    """A PFM file as a float32 array, row 0 the image's top (the file stores the bottom row first)."""
    data = Path(path).read_bytes()
    parts = data.split(b"\n", 3)
    assert parts[0] == b"Pf", "a grey PFM"
    width, height = map(int, parts[1].split())
    scale = float(parts[2])
    values = np.frombuffer(parts[3], dtype="<f4" if scale < 0 else ">f4", count=width * height)
    return values.reshape(height, width)[::-1].astype(np.float32)


def write_pfm(path, image):
    """A 2-D array as a grey little-endian PFM file (row 0 the image's top)."""
    image = np.asarray(image, dtype="<f4")
    header = b"Pf\n%d %d\n-1.0\n" % (image.shape[1], image.shape[0])
    Path(path).write_bytes(header + image[::-1].tobytes())


TIMING = ("seconds", "per_second")


def without_timings(value):
    """metrics.json without its clock readings (every key naming seconds), which differ run to run."""
    if isinstance(value, dict):
        return {k: without_timings(v) for k, v in value.items() if not any(t in k for t in TIMING)}
    if isinstance(value, list):
        return [without_timings(v) for v in value]
    return value


@pytest.fixture(scope="session")
def ff():
    import freeform
    return freeform


@pytest.fixture(scope="session")
def tiny_path():
    return str(SCENES / "tiny.json")


@pytest.fixture(scope="session")
def cli_design(tmp_path_factory, tiny_path):
    """The tiny scene designed by the command line (seed 7, 2 threads): its folder."""
    out = tmp_path_factory.mktemp("cli-design")
    run_cli("design", tiny_path, "--out", out, "--seed", 7, "--threads", 2, "--quiet")
    return out


@pytest.fixture(scope="session")
def py_design(ff, tiny_path):
    """The same design from Python."""
    return ff.design(ff.Scene.load(tiny_path), seed=7, threads=2)


def load_json(path):
    return json.loads(Path(path).read_text())

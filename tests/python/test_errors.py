"""Bad input raises a Python exception with a message naming what is wrong, never a crash.

Each case is checked before any design work starts, so the list runs in a second. Where
the command line has the same input (an option's value, a scene without a target), the
message is the command line's."""
import json
import math

import numpy as np
import pytest

from conftest import SCENES, cli_error


@pytest.fixture(scope="module")
def tiny(ff):
    return ff.Scene.load(str(SCENES / "tiny.json"))


@pytest.fixture(scope="module")
def no_target(ff):
    return ff.Scene.load(str(SCENES / "no-target.json"))


def good_target():
    t = np.zeros((32, 32))
    t[8:24, 8:24] = 1
    return t


# (name, call(ff, tiny, no_target), exception, message pattern)
CASES = [
    # targets given as arrays
    ("target complex", lambda ff, s, n: ff.design(n, good_target() + 0j), TypeError, r"^target: .*complex128"),
    ("target bool", lambda ff, s, n: ff.design(n, good_target() > 0), TypeError, r"^target: .*bool"),
    ("target strings", lambda ff, s, n: ff.design(n, np.array([["a", "b"], ["c", "d"]])), TypeError,
     r"^target: .*dtype"),
    ("target object", lambda ff, s, n: ff.design(n, {"not": "an image"}), TypeError, r"^target: "),
    ("target 1-D", lambda ff, s, n: ff.design(n, np.ones(32)), ValueError, r"^target: expected a 2-D array"),
    ("target RGB", lambda ff, s, n: ff.design(n, np.ones((32, 32, 3))), ValueError,
     r"^target: expected a 2-D array .* got 3"),
    ("target empty", lambda ff, s, n: ff.design(n, np.ones((0, 32))), ValueError, r"^target: the array is empty"),
    ("target NaN", lambda ff, s, n: ff.design(n, np.where(good_target() > 0, np.nan, 0)), ValueError,
     r"^target: the array has non-finite values$"),
    ("target inf", lambda ff, s, n: ff.design(n, np.where(good_target() > 0, np.inf, 0)), ValueError,
     r"^target: the array has non-finite values$"),
    ("target negative", lambda ff, s, n: ff.design(n, good_target() - 0.5), ValueError,
     r"^target: the array has negative values$"),
    ("target negative int", lambda ff, s, n: ff.design(n, np.full((4, 4), -1, dtype=np.int8)), ValueError,
     r"^target: the array has negative values$"),
    ("target black", lambda ff, s, n: ff.design(n, np.zeros((32, 32), dtype=np.uint16)), ValueError,
     r"^target: the array is entirely black$"),
    # the design's options
    ("time_budget 0", lambda ff, s, n: ff.design(s, time_budget=0), ValueError, r"^time_budget: must be > 0"),
    ("time_budget NaN", lambda ff, s, n: ff.design(s, time_budget=math.nan), ValueError,
     r"^time_budget: must be > 0"),
    ("time_budget inf", lambda ff, s, n: ff.design(s, time_budget=math.inf), ValueError,
     r"^time_budget: must be > 0"),
    ("time_budget text", lambda ff, s, n: ff.design(s, time_budget="10"), TypeError, r"design\(\)"),
    ("seed negative", lambda ff, s, n: ff.design(s, seed=-1), ValueError, r"^seed: must be >= 0, got -1$"),
    ("seed float", lambda ff, s, n: ff.design(s, seed=1.5), TypeError, r"design\(\)"),
    ("threads negative", lambda ff, s, n: ff.design(s, threads=-2), ValueError, r"^threads: must be in \[0, 65536\]"),
    ("threads too many", lambda ff, s, n: ff.design(s, threads=100000), ValueError, r"^threads: must be in"),
    ("progress not callable", lambda ff, s, n: ff.design(s, progress=5), TypeError, r"^progress: expected a function"),
    ("scene as a path", lambda ff, s, n: ff.design(str(SCENES / "tiny.json")), TypeError, r"design\(\)"),
    ("seed positional", lambda ff, s, n: ff.design(s, None, 10), TypeError, r"design\(\)"),
    # scenes
    ("from_json number", lambda ff, s, n: ff.Scene.from_json(42), TypeError, r"^Scene.from_json: expected a dict"),
    ("from_json bad JSON", lambda ff, s, n: ff.Scene.from_json("{"), ValueError, r"^scene: invalid JSON at line 1"),
    ("from_json NaN", lambda ff, s, n: ff.Scene.from_json({"light": {"type": "collimated", "rays_per_cell": math.nan},
                                                           "surface": {}, "receiver": {}}),
     ValueError, r"^scene: invalid JSON"),
    ("from_json set", lambda ff, s, n: ff.Scene.from_json({"light": {1, 2}}), TypeError, r"not JSON serializable"),
    ("from_json list", lambda ff, s, n: ff.Scene.from_json([1, 2]), TypeError, r"expected a dict"),
    ("load a folder", lambda ff, s, n: ff.Scene.load(str(SCENES)), OSError, r"not a regular file"),
    ("load None", lambda ff, s, n: ff.Scene.load(None), TypeError, r"load\(\)"),
    ("missing font", lambda ff, s, n: ff.design(ff.Scene.from_json(
        {"light": {"type": "collimated"}, "surface": {"mesh": [9, 9]}, "receiver": {"resolution": [8, 8]},
         "target": {"text": "E", "font": "NoSuchFontAnywhere"}})), FileNotFoundError, r"NoSuchFontAnywhere"),
    # optimise.device: this module offers no device (only a program built with nvcc can, docs/cuda.md)
    ("device cuda", lambda ff, s, n: ff.design(ff.Scene.from_json(
        {"light": {"type": "collimated"}, "surface": {"mesh": [9, 9]}, "receiver": {"resolution": [8, 8]},
         "target": {"text": "E"}, "optimise": {"device": "cuda"}})), ValueError,
     r'^optimise\.device: "cuda" asked for, but the program running this design offers no CUDA device'),
    ("device unknown", lambda ff, s, n: ff.Scene.from_json(
        {"light": {"type": "collimated"}, "surface": {}, "receiver": {}, "optimise": {"device": "gpu"}}),
     ValueError, r"optimise\.device"),
    # render inputs
    ("heightmap NaN", lambda ff, s, n: ff.render(s, np.full((17, 17), np.nan)), ValueError,
     r"^heightmap: the array has a non-finite value at row 0, column 0$"),
    ("heightmap 1 x 5", lambda ff, s, n: ff.render(s, np.zeros((1, 5))), ValueError,
     r"^heightmap: the array is 5 x 1 pixels; at least 2 x 2 are needed$"),
    ("heightmap 3-D", lambda ff, s, n: ff.render(s, np.zeros((4, 4, 4))), ValueError, r"^heightmap: expected a 2-D"),
    ("heightmap complex", lambda ff, s, n: ff.render(s, np.zeros((4, 4), dtype=complex)), TypeError,
     r"^heightmap: expected an array of floats or integers"),
    ("heightmap and mesh", lambda ff, s, n: ff.render(s, np.zeros((4, 4)), (np.zeros((3, 3)), [[0, 1, 2]])),
     ValueError, r"^heightmap and mesh are alternatives"),
    ("mesh not a pair", lambda ff, s, n: ff.render(s, mesh=np.zeros((3, 3))), TypeError,
     r"^mesh: expected \(vertices, triangles\)"),
    ("mesh index out of range", lambda ff, s, n: ff.render(s, mesh=(np.zeros((3, 3)), [[0, 1, 3]])), ValueError,
     r"^mesh triangles: triangle 0 refers to vertex 3 of 3$"),
    ("mesh negative index", lambda ff, s, n: ff.render(s, mesh=(np.zeros((3, 3)), [[0, -1, 2]])), ValueError,
     r"^mesh triangles: triangle 0 refers to vertex -1 of 3$"),
    ("mesh float indices", lambda ff, s, n: ff.render(s, mesh=(np.zeros((3, 3)), [[0.0, 1.0, 2.0]])), TypeError,
     r"^mesh triangles: expected an array of integers"),
    ("mesh vertices N x 2", lambda ff, s, n: ff.render(s, mesh=(np.zeros((3, 2)), [[0, 1, 2]])), ValueError,
     r"^mesh vertices: expected an N x 3 array, got 3 x 2$"),
    ("mesh vertex inf", lambda ff, s, n: ff.render(s, mesh=(np.array([[0, 0, 0], [1, 0, 0], [0, np.inf, 0]]),
                                                            [[0, 1, 2]])),
     ValueError, r"^mesh vertices: vertex 2 has a non-finite coordinate$"),
    ("mesh no triangles", lambda ff, s, n: ff.render(s, mesh=(np.zeros((3, 3)), np.zeros((0, 3), dtype=int))),
     ValueError, r"^mesh triangles: expected an M x 3 array with M >= 1$"),
    ("render seed negative", lambda ff, s, n: ff.render(s, seed=-3), ValueError, r"^seed: must be >= 0"),
    ("render target NaN", lambda ff, s, n: ff.render(s, target=np.full((3, 3), np.nan)), ValueError,
     r"^target: the array has non-finite values$"),
]


@pytest.mark.parametrize("name,call,exception,pattern", CASES, ids=[c[0] for c in CASES])
def test_bad_input_raises(ff, tiny, no_target, name, call, exception, pattern):
    with pytest.raises(exception, match=pattern):
        call(ff, tiny, no_target)


def test_enough_cases():
    assert len(CASES) >= 20


def test_design_without_a_target_says_what_the_command_line_says(ff, tmp_path):
    path = SCENES / "no-target.json"
    expected = cli_error("design", path, "--out", tmp_path / "out")
    with pytest.raises(ValueError) as e:
        ff.design(ff.Scene.load(str(path)))
    assert str(e.value) == expected


def test_time_budget_message_is_the_command_lines(ff, tmp_path):
    expected = cli_error("design", SCENES / "tiny.json", "--out", tmp_path / "out", "--time-budget", "0")
    with pytest.raises(ValueError) as e:
        ff.design(ff.Scene.load(str(SCENES / "tiny.json")), time_budget=0)
    assert str(e.value).replace("time_budget", "--time-budget").startswith(expected)


def test_write_into_a_file_raises_oserror(py_design, tmp_path):
    d = py_design
    (tmp_path / "file").write_text("in the way")
    with pytest.raises(OSError, match="cannot create the output folder"):
        d.write(tmp_path / "file")
    (tmp_path / "out" / "metrics.json").mkdir(parents=True)
    with pytest.raises(OSError, match="a folder of that name is in the way"):
        d.write(tmp_path / "out")
    assert json.loads(json.dumps(d.metrics)) == d.metrics

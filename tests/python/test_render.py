"""freeform.render against `freeform render`: the same image and metrics."""
import numpy as np

from conftest import SCENES, load_json, read_pfm, run_cli, without_timings


def compare(irradiance, metrics, folder):
    from_file = read_pfm(folder / "irradiance.pfm")
    assert irradiance.dtype == np.float64 and irradiance.shape == from_file.shape
    assert np.array_equal(irradiance.astype(np.float32), from_file)
    assert without_timings(metrics) == without_timings(load_json(folder / "metrics.json"))


def test_render_of_a_heightmap_equals_the_command_lines(ff, py_design, cli_design, tmp_path):
    scene = str(SCENES / "tiny.json")
    run_cli("render", scene, "--heightmap", cli_design / "heightmap.pfm", "--out", tmp_path, "--threads", 2)
    irradiance, metrics = ff.render(ff.Scene.load(scene), py_design.heightmap, threads=2)
    compare(irradiance, metrics, tmp_path)
    assert metrics["command"] == "render" and metrics["scene"] == scene
    assert metrics["error_physical"] > 0 and irradiance.sum() > 0


def test_render_of_a_mesh_equals_the_command_lines(ff, py_design, cli_design, tmp_path):
    scene = str(SCENES / "tiny.json")
    run_cli("render", scene, "--mesh", cli_design / "surface.obj", "--out", tmp_path, "--threads", 1, "--seed", 4)
    irradiance, metrics = ff.render(ff.Scene.load(scene), mesh=py_design.mesh, threads=1, seed=4)
    compare(irradiance, metrics, tmp_path)
    assert metrics["tracer"] == "embree"


def test_render_of_the_scenes_start_equals_the_command_lines(ff, tmp_path):
    scene = str(SCENES / "no-target.json")
    run_cli("render", scene, "--out", tmp_path, "--threads", 2)
    irradiance, metrics = ff.render(ff.Scene.load(scene), threads=2)
    compare(irradiance, metrics, tmp_path)
    assert irradiance.shape == (32, 32)
    assert "error" not in metrics  # no target: nothing to judge against


def test_render_with_a_target_array(ff, py_design):
    scene = ff.Scene.load(str(SCENES / "no-target.json"))
    irradiance, metrics = ff.render(scene, py_design.heightmap, target=py_design.target, threads=2)
    assert metrics["effective_scene"]["target"] == {"image": "(NumPy array, 32 x 32)", "upsample": "bilinear"}
    # The design's own surface against its own target: close to the design's figure.
    assert abs(metrics["error_physical"] - py_design.metrics["export"]["forms"]["designed"]["error_physical"]) < 0.02

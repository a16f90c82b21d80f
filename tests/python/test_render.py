"""freeform.render against `freeform render`: the same image and metrics."""
import json

import numpy as np

from conftest import SCENES, load_json, read_pfm, run_cli, without_timings, write_pfm


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
    assert metrics["effective_scene"]["target"] == {"image": "(NumPy array, 32 x 32)", "upsample": "bilinear",
                                                    "fit": "stretch"}
    # The design's own surface against its own target: close to the design's figure.
    assert abs(metrics["error_physical"] - py_design.metrics["export"]["forms"]["designed"]["error_physical"]) < 0.02


def test_a_target_array_is_framed_by_the_scenes_target_fit(ff, py_design, cli_design, tmp_path):
    # A 48 x 32 picture (wider than the square receiver): the scene's image target says
    # "contain", and an array of the same values is laid on the receiver the same way.
    picture = np.zeros((32, 48))
    picture[8:24, 4:44] = np.linspace(0.25, 1.0, 40).astype(np.float32)  # as the PFM file stores it
    write_pfm(tmp_path / "wide.pfm", picture)
    scene_json = load_json(SCENES / "no-target.json")
    scene_json["target"] = {"image": str(tmp_path / "wide.pfm"), "fit": "contain"}
    (tmp_path / "scene.json").write_text(json.dumps(scene_json))
    out = tmp_path / "out"
    run_cli("render", tmp_path / "scene.json", "--heightmap", cli_design / "heightmap.pfm", "--out", out,
            "--threads", 2)
    from_file = load_json(out / "metrics.json")
    scene = ff.Scene.load(str(tmp_path / "scene.json"))
    _, contained = ff.render(scene, py_design.heightmap, target=picture, threads=2)
    assert contained["effective_scene"]["target"]["fit"] == "contain"
    assert contained["error_physical"] == from_file["error_physical"]
    scene_json["target"]["fit"] = "stretch"
    _, stretched = ff.render(ff.Scene.from_json(scene_json), py_design.heightmap, target=picture, threads=2)
    assert abs(stretched["error_physical"] - contained["error_physical"]) > 1e-3

"""freeform.Scene: loading, the JSON round trip, and the command line's messages."""
import json

import pytest

from conftest import SCENES, cli_error, load_json, run_cli


def test_round_trip_through_to_json_and_from_json(ff, tmp_path):
    scene = ff.Scene.load(str(SCENES / "tiny.json"))
    first = scene.to_json()
    # What the file says, every default written out beside it.
    assert first["receiver"]["resolution"] == [32, 32]
    assert first["surface"]["mesh"] == [17, 17]
    assert first["optimise"]["max_iterations"] == 1500 and first["optimise"]["seed"] == 5
    assert first["target"] == {"text": "E", "font": "DejaVuSans-Bold", "margin": 0.1}
    assert first["surface"]["material"] == "mirror" and "phong_alpha" in first["surface"]
    assert ff.Scene.from_json(first).to_json() == first
    assert ff.Scene.from_json(json.dumps(first)).to_json() == first
    assert scene.path == str(SCENES / "tiny.json")
    assert ff.Scene.from_json(first).path is None
    # The command line reads the written scene back to the same effective scene.
    (tmp_path / "again.json").write_text(json.dumps(first))
    run_cli("render", tmp_path / "again.json", "--out", tmp_path / "r", "--threads", 1)
    rendered = load_json(tmp_path / "r" / "metrics.json")["effective_scene"]
    rendered["light"]["rays_per_cell"] = first["light"]["rays_per_cell"]  # raised for the mesh by a render
    assert rendered == first


def test_from_json_resolves_files_against_base_dir(ff, tmp_path):
    (tmp_path / "t.pgm").write_bytes(b"P5 2 2 255\n" + bytes([0, 10, 20, 30]))
    data = {"light": {"type": "collimated"}, "surface": {}, "receiver": {}, "target": {"image": "t.pgm"}}
    scene = ff.Scene.from_json(data, base_dir=str(tmp_path))
    assert scene.to_json()["target"]["image"] == str(tmp_path / "t.pgm")
    with pytest.raises(FileNotFoundError, match=r"^scene: target.image: file not found: "):
        ff.Scene.from_json(data, base_dir=str(tmp_path / "elsewhere"))


# Bad scenes: Scene.load must raise what the command line prints, word for word, and
# Scene.from_json the same with "scene" for the file's name.
BAD_SCENES = {
    "unknown-key": {"light": {"type": "collimated"}, "surface": {"colour": 1}, "receiver": {}},
    "wrong-type": {"light": {"type": "collimated"}, "surface": {"size": "big"}, "receiver": {}},
    "negative-size": {"light": {"type": "collimated"}, "surface": {"size": [0.1, -0.1]}, "receiver": {}},
    "bad-resolution": {"light": {"type": "collimated"}, "surface": {}, "receiver": {"resolution": [0, 10]}},
    "no-light": {"surface": {}, "receiver": {}},
    "bad-light-type": {"light": {"type": "laser"}, "surface": {}, "receiver": {}},
    "inverted-bounds": {"light": {"type": "collimated"}, "surface": {"height_bounds": [0.01, -0.01]},
                        "receiver": {}},
    "target-both": {"light": {"type": "collimated"}, "surface": {}, "receiver": {},
                    "target": {"text": "E", "image": "e.png"}},
    "bad-optimise": {"light": {"type": "collimated"}, "surface": {}, "receiver": {},
                     "optimise": {"time_budget": -1}},
}


@pytest.mark.parametrize("name", sorted(BAD_SCENES))
def test_bad_scene_raises_the_command_lines_message(ff, tmp_path, name):
    path = tmp_path / (name + ".json")
    path.write_text(json.dumps(BAD_SCENES[name]))
    expected = cli_error("render", path, "--out", tmp_path / "out")
    assert expected.startswith(str(path) + ": ")
    with pytest.raises(ValueError) as e:
        ff.Scene.load(str(path))
    assert str(e.value) == expected
    with pytest.raises(ValueError) as e:
        ff.Scene.from_json(BAD_SCENES[name])
    assert str(e.value) == "scene: " + expected[len(str(path)) + 2:]


def test_syntax_error_names_line_and_column(ff, tmp_path):
    path = tmp_path / "syntax.json"
    path.write_text('{\n  "light": {"type": "collimated"},\n  "surface": {,\n}')
    expected = cli_error("render", path, "--out", tmp_path / "out")
    with pytest.raises(ValueError) as e:
        ff.Scene.load(str(path))
    assert str(e.value) == expected and "line 3" in expected
    with pytest.raises(ValueError, match=r"^scene: invalid JSON at line 3"):
        ff.Scene.from_json(path.read_text())


def test_missing_files(ff, tmp_path):
    missing = tmp_path / "no-such-scene.json"
    expected = cli_error("render", missing, "--out", tmp_path / "out")
    with pytest.raises(FileNotFoundError) as e:
        ff.Scene.load(str(missing))
    assert str(e.value) == expected
    path = tmp_path / "target-missing.json"
    path.write_text(json.dumps({"light": {"type": "collimated"}, "surface": {}, "receiver": {},
                                "target": {"image": "nowhere.png"}}))
    expected = cli_error("render", path, "--out", tmp_path / "out")
    with pytest.raises(FileNotFoundError) as e:
        ff.Scene.load(path)  # a pathlib.Path works too
    assert str(e.value) == expected

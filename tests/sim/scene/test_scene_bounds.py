"""Scene files are bounded before they cost anything: objects per scene, label and name
lengths, indices, coordinates (finite, within reach) and the cells of the navigation grid.
Each limit is one ``error:`` line with exit code 2 through ``storyteller scene inspect`` (and
``event-program``, whose worker used to print a traceback for a floor of 8e9 cells)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from storyteller.orchestrator.cli.app import app
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.errors import SceneFileError
from storyteller.sim.scene.files import load_scene, save_scene_json
from storyteller.sim.scene.meshes import MAX_NODE_NAME_CHARS, parse_instance_name
from storyteller.sim.scene.model import MAX_LABEL_CHARS, MAX_NAV_CELLS, MAX_SCENE_OBJECTS
from storyteller.sim.scene.strict_json import MAX_SCENE_FILE_BYTES
from tests.support.finished_run import one_error_line

runner = CliRunner()


def scene_doc(tmp_path: Path) -> dict[str, Any]:
    path = tmp_path / "home.json"
    save_scene_json(load_bundled_scene("home"), path)
    doc: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    return doc


def write(tmp_path: Path, doc: Any, name: str = "scene.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(doc), encoding="utf-8")
    return path


def inspect(path: Path) -> str:
    return one_error_line(runner.invoke(app, ["scene", "inspect", str(path)]))


def box(i: int, label: str = "box") -> dict[str, Any]:
    return {"name": f"{label}_{i}", "label": label, "idx": i, "center": [1.0, 1.0, 0.5], "size": [0.5, 0.5, 1.0]}


def test_a_floor_of_8e9_cells_is_one_line_before_any_grid(tmp_path: Path) -> None:
    doc = scene_doc(tmp_path)
    doc["bounds_max"] = [30_000.0, 30_000.0]  # 0.3 m cells: 1e10 cells (a grid would need ~100 GB)
    doc["nav"]["cell_size"] = 0.3
    line = inspect(write(tmp_path, doc))
    assert "navigation cells" in line and f"{MAX_NAV_CELLS:,}" in line


def test_event_program_on_a_floor_of_8e9_cells_is_one_line_not_a_worker_traceback(tmp_path: Path) -> None:
    doc = scene_doc(tmp_path)
    doc["nav"]["cell_size"] = 0.001  # 8e9 cells over the home floor
    program = tmp_path / "p.py"
    program.write_text("def parse_event():\n    pass\n", encoding="utf-8")
    result = runner.invoke(app, ["event-program", str(write(tmp_path, doc)), "--program", str(program)])
    assert "navigation cells" in one_error_line(result)


def test_too_many_objects(tmp_path: Path) -> None:
    doc = scene_doc(tmp_path)
    doc["objects"] = [box(i) for i in range(MAX_SCENE_OBJECTS + 1)]
    assert f"at most {MAX_SCENE_OBJECTS}" in inspect(write(tmp_path, doc))
    doc["objects"] = doc["objects"][:MAX_SCENE_OBJECTS]  # the limit itself loads
    assert len(load_scene(write(tmp_path, doc)).objects) == MAX_SCENE_OBJECTS


def test_too_many_reference_objects(tmp_path: Path) -> None:
    objects = [
        {"label": "box", "idx": i, "center": [1.0, 1.0, 0.5], "width": 0.5, "depth": 0.5, "height": 1.0,
         "orientation": [0.0, 1.0]}
        for i in range(MAX_SCENE_OBJECTS + 1)
    ]
    folder = tmp_path / "room"
    folder.mkdir()
    write(folder, objects, "objects.json")
    assert f"at most {MAX_SCENE_OBJECTS}" in inspect(folder)


def test_a_long_label_and_a_huge_index(tmp_path: Path) -> None:
    doc = scene_doc(tmp_path)
    label = "a" * (MAX_LABEL_CHARS + 1)
    doc["objects"] = [box(1, label)]
    line = inspect(write(tmp_path, doc))
    assert "at most" in line and len(line) < 500
    doc["objects"] = [{**box(1), "idx": 10**12, "name": f"box_{10**12}"}]
    assert "idx" in inspect(write(tmp_path, doc))


@pytest.mark.parametrize("bad", ["NaN", "Infinity", "-Infinity", "1e999", "1e6"])
def test_coordinates_are_finite_and_within_reach(tmp_path: Path, bad: str) -> None:
    doc = scene_doc(tmp_path)
    doc["objects"][0]["center"] = "BAD"
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(doc).replace('"BAD"', f"[{bad}, 1.0, 0.5]"), encoding="utf-8")
    assert "center" in inspect(path)


def test_deeply_nested_json_and_an_oversized_file(tmp_path: Path) -> None:
    path = tmp_path / "deep.json"
    path.write_text('{"objects": ' + "[" * 100_000 + "]" * 100_000 + "}", encoding="utf-8")
    assert "nested" in inspect(path)
    big = tmp_path / "big.json"
    with big.open("wb") as f:  # sparse: no disk used
        f.truncate(MAX_SCENE_FILE_BYTES + 1)
    assert "allowed" in inspect(big)


def test_a_mesh_node_name_of_60000_digits(tmp_path: Path) -> None:
    path = tmp_path / "long.obj"
    name = "a" + "1" * 60_000 + "b"
    path.write_text(f"o {name}\nv 0 0 0\nv 1 0 0\nv 0 1 1\nf 1 2 3\n", encoding="utf-8")
    assert f"at most {MAX_NODE_NAME_CHARS}" in inspect(path)


def test_a_mesh_index_of_many_digits(tmp_path: Path) -> None:
    path = tmp_path / "index.obj"
    path.write_text(f"o chair_{'9' * 150}\nv 0 0 0\nv 1 0 0\nv 0 1 1\nf 1 2 3\n", encoding="utf-8")
    assert "idx" in inspect(path)


def test_instance_names_parse_in_one_scan() -> None:
    """The scan that replaced ``([a-z][a-z0-9]*?)(\\d+)`` (quadratic on a letter, digits and a
    letter) gives the names it gave."""
    cases = {
        "chair3": ("chair", 3), "a1b": ("a1b", None), "tv2stand10": ("tv2stand", 10), "x": ("x", None),
        "Chair.003": ("chair", 3), "CoffeeMaker-2": ("coffee_maker", 2), "12": ("object", 12),
    }
    for raw, expected in cases.items():
        assert parse_instance_name(raw) == expected
    label, idx = parse_instance_name("a" + "1" * 3000 + "b")
    assert idx is None and len(label) == 3002


def test_scene_file_errors_stay_short() -> None:
    err = SceneFileError("x.json", "bad", obj="n" * 10_000, field="f" * 10_000)
    assert len(str(err)) < 400

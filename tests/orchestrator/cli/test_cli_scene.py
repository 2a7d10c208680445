"""``storyteller scene list`` / ``scene inspect``: tables, JSON, PNG, and one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib
import pytest
from matplotlib.image import imread
from typer.testing import CliRunner

from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.cli.scene import MAX_TABLE_RELATIONS
from storyteller.sim.scene.bundled import load_bundled_scene
from tests.support.reference import SCENES, requires_reference

runner = CliRunner()


def test_scene_list() -> None:
    result = runner.invoke(app, ["scene", "list"])
    assert result.exit_code == 0
    assert result.stdout.split() == ["home", "office", "restaurant"]


def test_inspect_tables() -> None:
    result = runner.invoke(app, ["scene", "inspect", "home"])
    assert result.exit_code == 0, result.output
    out = result.stdout
    for part in (
        "home: 32 objects",
        "Objects",
        "Relations",
        "Clusters",
        "Navigation grid",
        "coffee_maker_1",
        "cabinet_1",
    ):
        assert part in out
    assert result.stderr == ""


@pytest.mark.parametrize("name", ["home", "office", "restaurant"])
def test_inspect_json(name: str) -> None:
    result = runner.invoke(app, ["scene", "inspect", name, "--json"])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)  # exactly one JSON document
    scene = load_bundled_scene(name)
    assert data["scene"] == name
    assert [o["name"] for o in data["objects"]] == scene.object_names
    for entry in data["objects"]:
        obj = scene.get(entry["name"])
        assert entry["label"] == obj.label
        assert entry["center"] == pytest.approx(obj.center, abs=1e-4)
        assert entry["size"] == pytest.approx(obj.size, abs=1e-4)
        assert entry["facing"] == pytest.approx(obj.facing, abs=1e-4)
    names = set(scene.object_names)
    assert data["relations"] and all(
        len(t) == 3 and t[0] in names and t[2] in names for t in data["relations"]
    )
    assert sorted(n for c in data["clusters"] for n in c) == sorted(names)
    grid = data["grid"]
    assert grid["cell_size"] == pytest.approx(0.3)
    assert grid["free_cells"] + grid["blocked_cells"] == grid["shape"][0] * grid["shape"][1]
    assert 0 < grid["main_component_cells"] <= grid["free_cells"]


def test_inspect_json_home_relations() -> None:
    data = json.loads(runner.invoke(app, ["scene", "inspect", "home", "--json"]).stdout)
    assert ["coffee_maker_1", "on", "cabinet_1"] in data["relations"]
    assert ["microwave_1", "on", "cabinet_2"] in data["relations"]


def test_inspect_table_shows_the_first_relations_of_many(tmp_path: Path) -> None:
    """60 packed boxes have thousands of relations: the table shows the first MAX_TABLE_RELATIONS
    and says so, ``--json`` lists them all (the table of 16,000 took 15 s to draw)."""
    objects = [{"name": f"box_{i}", "label": "box", "idx": i, "center": [i % 8 * 0.3, i // 8 * 0.3, 0.1],
                "size": [0.2, 0.2, 0.2]} for i in range(60)]
    path = tmp_path / "packed.json"
    path.write_text(json.dumps({"name": "packed", "bounds_min": [-1, -1], "bounds_max": [4, 4], "objects": objects}))
    relations = json.loads(runner.invoke(app, ["scene", "inspect", str(path), "--json"]).stdout)["relations"]
    assert len(relations) > MAX_TABLE_RELATIONS
    result = runner.invoke(app, ["scene", "inspect", str(path)])
    assert result.exit_code == 0, result.output
    table = result.stdout.split(f"Relations ({len(relations)})")[1].split("Clusters (")[0]
    assert f"(the first {MAX_TABLE_RELATIONS} of {len(relations)} relations shown; --json lists all)" in table
    rows = [line.split("│")[1:4] for line in table.splitlines() if line.startswith("│")]
    assert [[cell.strip() for cell in row] for row in rows] == relations[:MAX_TABLE_RELATIONS]


@requires_reference
@pytest.mark.slow
def test_inspect_reference_folder_with_png(tmp_path: Path) -> None:
    png = tmp_path / "house.png"
    result = runner.invoke(
        app, ["scene", "inspect", str(SCENES / "House"), "--json", "--png", str(png)]
    )
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    assert len(data["objects"]) == 23 and data["png"] == str(png)
    assert ["coffee_maker_1", "on", "cabinet_1"] in data["relations"]
    image = imread(png)
    assert image.ndim == 3 and image.shape[0] > 200 and image.shape[1] > 200
    assert np.unique(image.reshape(-1, image.shape[2]), axis=0).shape[0] > 20  # a real picture


def test_inspect_png_with_tables(tmp_path: Path) -> None:
    png = tmp_path / "office.png"
    result = runner.invoke(app, ["scene", "inspect", "office", "--png", str(png)])
    assert result.exit_code == 0
    assert f"wrote {png}" in result.stdout and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _glb_without_nodes(path: Path) -> Path:
    pygltflib.GLTF2(scenes=[pygltflib.Scene(nodes=[])], scene=0).save_binary(str(path))
    return path


def _scene_json(
    tmp: Path, edit: Callable[[dict[str, Any]], None] | None = None, text: Callable[[str], str] | None = None
) -> Path:
    data = json.loads(load_bundled_scene("home").model_dump_json())
    if edit is not None:
        edit(data)
    body = json.dumps(data)
    if text is not None:
        body = text(body)
    path = tmp / "scene.json"
    path.write_text(body, encoding="utf-8")
    return path


def _file(path: Path, content: bytes) -> Path:
    path.write_bytes(content)
    return path


def _folder(path: Path) -> Path:
    path.mkdir()
    return path


def _dup(data: dict[str, Any]) -> None:
    data["objects"].append(dict(data["objects"][0]))


BAD: list[tuple[str, Callable[[Path], Path], str]] = [
    ("missing-field", lambda t: _scene_json(t, lambda d: d["objects"][1].pop("size")), "object 'cabinet_1', field 'size': required field is missing"),
    ("nan", lambda t: _scene_json(t, text=lambda s: s.replace('"center": [0.45', '"center": [NaN', 1)), "non-finite number 'NaN'"),
    ("duplicate", lambda t: _scene_json(t, _dup), "object 'fridge_1', field 'name': duplicate object name"),
    ("negative-size", lambda t: _scene_json(t, lambda d: d["objects"][0].update(size=[-1, 1, 1])), "object 'fridge_1', field 'size'"),
    ("unknown-key", lambda t: _scene_json(t, lambda d: d["objects"][2].update(weight=3)), "object 'dishwasher_1', field 'weight': unknown key"),
    ("truncated", lambda t: _scene_json(t, text=lambda s: s[: len(s) // 2]), "truncated"),
    ("wrong-type", lambda t: _scene_json(t, lambda d: d["objects"][0].update(has_facing="yes")), "field 'has_facing'"),
    ("empty", lambda t: _file(t / "e.json", b""), "file is empty"),
    ("binary", lambda t: _file(t / "b.json", bytes(range(256))), "binary data"),
    ("no-objects-json", lambda t: _folder(t / "folder"), "no objects.json"),
    ("glb-no-nodes", lambda t: _glb_without_nodes(t / "x.glb"), "no nodes with geometry"),
    ("not-found", lambda t: t / "nothing.json", "not a bundled scene"),
]  # fmt: skip


@pytest.mark.parametrize(("case", "build", "message"), BAD, ids=[b[0] for b in BAD])
def test_inspect_bad_scene_exits_2_with_one_line(
    tmp_path: Path, case: str, build: Callable[[Path], Path], message: str
) -> None:
    path = build(tmp_path)
    for extra in ([], ["--json"]):
        result = runner.invoke(app, ["scene", "inspect", str(path), *extra])
        assert result.exit_code == 2, result.output
        assert result.stdout == ""
        lines = result.stderr.splitlines()
        assert len(lines) == 1, result.stderr
        assert lines[0].startswith("error: ") and message in lines[0]
        assert path.name in lines[0]
        assert "Traceback" not in result.output
        assert not isinstance(result.exception, Exception) or isinstance(
            result.exception, SystemExit
        )


def test_unwritable_png_exits_2(tmp_path: Path) -> None:
    result = runner.invoke(
        app, ["scene", "inspect", "home", "--png", str(tmp_path / "no" / "such" / "dir.png")]
    )
    assert result.exit_code == 2 and len(result.stderr.splitlines()) == 1
    assert "cannot write the picture" in result.stderr
    result = runner.invoke(app, ["scene", "inspect", "home", "--png", str(tmp_path)])
    assert result.exit_code == 2 and "is a folder" in result.stderr


def test_real_process_prints_no_traceback(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text('{"name": "x", "objects": [', encoding="utf-8")
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            "from storyteller.orchestrator.cli.app import app; app()",
            "scene",
            "inspect",
            str(bad),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith(f"error: {bad}: JSON ends early")

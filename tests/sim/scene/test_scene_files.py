"""Scene files: reference folders, the project's JSON, and one clear error per bad file."""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

import pytest

from storyteller.sim.scene.bundled import bundled_scene_names, load_bundled_scene, resolve_scene
from storyteller.sim.scene.files import SceneFileError, load_reference_folder, load_scene, save_scene_json
from storyteller.sim.scene.model import Scene
from tests.support.reference import SCENES, requires_reference


# ----- good files ------------------------------------------------------------------------------
@requires_reference
@pytest.mark.parametrize(("folder", "count"), [("House", 23), ("Office", 51), ("Restaurant", 39)])
def test_reference_folders_load_unmodified(folder: str, count: int) -> None:
    scene = load_scene(SCENES / folder)
    assert scene.name == folder
    assert len(scene.objects) == count
    assert scene.bounds_min[0] == pytest.approx(0.0, abs=1e-6)
    raw = json.loads((SCENES / folder / "objects.json").read_text())
    by_name = scene.by_name
    for entry in raw:
        obj = by_name[f"{entry['label']}_{entry['idx']}"]
        assert obj.center == pytest.approx(tuple(entry["center"]))
        assert obj.size == pytest.approx((entry["width"], entry["depth"], entry["height"]))
        assert obj.has_facing is entry["has_orientation"]
        assert obj.sit_offset_horizontal == pytest.approx(entry["sit_offset_horizontal"])
        # The reference's vertical offset is a seat flag (0.2 on every seat); we store a height.
        assert obj.is_seat is (entry["sit_offset_vertical"] > 0)
        if obj.is_seat:
            assert 0.3 <= obj.sit_offset_vertical <= 0.5


@requires_reference
def test_reference_details() -> None:
    house = load_scene(
        SCENES / "House" / "objects.json"
    )  # the file works as well as its folder
    assert house.nav.cell_size == pytest.approx(0.3)
    assert house.nav.body_radius == pytest.approx(0.302)
    assert house.nav.unoccupied == ((5, 28),)
    assert house.get("coffee_maker_1").z_min == pytest.approx(0.9, abs=0.05)
    office = load_scene(SCENES / "Office")
    assert len(office.nav.occupied) > 100
    assert office.bounds_max == pytest.approx((9.57271159, 16.74502809499405))


@pytest.mark.parametrize("name", ["home", "office", "restaurant"])
def test_project_json_round_trip(name: str, tmp_path: Path) -> None:
    scene = load_bundled_scene(name)
    path = tmp_path / f"{name}.json"
    save_scene_json(scene, path)
    again = load_scene(path)
    assert again == scene
    assert again.model_dump_json() == scene.model_dump_json()


@requires_reference
def test_reference_scene_round_trips_through_project_json(tmp_path: Path) -> None:
    scene = load_scene(SCENES / "Restaurant")
    save_scene_json(scene, tmp_path / "r.json")
    assert load_scene(tmp_path / "r.json") == scene


def test_resolve_scene_by_name_and_path(tmp_path: Path) -> None:
    assert bundled_scene_names() == ["home", "office", "restaurant"]
    home = resolve_scene("home")
    save_scene_json(home, tmp_path / "copy.json")
    assert resolve_scene(tmp_path / "copy.json") == home
    assert resolve_scene(str(tmp_path / "copy.json")) == home
    with pytest.raises(SceneFileError, match=r"not a bundled scene .*home, office, restaurant"):
        resolve_scene("nowhere")
    with pytest.raises(SceneFileError, match="not a bundled scene"):
        load_bundled_scene("castle")


# ----- bad files -------------------------------------------------------------------------------
def _project(**changes: Any) -> dict[str, Any]:
    """A small valid project scene, as JSON data, with top-level changes."""
    data: dict[str, Any] = json.loads(load_bundled_scene("home").model_dump_json())
    data["objects"] = data["objects"][:3]
    data.update(changes)
    return data


def _with_object(i: int, **changes: Any) -> dict[str, Any]:
    data = _project()
    data["objects"][i].update(changes)
    return data


def _without_key(i: int, key: str) -> dict[str, Any]:
    data = _project()
    del data["objects"][i][key]
    return data


def _write(path: Path, content: str | bytes | dict[str, Any] | list[Any]) -> Path:
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif isinstance(content, str):
        path.write_text(content, encoding="utf-8")
    else:
        path.write_text(json.dumps(content), encoding="utf-8")
    return path


def _reference_folder(
    tmp: Path, mutate: Callable[[list[dict[str, Any]]], None] | None = None
) -> Path:
    """A small reference-format folder (three objects, scene.json, grid_map.json)."""
    folder = tmp / "Ref"
    folder.mkdir()
    objects = _ref_objects()
    if mutate is not None:
        mutate(objects)
    _write(folder / "objects.json", objects)
    _write(folder / "scene.json", {"bbox": [[0.0, 0.0, 0.0], [4.0, 3.0, 2.5]]})
    _write(
        folder / "grid_map.json",
        {
            "grid_step": 0.3,
            "cylinder_radius": 0.3,
            "user_modifications": {"occupied": [], "unoccupied": []},
        },
    )
    return folder


def _ref_objects() -> list[dict[str, Any]]:
    """Three objects in the reference annotation format."""
    return [
        {
            "id": i,
            "label": label,
            "idx": idx,
            "orientation": [0.0, 1.0, 0.0],
            "has_orientation": True,
            "width": 0.5,
            "depth": 0.5,
            "height": h,
            "center": [x, 1.0, h / 2],
            "sit_offset_horizontal": 0.1,
            "sit_offset_vertical": 0.45 if label == "chair" else 0.0,
            "use_this": True,
        }
        for i, (label, idx, x, h) in enumerate(
            [("chair", 1, 1.0, 0.9), ("chair", 2, 2.0, 0.9), ("table", 1, 3.0, 0.75)]
        )
    ]


def _folder(path: Path) -> Path:
    path.mkdir()
    return path


def _ref_file(tmp: Path, filename: str, content: str | dict[str, Any]) -> Path:
    """A reference folder with ``filename`` replaced by ``content``; returns the folder."""
    folder = _reference_folder(tmp)
    _write(folder / filename, content)
    return folder


def _set(i: int, key: str, value: Any) -> Callable[[list[dict[str, Any]]], None]:
    def mutate(objects: list[dict[str, Any]]) -> None:
        objects[i][key] = value

    return mutate


def _drop(i: int, key: str) -> Callable[[list[dict[str, Any]]], None]:
    def mutate(objects: list[dict[str, Any]]) -> None:
        del objects[i][key]

    return mutate


# (case id, builder returning the path to load, expected file name, object, field, message part)
BadCase = tuple[str, Callable[[Path], Path], str, str | None, str | None, str]

BAD_CASES: list[BadCase] = [
    ("json-missing-field", lambda t: _write(t / "s.json", _without_key(1, "center")), "s.json", "cabinet_1", "center", "required field is missing"),
    ("json-missing-top", lambda t: _write(t / "s.json", {k: v for k, v in _project().items() if k != "bounds_max"}), "s.json", None, "bounds_max", "required field is missing"),
    ("json-nan", lambda t: _write(t / "s.json", json.dumps(_project()).replace('"center": [0.45', '"center": [NaN')), "s.json", "fridge_1", "center", "non-finite number 'NaN'"),
    ("json-infinity", lambda t: _write(t / "s.json", json.dumps(_project()).replace('"size": [0.8', '"size": [Infinity')), "s.json", "fridge_1", "size", "non-finite number 'Infinity'"),
    ("json-overflow", lambda t: _write(t / "s.json", json.dumps(_project()).replace('"size": [0.8', '"size": [1e999')), "s.json", "fridge_1", "size", "too large"),
    ("json-neg-infinity-second-object", lambda t: _write(t / "s.json", json.dumps(_project()).replace('"center": [1.95', '"center": [-Infinity')), "s.json", "cabinet_1", "center", "non-finite number '-Infinity'"),
    ("json-nan-nameless-object", lambda t: _write(t / "s.json", json.dumps(_with_object(0, name=7)).replace('"idx": 1', '"idx": NaN', 1)), "s.json", "#0", "idx", "non-finite number 'NaN'"),
    ("json-nan-top-level", lambda t: _write(t / "s.json", json.dumps(_project()).replace('"bounds_max": [8.0', '"bounds_max": [NaN')), "s.json", None, "bounds_max", "non-finite number 'NaN'"),
    ("json-nan-nested", lambda t: _write(t / "s.json", json.dumps(_project()).replace('"cell_size": 0.3', '"cell_size": NaN')), "s.json", None, "nav.cell_size", "non-finite number 'NaN'"),
    ("json-huge-int", lambda t: _write(t / "s.json", json.dumps(_project()).replace('"idx": 1', '"idx": ' + "9" * 5000, 1)), "s.json", "fridge_1", "idx", "5000 digits"),
    ("json-duplicate-name", lambda t: _write(t / "s.json", _with_object(2, **_project()["objects"][0])), "s.json", "fridge_1", "name", "duplicate object name"),
    ("json-negative-size", lambda t: _write(t / "s.json", _with_object(0, size=[0.8, -0.7, 1.8])), "s.json", "fridge_1", "size", ">= 0"),
    ("json-unknown-key", lambda t: _write(t / "s.json", _with_object(0, colour="red")), "s.json", "fridge_1", "colour", "unknown key"),
    ("json-unknown-top-key", lambda t: _write(t / "s.json", _project(author="me")), "s.json", None, "author", "unknown key"),
    ("json-truncated", lambda t: _write(t / "s.json", json.dumps(_project())[:200]), "s.json", None, None, "truncated"),
    ("json-wrong-type-string", lambda t: _write(t / "s.json", _with_object(1, center=["1.0", 0.3, 0.45])), "s.json", "cabinet_1", "center.0", "valid number"),
    ("json-wrong-type-bool-idx", lambda t: _write(t / "s.json", _with_object(1, idx=True)), "s.json", "cabinet_1", "idx", "valid integer"),
    ("json-short-vector", lambda t: _write(t / "s.json", _with_object(1, center=[1.0, 0.3])), "s.json", "cabinet_1", "center", "too few numbers"),
    ("json-name-mismatch", lambda t: _write(t / "s.json", _with_object(1, name="cabinet_7")), "s.json", "cabinet_7", "name", "'<label>_<idx>'"),
    ("json-objects-not-list", lambda t: _write(t / "s.json", _project(objects={"a": 1})), "s.json", None, "objects", "valid array"),
    ("json-bad-bounds", lambda t: _write(t / "s.json", _project(bounds_max=[0.0, 5.0])), "s.json", None, None, "bounds_max must be greater"),
    ("json-duplicate-key", lambda t: _write(t / "s.json", '{"name": "a", "name": "b"}'), "s.json", None, None, "appears twice"),
    ("json-top-level-list", lambda t: _write(t / "s.json", [1, 2]), "s.json", None, None, "expected a JSON object"),
    ("empty-file", lambda t: _write(t / "s.json", ""), "s.json", None, None, "file is empty"),
    ("whitespace-file", lambda t: _write(t / "s.json", "  \n "), "s.json", None, None, "file is empty"),
    ("binary-garbage", lambda t: _write(t / "s.json", bytes(range(256)) * 4), "s.json", None, None, "binary data"),
    ("latin1-text", lambda t: _write(t / "s.json", '{"name": "caf\xe9"}'.encode("latin-1")), "s.json", None, None, "not UTF-8"),
    ("missing-file", lambda t: t / "absent.json", "absent.json", None, None, "file not found"),
    ("unknown-suffix", lambda t: _write(t / "scene.yaml", "name: x"), "scene.yaml", None, None, "unsupported scene file type"),
    ("folder-without-objects", lambda t: _folder(t / "empty_dir"), "empty_dir", None, None, "no objects.json"),
    ("ref-missing-field", lambda t: _reference_folder(t, _drop(1, "width")), "objects.json", "chair_2", "width", "required field is missing"),
    ("ref-nan", lambda t: _ref_file(t, "objects.json", json.dumps(_ref_objects()).replace('"depth": 0.5', '"depth": NaN', 1)), "objects.json", "chair_1", "depth", "non-finite number 'NaN'"),
    ("ref-infinity-center", lambda t: _ref_file(t, "objects.json", json.dumps(_ref_objects()).replace('"center": [3.0', '"center": [Infinity', 1)), "objects.json", "table_1", "center", "non-finite number 'Infinity'"),
    ("ref-infinity-ignored-key", lambda t: _reference_folder(t, _set(1, "bbox", [[0, 0, 0], [float("inf"), 1, 1]])), "objects.json", "chair_2", "bbox", "non-finite number 'Infinity'"),
    ("ref-overflow", lambda t: _ref_file(t, "objects.json", json.dumps(_ref_objects()).replace('"width": 0.5', '"width": 1e999', 1)), "objects.json", "chair_1", "width", "number 1e999 is too large"),
    ("ref-nan-nameless", lambda t: _ref_file(t, "objects.json", json.dumps(_ref_objects()).replace('"idx": 2', '"idx": NaN', 1)), "objects.json", "#1", "idx", "non-finite number 'NaN'"),
    ("ref-scene-json-nan", lambda t: _ref_file(t, "scene.json", '{"bbox": [[0.0, 0.0, 0.0], [4.0, NaN, 2.5]]}'), "scene.json", None, "bbox", "non-finite number 'NaN'"),
    ("ref-grid-nan", lambda t: _ref_file(t, "grid_map.json", '{"grid_step": NaN}'), "grid_map.json", None, "grid_step", "non-finite number 'NaN'"),
    ("ref-duplicate-name", lambda t: _reference_folder(t, _set(1, "idx", 1)), "objects.json", "chair_1", "idx", "duplicate object name"),
    ("ref-negative-size", lambda t: _reference_folder(t, _set(2, "height", -0.75)), "objects.json", "table_1", "height", ">= 0"),
    ("ref-unknown-key", lambda t: _reference_folder(t, _set(0, "material", "oak")), "objects.json", "chair_1", "material", "unknown key"),
    ("ref-wrong-type", lambda t: _reference_folder(t, _set(0, "center", "middle")), "objects.json", "chair_1", "center", "list of 3 numbers"),
    ("ref-bool-number", lambda t: _reference_folder(t, _set(0, "width", True)), "objects.json", "chair_1", "width", "expected a number"),
    ("ref-string-flag", lambda t: _reference_folder(t, _set(0, "use_this", "yes")), "objects.json", "chair_1", "use_this", "true or false"),
    ("ref-zero-facing", lambda t: _reference_folder(t, _set(0, "orientation", [0.0, 0.0, 0.0])), "objects.json", "chair_1", "orientation", "non-zero"),
    ("ref-bad-label", lambda t: _reference_folder(t, _set(0, "label", "Big Chair")), "objects.json", "Big Chair_1", "label", "snake case"),
    ("ref-negative-idx", lambda t: _reference_folder(t, _set(0, "idx", -1)), "objects.json", "chair_-1", "idx", "integer >= 0"),
    ("ref-entry-not-object", lambda t: _reference_folder(t, lambda o: cast("list[object]", o).append(7)), "objects.json", "#3", None, "expected a JSON object"),  # 7: no object, on purpose
    ("ref-not-list", lambda t: _ref_file(t, "objects.json", {"objects": []}), "objects.json", None, None, "JSON list"),
    ("ref-truncated", lambda t: _ref_file(t, "objects.json", json.dumps(_ref_objects())[:150]), "objects.json", None, None, "truncated"),
    ("json-object-far-outside", lambda t: _write(t / "s.json", _with_object(1, center=[1.95, 10.5, 0.45])), "s.json", "cabinet_1", "center", "2.50 m outside the scene bounds"),
    ("ref-object-far-outside", lambda t: _reference_folder(t, _set(2, "center", [-2.0, 1.0, 0.375])), "objects.json", "table_1", "center", "2.00 m outside the scene bounds"),
    ("ref-bad-bbox", lambda t: _ref_file(t, "scene.json", {"bbox": [[0, 0, 0], [0, 3, 2]]}), "scene.json", None, "bbox", "must exceed"),
    ("ref-bad-grid", lambda t: _ref_file(t, "grid_map.json", {"grid_step": 0.3, "user_modifications": {"occupied": [[1, "a"]]}}), "grid_map.json", None, "user_modifications.occupied", "integer cells"),
    ("ref-grid-step-zero", lambda t: _ref_file(t, "grid_map.json", {"grid_step": 0}), "grid_map.json", None, "grid_step", "> 0"),
    ("ref-objects-fifo", lambda t: _fifo(_reference_folder(t) / "objects.json"), "objects.json", None, None, "not a regular file"),
    ("ref-objects-folder", lambda t: _as_folder(_reference_folder(t) / "objects.json"), "objects.json", None, None, "found a folder"),
]  # fmt: skip


def _fifo(path: Path) -> Path:
    """``path`` replaced by a FIFO that no one writes (opening it to read would block)."""
    path.unlink()
    os.mkfifo(path)
    return path.parent


def _as_folder(path: Path) -> Path:
    """``path`` replaced by a folder."""
    path.unlink()
    path.mkdir()
    return path.parent


@pytest.mark.parametrize(
    ("case", "build", "filename", "obj", "field", "message"),
    BAD_CASES,
    ids=[c[0] for c in BAD_CASES],
)
def test_bad_file_gives_one_clear_error(
    tmp_path: Path,
    case: str,
    build: Callable[[Path], Path],
    filename: str,
    obj: str | None,
    field: str | None,
    message: str,
) -> None:
    path = build(tmp_path)
    with pytest.raises(SceneFileError) as info:
        load_scene(path)
    err = info.value
    text = str(err)
    assert Path(err.path).name == filename, text
    assert err.obj == obj, text
    assert err.field == field, text
    assert message in text, text
    assert "\n" not in text and text.startswith(err.path)
    assert "Traceback" not in text and len(text) < 400
    assert info.value.__suppress_context__ or info.value.__cause__ is None


def test_objects_slightly_outside_the_bounds_are_accepted(tmp_path: Path) -> None:
    scene = load_scene(_write(tmp_path / "s.json", _with_object(1, center=[1.95, 8.9, 0.45])))
    assert scene.get("cabinet_1").center[1] == 8.9  # 0.9 m past bounds_max (8.0)


def test_empty_reference_folder_is_an_empty_scene(tmp_path: Path) -> None:
    folder = _reference_folder(tmp_path, lambda objects: objects.clear())
    scene = load_reference_folder(folder)
    assert scene.objects == () and scene.bounds_max == (4.0, 3.0)
    (folder / "scene.json").unlink()
    with pytest.raises(SceneFileError, match="cannot tell the floor size"):
        load_reference_folder(folder)


def test_reference_folder_without_optional_files(tmp_path: Path) -> None:
    folder = _reference_folder(tmp_path)
    (folder / "scene.json").unlink()
    (folder / "grid_map.json").unlink()
    scene = load_scene(folder)
    assert scene.bounds_min == pytest.approx((0.75, 0.75)) and scene.bounds_max == pytest.approx(
        (3.25, 1.25)
    )
    assert scene.nav.cell_size == 0.3 and scene.nav.occupied == ()


@requires_reference
def test_copied_reference_folder_loads_under_any_name(tmp_path: Path) -> None:
    shutil.copytree(SCENES / "House", tmp_path / "MyHouse")
    scene = load_scene(tmp_path / "MyHouse")
    assert scene.name == "MyHouse" and len(scene.objects) == 23
    assert isinstance(scene, Scene)


@pytest.mark.parametrize(
    ("build", "where"),
    [
        (
            lambda t: _write(
                t / "s.json", json.dumps(_project()).replace('"center": [0.45', '"center": [NaN')
            ),
            "s.json: object 'fridge_1', field 'center': non-finite number 'NaN'",
        ),
        (
            lambda t: _ref_file(
                t,
                "objects.json",
                json.dumps(_ref_objects()).replace('"height": 0.75', '"height": Infinity', 1),
            ),
            "objects.json: object 'table_1', field 'height': non-finite number 'Infinity'",
        ),
    ],
    ids=["project-json", "reference-folder"],
)
def test_cli_names_object_and_field_of_a_non_finite_number(
    tmp_path: Path, build: Callable[[Path], Path], where: str
) -> None:
    from typer.testing import CliRunner

    from storyteller.orchestrator.cli.app import app

    result = CliRunner().invoke(app, ["scene", "inspect", str(build(tmp_path))])
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and where in lines[0], result.stderr
    assert "Traceback" not in result.output

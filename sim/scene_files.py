"""Reading and writing scene files, with errors that name the file, the object and the field.

Formats:

- the project's own JSON (``Scene.model_dump_json``), ``format: "storyteller-scene/1"``;
- a reference annotation folder (``objects.json`` + optional ``scene.json`` and
  ``grid_map.json``), as published with the Event-Driven Storytelling paper;
- instance-segmented meshes (GLB / glTF / OBJ / PLY), see ``sim.scene_meshes``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from sim.scene import NavHints, Scene, SceneObject

MESH_SUFFIXES = {".glb", ".gltf", ".obj", ".ply", ".off", ".stl"}


class SceneFileError(Exception):
    """A scene file that cannot be used. ``str()`` is one sentence fit for a user."""

    def __init__(self, path: Path | str, message: str, *, obj: str | None = None, field: str | None = None):
        self.path = str(path)
        self.obj = obj
        self.field = field
        self.message = message
        where = self.path
        if obj is not None:
            where += f": object '{obj}'"
        if field is not None:
            where += f", field '{field}'" if obj is not None else f": field '{field}'"
        super().__init__(f"{where}: {message}")


def _read_json(path: Path) -> Any:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SceneFileError(path, "file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneFileError(path, f"cannot read file ({exc.__class__.__name__}: {exc})") from None
    try:
        return json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        raise SceneFileError(path, f"invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}") from None
    except ValueError as exc:
        raise SceneFileError(path, str(exc)) from None


def _reject_constant(name: str) -> float:
    raise ValueError(f"non-finite number '{name}' is not allowed")


def _validation_error(path: Path, exc: ValidationError, objects: list[Any] | None) -> SceneFileError:
    err = exc.errors()[0]
    loc = [str(p) for p in err["loc"]]
    obj_name: str | None = None
    field_parts = loc
    if objects is not None and len(loc) >= 2 and loc[0] == "objects" and loc[1].isdigit():
        i = int(loc[1])
        raw = objects[i] if i < len(objects) else None
        obj_name = raw.get("name") if isinstance(raw, dict) else None
        obj_name = obj_name or f"#{i}"
        field_parts = loc[2:]
    field = ".".join(field_parts) or None
    msg = err["msg"]
    if err["type"] == "extra_forbidden":
        msg = "unknown key"
    elif err["type"] == "missing":
        msg = "required field is missing"
    return SceneFileError(path, msg, obj=obj_name, field=field)


def load_scene_json(path: Path) -> Scene:
    """Load the project's own scene JSON."""
    data = _read_json(path)
    if not isinstance(data, dict):
        raise SceneFileError(path, "expected a JSON object at top level")
    objects = data.get("objects") if isinstance(data.get("objects"), list) else None
    try:
        return Scene.model_validate(data)
    except ValidationError as exc:
        raise _validation_error(path, exc, objects) from None


def save_scene_json(scene: Scene, path: Path) -> None:
    path.write_text(scene.model_dump_json(indent=2) + "\n", encoding="utf-8")


# ----- reference annotation folders ------------------------------------------------------
_REFERENCE_KEYS = {
    "id", "label", "idx", "aa_extents", "orientation", "has_orientation", "width", "depth",
    "height", "center", "bbox", "sit_offset_horizontal", "sit_offset_vertical", "use_this",
}  # fmt: skip
_REFERENCE_REQUIRED = {"label", "idx", "center", "width", "depth", "height", "orientation"}


def _number(path: Path, name: str, field: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SceneFileError(path, f"expected a number, got {value!r}", obj=name, field=field)
    if not math.isfinite(value):
        raise SceneFileError(path, f"expected a finite number, got {value!r}", obj=name, field=field)
    return float(value)


def _vector(path: Path, name: str, field: str, value: Any, n: int) -> tuple[float, ...]:
    if not isinstance(value, list) or len(value) < n:
        raise SceneFileError(path, f"expected a list of {n} numbers, got {value!r}", obj=name, field=field)
    return tuple(_number(path, name, field, v) for v in value[:n])


def _reference_object(path: Path, i: int, raw: Any) -> SceneObject:
    if not isinstance(raw, dict):
        raise SceneFileError(path, f"entry #{i} is not a JSON object")
    label = raw.get("label")
    idx = raw.get("idx")
    name = f"{label}_{idx}" if isinstance(label, str) and isinstance(idx, int) else f"#{i}"
    for key in sorted(_REFERENCE_REQUIRED - raw.keys()):
        raise SceneFileError(path, "required field is missing", obj=name, field=key)
    for key in sorted(raw.keys() - _REFERENCE_KEYS):
        raise SceneFileError(path, "unknown key", obj=name, field=key)
    if not isinstance(label, str) or not label:
        raise SceneFileError(path, f"expected a non-empty string, got {label!r}", obj=name, field="label")
    if isinstance(idx, bool) or not isinstance(idx, int) or idx < 0:
        raise SceneFileError(path, f"expected an integer >= 0, got {idx!r}", obj=name, field="idx")
    center = _vector(path, name, "center", raw["center"], 3)
    size = tuple(_number(path, name, k, raw[k]) for k in ("width", "depth", "height"))
    for k, v in zip(("width", "depth", "height"), size, strict=True):
        if v < 0:
            raise SceneFileError(path, f"must be >= 0, got {v}", obj=name, field=k)
    facing = _vector(path, name, "orientation", raw["orientation"], 2)
    if math.hypot(*facing) < 1e-6:
        raise SceneFileError(path, "must be a non-zero xy vector", obj=name, field="orientation")
    try:
        return SceneObject(
            name=name,
            label=label,
            idx=idx,
            center=center,  # type: ignore[arg-type]
            size=size,  # type: ignore[arg-type]
            facing=facing,  # type: ignore[arg-type]
            has_facing=bool(raw.get("has_orientation", True)),
            sit_offset_horizontal=_number(path, name, "sit_offset_vertical", raw.get("sit_offset_horizontal", 0.0)),
            sit_offset_vertical=_number(path, name, "sit_offset_vertical", raw.get("sit_offset_vertical", 0.0)),
            interactive=bool(raw.get("use_this", True)),
        )
    except ValidationError as exc:
        err = exc.errors()[0]
        field = ".".join(str(p) for p in err["loc"]) or None
        raise SceneFileError(path, err["msg"], obj=name, field=field) from None


def load_reference_folder(folder: Path) -> Scene:
    """Load a reference annotation folder (``objects.json`` [+ ``scene.json``, ``grid_map.json``])."""
    objects_path = folder / "objects.json"
    raw_objects = _read_json(objects_path)
    if not isinstance(raw_objects, list):
        raise SceneFileError(objects_path, "expected a JSON list of objects")
    objects = [_reference_object(objects_path, i, raw) for i, raw in enumerate(raw_objects)]
    seen: set[str] = set()
    for obj in objects:
        if obj.name in seen:
            raise SceneFileError(objects_path, "duplicate object name", obj=obj.name, field="idx")
        seen.add(obj.name)

    bounds_min, bounds_max = _reference_bounds(folder, objects)
    nav = _reference_nav(folder)
    try:
        return Scene(name=folder.name, bounds_min=bounds_min, bounds_max=bounds_max, objects=tuple(objects), nav=nav)
    except ValidationError as exc:
        raise _validation_error(objects_path, exc, None) from None


def _reference_bounds(folder: Path, objects: list[SceneObject]) -> tuple[tuple[float, float], tuple[float, float]]:
    scene_path = folder / "scene.json"
    if scene_path.exists():
        data = _read_json(scene_path)
        bbox = data.get("bbox") if isinstance(data, dict) else None
        if not (isinstance(bbox, list) and len(bbox) == 2):
            raise SceneFileError(scene_path, "expected [[xmin, ymin, zmin], [xmax, ymax, zmax]]", field="bbox")
        lo = _vector(scene_path, "scene", "bbox", bbox[0], 2)
        hi = _vector(scene_path, "scene", "bbox", bbox[1], 2)
        return (lo[0], lo[1]), (hi[0], hi[1])
    if not objects:
        raise SceneFileError(folder / "objects.json", "no objects and no scene.json: cannot tell the floor size")
    corners = [c for o in objects for c in o.footprint()]
    xs = [float(c[0]) for c in corners]
    ys = [float(c[1]) for c in corners]
    return (min(xs), min(ys)), (max(xs), max(ys))


def _reference_nav(folder: Path) -> NavHints:
    grid_path = folder / "grid_map.json"
    if not grid_path.exists():
        return NavHints()
    data = _read_json(grid_path)
    if not isinstance(data, dict):
        raise SceneFileError(grid_path, "expected a JSON object")
    mods = data.get("user_modifications") or {}
    try:
        return NavHints(
            cell_size=data.get("grid_step", 0.3),
            body_radius=data.get("cylinder_radius"),
            occupied=tuple(tuple(c) for c in mods.get("occupied", [])),
            unoccupied=tuple(tuple(c) for c in mods.get("unoccupied", [])),
        )
    except (ValidationError, TypeError) as exc:
        raise SceneFileError(grid_path, f"invalid grid settings ({exc.__class__.__name__})") from None


# ----- dispatch -----------------------------------------------------------------------------
def load_scene(path: Path | str) -> Scene:
    """Load a scene from a reference folder, a project JSON file, or a mesh file.

    Raises ``SceneFileError`` for anything wrong with the input.
    """
    path = Path(path)
    if path.is_dir():
        if not (path / "objects.json").exists():
            raise SceneFileError(path, "folder has no objects.json (expected a reference annotation folder)")
        return load_reference_folder(path)
    if not path.exists():
        raise SceneFileError(path, "file not found")
    suffix = path.suffix.lower()
    if suffix == ".json":
        if path.name == "objects.json":
            return load_reference_folder(path.parent)
        return load_scene_json(path)
    if suffix in MESH_SUFFIXES:
        from sim.scene_meshes import load_mesh_scene

        return load_mesh_scene(path)
    raise SceneFileError(path, f"unsupported scene file type '{suffix}' (expected a folder, .json, or a mesh)")

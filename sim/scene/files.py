"""Reading and writing scene files, with errors that name the file, the object and the field.

Formats:

- the project's own JSON (``Scene.model_dump_json``), ``format: "storyteller-scene/1"``;
- a reference annotation folder (``objects.json`` + optional ``scene.json`` and
  ``grid_map.json``), as published with the Event-Driven Storytelling paper;
- instance-segmented meshes (GLB / glTF / OBJ / PLY), see ``storyteller.sim.scene.meshes``.

Bounded: a JSON file is read only up to ``MAX_SCENE_FILE_BYTES`` (``storyteller.sim.bounded_files``: a
regular file, never a device or a FIFO) and nested at most ``MAX_SCENE_JSON_DEPTH`` deep (both
checked by ``storyteller.sim.scene.strict_json``), and holds at most ``MAX_SCENE_OBJECTS`` objects
(``storyteller.sim.scene.model`` states the other limits); anything outside them is a ``SceneFileError``,
checked before the work it would cost.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from storyteller.sim.scene.errors import SceneFileError as SceneFileError  # re-exported: callers catch it here
from storyteller.sim.scene.meshes import load_mesh_scene
from storyteller.sim.scene.model import MAX_SCENE_OBJECTS, NavHints, Scene, SceneObject
from storyteller.sim.scene.strict_json import parse_json, read_json, read_text, reference_name, short_repr
from storyteller.sim.validation_text import problem_field, problem_message

MESH_SUFFIXES = {".glb", ".gltf", ".obj", ".ply"}


def _validation_error(
    path: Path, exc: ValidationError, objects: list[Any] | None
) -> SceneFileError:
    err = exc.errors()[0]
    loc = [str(p) for p in err["loc"]]
    obj_name: str | None = None
    field_parts = loc
    if objects is not None and len(loc) >= 2 and loc[0] == "objects" and loc[1].isdigit():
        i = int(loc[1])
        raw = objects[i] if i < len(objects) else None
        name = raw.get("name") if isinstance(raw, dict) else None
        obj_name = name if isinstance(name, str) and name else f"#{i}"
        field_parts = loc[2:]
        if not field_parts and err["type"] == "value_error":
            field_parts = ["name"]  # the only object-level rule: name == '<label>_<idx>'
    field = ".".join(field_parts) or None
    msg = problem_message(err)
    if err["type"] not in ("extra_forbidden", "missing", "value_error"):
        msg += f", got {short_repr(err['input'])}"
    if err["type"] == "missing" and field_parts and field_parts[-1].isdigit():
        msg = "too few numbers in the list"
        field = ".".join(field_parts[:-1])
    return SceneFileError(path, msg, obj=obj_name, field=field)


def load_scene_json(path: Path) -> Scene:
    """Load the project's own scene JSON (``Scene.model_dump_json``), validated strictly.

    Strict means: numbers must be JSON numbers (no ``"1.0"`` strings), integers must be integers,
    booleans must be booleans, and every key must be known.
    """
    text = read_text(path)
    data = parse_json(path, text, "scene")
    if not isinstance(data, dict):
        hint = (
            " (a list of objects? pass the folder of a reference objects.json)"
            if isinstance(data, list)
            else ""
        )
        raise SceneFileError(path, f"expected a JSON object at top level{hint}")
    raw_objects = data.get("objects")
    objects = raw_objects if isinstance(raw_objects, list) else None
    if objects is not None:
        _check_object_count(path, len(objects))
        seen: set[str] = set()
        for raw in objects:
            name = raw.get("name") if isinstance(raw, dict) else None
            if isinstance(name, str):
                if name in seen:
                    raise SceneFileError(path, "duplicate object name", obj=name, field="name")
                seen.add(name)
    try:
        scene = Scene.model_validate_json(text, strict=True)
    except ValidationError as exc:
        raise _validation_error(path, exc, objects) from None
    _check_within_bounds(path, scene)
    return scene


def _check_object_count(path: Path, count: int) -> None:
    if count > MAX_SCENE_OBJECTS:
        raise SceneFileError(
            path, f"{count} objects, at most {MAX_SCENE_OBJECTS} allowed in a scene", field="objects"
        )


FAR_OUTSIDE = 1.0
"""Metres an object's centre may lie beyond the scene's floor rectangle (annotation slack)."""


def _check_within_bounds(path: Path, scene: Scene) -> None:
    """Every object's centre lies within ``FAR_OUTSIDE`` of the floor rectangle."""
    (x0, y0), (x1, y1) = scene.bounds_min, scene.bounds_max
    for obj in scene.objects:
        x, y = obj.center[0], obj.center[1]
        beyond = max(x0 - x, x - x1, y0 - y, y - y1)
        if beyond > FAR_OUTSIDE:
            raise SceneFileError(
                path,
                f"centre [{x:.2f}, {y:.2f}] is {beyond:.2f} m outside the scene bounds "
                f"(x {x0:.2f}..{x1:.2f}, y {y0:.2f}..{y1:.2f}); objects must stand within "
                f"{FAR_OUTSIDE:.1f} m of the floor",
                obj=obj.name,
                field="center",
            )


def save_scene_json(scene: Scene, path: Path) -> None:
    """Write ``scene`` as the project's JSON format (round-trips through ``load_scene_json``)."""
    path.write_text(scene.model_dump_json(indent=2) + "\n", encoding="utf-8")


# ----- reference annotation folders ------------------------------------------------------
_REFERENCE_KEYS = {
    "id", "label", "idx", "aa_extents", "orientation", "has_orientation", "width", "depth",
    "height", "center", "bbox", "sit_offset_horizontal", "sit_offset_vertical", "use_this",
}  # fmt: skip
_REFERENCE_REQUIRED = {"label", "idx", "center", "width", "depth", "height", "orientation"}


def _number(path: Path, name: str | None, field: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SceneFileError(
            path, f"expected a number, got {short_repr(value)}", obj=name, field=field
        )
    if not math.isfinite(value):
        raise SceneFileError(
            path, f"expected a finite number, got {short_repr(value)}", obj=name, field=field
        )
    return float(value)


def _vector(
    path: Path, name: str | None, field: str, value: Any, n: int, extra: int = 0
) -> tuple[float, ...]:
    """The first ``n`` numbers of a JSON list of ``n`` to ``n + extra`` finite numbers."""
    if not isinstance(value, list) or not n <= len(value) <= n + extra:
        count = f"{n}" if not extra else f"{n} to {n + extra}"
        raise SceneFileError(
            path,
            f"expected a list of {count} numbers, got {short_repr(value)}",
            obj=name,
            field=field,
        )
    for v in value[n:]:
        _number(path, name, field, v)
    return tuple(_number(path, name, field, v) for v in value[:n])


def _reference_object(path: Path, i: int, raw: Any) -> SceneObject:
    if not isinstance(raw, dict):
        raise SceneFileError(path, f"expected a JSON object, got {short_repr(raw)}", obj=f"#{i}")
    label = raw.get("label")
    idx = raw.get("idx")
    name = reference_name(raw, i)
    for key in sorted(_REFERENCE_REQUIRED - raw.keys()):
        raise SceneFileError(path, "required field is missing", obj=name, field=key)
    for key in sorted(raw.keys() - _REFERENCE_KEYS):
        raise SceneFileError(path, "unknown key", obj=name, field=key)
    if not isinstance(label, str) or not _LABEL_PATTERN.match(label):
        raise SceneFileError(
            path,
            f"expected a lower snake case label like 'coffee_maker', got {short_repr(label)}",
            obj=name,
            field="label",
        )
    if not isinstance(idx, int) or isinstance(idx, bool) or idx < 0:
        raise SceneFileError(
            path, f"expected an integer >= 0, got {short_repr(idx)}", obj=name, field="idx"
        )
    center = _vector(path, name, "center", raw["center"], 3)
    size = tuple(_number(path, name, k, raw[k]) for k in ("width", "depth", "height"))
    for k, v in zip(("width", "depth", "height"), size, strict=True):
        if v < 0:
            raise SceneFileError(path, f"must be >= 0, got {v}", obj=name, field=k)
    facing = _vector(path, name, "orientation", raw["orientation"], 2, extra=1)
    if math.hypot(*facing) < 1e-6:
        raise SceneFileError(path, "must be a non-zero xy vector", obj=name, field="orientation")
    flags = {k: _flag(path, name, k, raw.get(k, True)) for k in ("has_orientation", "use_this")}
    offsets = {
        k: _number(path, name, k, raw.get(k, 0.0))
        for k in ("sit_offset_horizontal", "sit_offset_vertical")
    }
    try:
        return SceneObject(
            name=name,
            label=label,
            idx=idx,
            center=center,
            size=size,
            facing=facing,
            has_facing=flags["has_orientation"],
            sit_offset_horizontal=offsets["sit_offset_horizontal"],
            sit_offset_vertical=reference_seat_height(offsets["sit_offset_vertical"], size[2]),
            interactive=flags["use_this"],
        )
    except ValidationError as exc:
        err = exc.errors()[0]
        raise SceneFileError(
            path, problem_message(err), obj=name, field=problem_field(err) or None
        ) from None


def reference_seat_height(sit_offset_vertical: float, height: float) -> float:
    """Seat height (m above the object's bottom) for a reference object.

    The reference data marks every seat with ``sit_offset_vertical = 0.2`` whatever its size (a
    0.42 m stool and a 0.98 m couch alike), so the value is a seat flag there, not a height. Our
    model stores the seat height, estimated from the object: a low object (<= 0.5 m) is sat on
    its top; a chair or couch with a back at half its height, within [0.38, 0.48] m.
    """
    if sit_offset_vertical <= 0.0:
        return 0.0
    if height <= 0.5:
        return round(height, 3)
    return round(min(0.48, max(0.38, 0.5 * height)), 3)


_LABEL_PATTERN = re.compile(r"^[a-z][a-z0-9_]*$")


def _flag(path: Path, name: str, field: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise SceneFileError(
            path, f"expected true or false, got {short_repr(value)}", obj=name, field=field
        )
    return value


def load_reference_folder(folder: Path) -> Scene:
    """Load a reference annotation folder (``objects.json`` [+ ``scene.json``, ``grid_map.json``]).

    The scene's floor rectangle comes from ``scene.json``'s ``bbox`` (or, without it, from the
    objects' footprints); navigation hints from ``grid_map.json``. The scene is named after the
    folder.
    """
    objects_path = folder / "objects.json"
    if not objects_path.exists():  # a FIFO or a device there: read_json says it is no regular file
        raise SceneFileError(
            folder, "folder has no objects.json (expected a reference annotation folder)"
        )
    raw_objects = read_json(objects_path, "objects")
    if not isinstance(raw_objects, list):
        raise SceneFileError(objects_path, "expected a JSON list of objects at top level")
    _check_object_count(objects_path, len(raw_objects))
    objects = [_reference_object(objects_path, i, raw) for i, raw in enumerate(raw_objects)]
    seen: set[str] = set()
    for obj in objects:
        if obj.name in seen:
            raise SceneFileError(
                objects_path,
                "duplicate object name (same label and idx twice)",
                obj=obj.name,
                field="idx",
            )
        seen.add(obj.name)

    bounds_min, bounds_max = _reference_bounds(folder, objects)
    nav = _reference_nav(folder)
    try:
        scene = Scene(
            name=folder.resolve().name or "scene",
            bounds_min=bounds_min,
            bounds_max=bounds_max,
            objects=tuple(objects),
            nav=nav,
        )
    except ValidationError as exc:  # the scene-wide limits (floor size in cells, coordinates)
        raise _validation_error(objects_path, exc, None) from None
    _check_within_bounds(objects_path, scene)
    return scene


def _reference_bounds(
    folder: Path, objects: list[SceneObject]
) -> tuple[tuple[float, float], tuple[float, float]]:
    scene_path = folder / "scene.json"
    if scene_path.exists():
        data = read_json(scene_path)
        if not isinstance(data, dict):
            raise SceneFileError(scene_path, "expected a JSON object at top level")
        if "bbox" not in data:
            raise SceneFileError(scene_path, "required field is missing", field="bbox")
        bbox = data["bbox"]
        if not (isinstance(bbox, list) and len(bbox) == 2):
            raise SceneFileError(
                scene_path,
                f"expected [[xmin, ymin, zmin], [xmax, ymax, zmax]], got {short_repr(bbox)}",
                field="bbox",
            )
        lo = _vector(scene_path, None, "bbox", bbox[0], 2, extra=1)
        hi = _vector(scene_path, None, "bbox", bbox[1], 2, extra=1)
        if hi[0] <= lo[0] or hi[1] <= lo[1]:
            raise SceneFileError(
                scene_path,
                f"upper corner {list(hi[:2])} must exceed lower corner {list(lo[:2])} on x and y",
                field="bbox",
            )
        return (lo[0], lo[1]), (hi[0], hi[1])
    if not objects:
        raise SceneFileError(
            folder / "objects.json", "no objects and no scene.json: cannot tell the floor size"
        )
    corners = np.concatenate([o.footprint() for o in objects])
    lo_xy, hi_xy = corners.min(axis=0), corners.max(axis=0)
    if hi_xy[0] <= lo_xy[0] or hi_xy[1] <= lo_xy[1]:
        raise SceneFileError(
            folder / "objects.json",
            "objects have no floor area and there is no scene.json for the bounds",
        )
    return (float(lo_xy[0]), float(lo_xy[1])), (float(hi_xy[0]), float(hi_xy[1]))


def _cells(path: Path, field: str, value: Any) -> tuple[tuple[int, int], ...]:
    if not isinstance(value, list):
        raise SceneFileError(
            path, f"expected a list of [i, j] cells, got {short_repr(value)}", field=field
        )
    cells = []
    for cell in value:
        if not (
            isinstance(cell, list)
            and len(cell) == 2
            and all(isinstance(c, int) and not isinstance(c, bool) for c in cell)
        ):
            raise SceneFileError(
                path, f"expected [i, j] integer cells, got {short_repr(cell)}", field=field
            )
        cells.append((cell[0], cell[1]))
    return tuple(cells)


def _reference_nav(folder: Path) -> NavHints:
    grid_path = folder / "grid_map.json"
    if not grid_path.exists():
        return NavHints()
    data = read_json(grid_path)
    if not isinstance(data, dict):
        raise SceneFileError(grid_path, "expected a JSON object at top level")
    mods = data.get("user_modifications", {})
    if not isinstance(mods, dict):
        raise SceneFileError(
            grid_path, f"expected an object, got {short_repr(mods)}", field="user_modifications"
        )
    cell = _number(grid_path, None, "grid_step", data.get("grid_step", 0.3))
    if cell <= 0:
        raise SceneFileError(grid_path, f"must be > 0, got {cell}", field="grid_step")
    radius_raw = data.get("cylinder_radius")
    radius = None if radius_raw is None else _number(grid_path, None, "cylinder_radius", radius_raw)
    if radius is not None and radius <= 0:
        raise SceneFileError(grid_path, f"must be > 0, got {radius}", field="cylinder_radius")
    try:
        return NavHints(
            cell_size=cell,
            body_radius=radius,
            occupied=_cells(grid_path, "user_modifications.occupied", mods.get("occupied", [])),
            unoccupied=_cells(grid_path, "user_modifications.unoccupied", mods.get("unoccupied", [])),
            # Reference cell (a, b) is centred at (x_margin + a * step, y_margin + b * step): see
            # sim.paths.nav_grid.reference_grid_origin for how this was inferred from the data.
            grid_origin=(
                _number(grid_path, None, "x_margin", data.get("x_margin", 0.0)),
                _number(grid_path, None, "y_margin", data.get("y_margin", 0.0)),
            ),
        )
    except ValidationError as exc:
        raise _validation_error(grid_path, exc, None) from None


# ----- dispatch -----------------------------------------------------------------------------
def load_scene(path: Path | str) -> Scene:
    """Load a scene from a reference folder, a project JSON file, or a mesh file.

    Raises ``SceneFileError`` for anything wrong with the input.
    """
    path = Path(path)
    if path.is_dir():
        return load_reference_folder(path)
    if not path.exists():
        raise SceneFileError(path, "file not found")
    suffix = path.suffix.lower()
    if suffix == ".json":
        if path.name == "objects.json":
            return load_reference_folder(path.parent)
        return load_scene_json(path)
    if suffix in MESH_SUFFIXES:
        return load_mesh_scene(path)
    kinds = ", ".join(sorted(MESH_SUFFIXES))
    raise SceneFileError(
        path,
        f"unsupported scene file type '{suffix or path.name}' (expected a folder, .json, or {kinds})",
    )

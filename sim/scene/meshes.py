"""Instance-segmented meshes (GLB / glTF / OBJ / PLY) -> ``Scene``, through trimesh.

One scene object per graph node that carries geometry (``trimesh.load_scene`` +
``scene.graph.nodes_geometry``). The rules, in order:

- **Names.** The node name (or, when the node name is empty or generic such as ``node_3`` /
  ``mesh``, the geometry name) gives label and index: ``"chair_3"``, ``"Chair.003"``,
  ``"chair3"`` -> ``chair_3``; ``"coffee maker 2"`` and ``"CoffeeMaker-2"`` -> ``coffee_maker_2``.
  A name without an index gets the smallest free index >= 1 of its label (nodes taken in name
  order). Two nodes that resolve to the same name are an error.
- **Up axis.** glTF / GLB are Y-up by specification and are turned to z-up with
  ``(x, y, z) -> (x, -z, y)``; OBJ and PLY are taken as z-up unless ``up_axis="y"`` is given.
- **Floor.** Nodes labelled ``floor`` / ``ground`` are the floor: its top is the floor height and
  its xy extent the scene bounds. ``ceiling`` / ``room`` nodes are dropped. Without a floor node
  the floor is the lowest point of all geometry, and the bounds are the objects' footprints
  grown by ``BOUNDS_MARGIN``. Everything is shifted so the floor is at z = 0.
- **Boxes.** Yaw-only oriented boxes: the minimum-area rectangle around the convex hull of the
  vertices' xy projection, plus the z extent.
- **Facing.** An asset's front is glTF's +Z in its own frame (the glTF convention), i.e. -y of
  the node's local frame once z-up (Blender's "front" view convention). That direction, turned
  by the node's world transform and projected on xy, is snapped to the nearest box axis; the
  box width is measured across it, the depth along it. ``has_facing`` is True only for labels
  known to have a front (``FRONTED_LABELS``) and when the direction is not near vertical;
  otherwise False (the facing then is the box axis nearest +y, and means nothing).
- **Seats.** Chairs, couches, benches and stools get seat offsets (``SEAT_RULES``).
- **Bounds.** A mesh file of more than ``MAX_MESH_FILE_BYTES``, more than ``MAX_SCENE_OBJECTS``
  nodes with geometry, or a node name longer than ``MAX_NODE_NAME_CHARS`` is refused before it is
  read further; names are parsed by a linear scan (no backtracking regular expression). What
  the file declares (glTF nodes and accessors), the files it names (read within the folder and
  the same byte limit; materials and textures never), the hierarchy's depth and the vertices of
  all instances are bounded too (``storyteller.sim.scene.mesh_limits``).
"""

from __future__ import annotations

import io
import math
import re
import warnings
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError
from scipy.spatial import ConvexHull, QhullError

from storyteller.sim.bounded_files import BoundedFileError, read_bounded_bytes
from storyteller.sim.scene.errors import SceneFileError
from storyteller.sim.scene.model import MAX_SCENE_OBJECTS, Scene, SceneObject
from storyteller.sim.validation_text import problem_field, problem_message

MAX_MESH_FILE_BYTES = 64 * 1024 * 1024
"""Bytes of a mesh scene file (trimesh holds several times the file in memory)."""
MAX_NODE_NAME_CHARS = 200
"""Characters of a node or geometry name that names an object."""
BOUNDS_MARGIN = 1.0  # metres of free floor around the objects when the file has no floor node
FLOOR_LABELS = frozenset({"floor", "ground"})
DROPPED_LABELS = frozenset({"ceiling", "room"})
FRONTED_LABELS = frozenset(
    {
        "chair", "armchair", "office_chair", "dining_chair", "couch", "sofa", "loveseat", "bench",
        "tv", "television", "monitor", "computer", "laptop", "fridge", "refrigerator", "microwave",
        "oven", "stove", "dishwasher", "washing_machine", "cabinet", "kitchen_counter", "counter",
        "bookshelf", "shelf", "wardrobe", "dresser", "desk", "coffee_maker", "toaster",
        "water_dispenser", "white_board", "whiteboard", "record_player", "dvd_player",
        "loudspeaker", "speaker", "bar_counter", "reception_desk", "sink", "piano", "fireplace",
        "bed", "toilet", "printer", "vending_machine", "cash_register", "tv_stand", "wine_rack",
    }
)  # fmt: skip
# label -> (seat height above the object's bottom in metres (None: the object's top), offset of
# the seat point along the facing as a fraction of the depth)
SEAT_RULES: dict[str, tuple[float | None, float]] = {
    "chair": (0.45, 0.1), "armchair": (0.42, 0.1), "office_chair": (0.47, 0.05),
    "dining_chair": (0.45, 0.1), "couch": (0.42, 0.1), "sofa": (0.42, 0.1),
    "loveseat": (0.42, 0.1), "bench": (0.45, 0.0), "stool": (None, 0.0), "bar_stool": (None, 0.0),
}  # fmt: skip

_GENERIC_NAME = re.compile(
    r"^(node|mesh|geometry|object|obj|group|primitive)?[\s._-]*\d*$", re.IGNORECASE
)
_CAMEL_LOWER = re.compile(r"(?<=[a-z0-9])(?=[A-Z])")  # "coffeeMaker" -> "coffee Maker"
_CAMEL_UPPER = re.compile(r"(?<=[A-Z])(?=[A-Z][a-z])")  # "TVStand" -> "TV Stand"
_SEPARATORS = re.compile(r"[^a-z0-9]+")
_OBJECT_LINE = re.compile(rb"^o ([^\r\n]*)", re.MULTILINE)  # an OBJ object's name line
_Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
_Y_UP_SUFFIXES = {".glb", ".gltf"}


def parse_instance_name(raw: str) -> tuple[str, int | None]:
    """``(label, idx)`` from a node name; ``idx`` None when the name carries no index.

    Lower snake case; camelCase is split; any run of non-alphanumerics is a separator; a trailing
    number (separate, or glued to the last word) is the index. A label that would be empty or
    start with a digit is prefixed with ``object``.
    """
    text = _CAMEL_LOWER.sub(" ", raw.strip())
    text = _CAMEL_UPPER.sub(" ", text)
    tokens = [t for t in _SEPARATORS.split(text.lower()) if t]
    idx: int | None = None
    if tokens and tokens[-1].isdigit():
        idx = int(tokens.pop())
    elif tokens and tokens[-1][0].isalpha() and tokens[-1][-1].isdigit():
        word = tokens[-1]
        cut = len(word.rstrip("0123456789"))  # the trailing digits, scanned once
        tokens[-1], idx = word[:cut], int(word[cut:])
    label = "_".join(tokens)
    if not label or not label[0].isalpha():
        label = "object" + (f"_{label}" if label else "")
    return label, idx


def yaw_box(points_xy: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Minimum-area rectangle around 2-D points.

    Returns ``(center (2,), axes (2, 2), extents (2,))``: ``axes[0]`` is a unit vector with angle
    in [0, pi/2), ``axes[1]`` is it turned by +90 degrees, ``extents`` the full side lengths
    along them. Degenerate inputs (a point, a segment) give zero extents where there is none.
    """
    pts = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    try:
        hull = pts[ConvexHull(pts).vertices]
    except (QhullError, ValueError):
        hull = pts  # fewer than 3 points, or all collinear: every point is on the "hull"
    edges = np.diff(np.vstack([hull, hull[:1]]), axis=0)
    angles = np.mod(np.arctan2(edges[:, 1], edges[:, 0]), math.pi / 2)
    angles = np.unique(np.round(np.concatenate([[0.0], angles]), 12))
    best: tuple[float, float] | None = None
    for a in angles:
        u = np.array([math.cos(a), math.sin(a)])
        v = np.array([-u[1], u[0]])
        pu, pv = hull @ u, hull @ v
        area = (pu.max() - pu.min()) * (pv.max() - pv.min())
        if best is None or area < best[0] - 1e-12:
            best = (area, float(a))
    assert best is not None
    a = best[1]
    axes = np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])
    proj = hull @ axes.T
    lo, hi = proj.min(axis=0), proj.max(axis=0)
    center = axes.T @ ((lo + hi) / 2.0)
    return center, axes, hi - lo


def _load_trimesh_scene(path: Path) -> Any:
    import trimesh

    from storyteller.sim.scene.mesh_limits import BoundedResolver, check_gltf_declarations, check_mesh_graph

    try:
        data = read_bounded_bytes(path, MAX_MESH_FILE_BYTES, str(path))
    except BoundedFileError as exc:
        raise SceneFileError(path, exc.problem) from None
    if not data:
        raise SceneFileError(path, "file is empty")
    suffix = path.suffix.lower()
    if suffix == ".obj":
        _check_obj_names(path, data)
    if suffix in (".glb", ".gltf"):
        check_gltf_declarations(path, data)
    kwargs: dict[str, Any] = {"split_objects": True, "group_material": False} if suffix == ".obj" else {}
    try:
        scene = trimesh.load_scene(io.BytesIO(data), file_type=suffix[1:], skip_materials=True,
                                   resolver=BoundedResolver(path, MAX_MESH_FILE_BYTES), **kwargs)
    except SceneFileError:
        raise
    except Exception as exc:  # trimesh raises many types for malformed files
        raise SceneFileError(
            path, f"cannot read mesh file ({exc.__class__.__name__}: {exc})"
        ) from None
    check_mesh_graph(path, scene.graph, scene.geometry)
    return scene


def _check_obj_names(path: Path, data: bytes) -> None:
    """OBJ objects with one name are merged by the reader: refuse them instead; and a file whose
    face lines make more than ``MAX_MESH_FACES`` triangles (``storyteller.sim.scene.mesh_limits``)
    or that names more than ``MAX_SCENE_OBJECTS`` objects (trimesh took 160 s and 1.3 GB to build
    200,000 before the count of its nodes refused them)."""
    from storyteller.sim.scene.mesh_limits import check_declared_faces, obj_triangles

    check_declared_faces(path, obj_triangles(data))
    seen: set[str] = set()
    for match in _OBJECT_LINE.finditer(data):
        name = match.group(1).decode("utf-8", errors="replace").strip()
        if name in seen:
            raise SceneFileError(
                path, "two OBJ objects ('o' lines) have this name", obj=name, field="name"
            )
        seen.add(name)
        if len(seen) > MAX_SCENE_OBJECTS:
            raise SceneFileError(
                path, f"more than {MAX_SCENE_OBJECTS} OBJ objects ('o' lines), at most {MAX_SCENE_OBJECTS} allowed in a scene"
            )


def load_mesh_scene(path: Path | str, *, up_axis: Literal["y", "z"] | None = None) -> Scene:
    """Load an instance-segmented mesh file as a ``Scene`` (rules in the module docstring).
    numpy's and trimesh's warnings (overflow on a huge transform) are not printed: the
    coordinates are checked and refused with one line instead."""
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        return _mesh_scene(Path(path), up_axis)


def _mesh_scene(path: Path, up_axis: Literal["y", "z"] | None) -> Scene:
    if not path.is_file():
        raise SceneFileError(path, "file not found")
    tm_scene = _load_trimesh_scene(path)
    up = up_axis or ("y" if path.suffix.lower() in _Y_UP_SUFFIXES else "z")
    to_z_up = _Y_UP_TO_Z_UP if up == "y" else np.eye(3)
    file_front = np.array([0.0, 0.0, 1.0]) if up == "y" else np.array([0.0, -1.0, 0.0])

    nodes = sorted(tm_scene.graph.nodes_geometry)
    if not nodes:
        raise SceneFileError(
            path, "mesh file has no nodes with geometry (expected one node per object)"
        )
    if len(nodes) > MAX_SCENE_OBJECTS:
        raise SceneFileError(
            path, f"{len(nodes)} nodes with geometry, at most {MAX_SCENE_OBJECTS} objects allowed in a scene"
        )

    parts: list[
        tuple[str, str, int | None, NDArray[np.float64], NDArray[np.float64]]
    ] = []  # raw, label, idx, verts, front
    for node in nodes:
        transform, geom_name = tm_scene.graph[node]
        geom = tm_scene.geometry.get(geom_name)
        raw_name = str(node) if not _GENERIC_NAME.match(str(node)) else str(geom_name)
        if len(raw_name) > MAX_NODE_NAME_CHARS:
            raise SceneFileError(
                path,
                f"name of {len(raw_name)} characters (at most {MAX_NODE_NAME_CHARS} allowed)",
                obj=raw_name[:40] + "...",
                field="name",
            )
        label, idx = parse_instance_name(raw_name)
        verts = np.asarray(getattr(geom, "vertices", np.empty((0, 3))), dtype=np.float64).reshape(-1, 3)
        if len(verts) == 0:
            raise SceneFileError(path, "node has no vertices", obj=str(node), field="geometry")
        if not np.isfinite(verts).all() or not np.isfinite(transform).all():
            raise SceneFileError(
                path, "node has non-finite coordinates", obj=str(node), field="geometry"
            )
        world = verts @ np.asarray(transform)[:3, :3].T + np.asarray(transform)[:3, 3]
        front = to_z_up @ (np.asarray(transform)[:3, :3] @ file_front)
        parts.append((str(node), label, idx, world @ to_z_up.T, front))

    floors = [p for p in parts if p[1] in FLOOR_LABELS]
    things = [p for p in parts if p[1] not in FLOOR_LABELS | DROPPED_LABELS]
    if floors:
        floor_z = max(float(p[3][:, 2].max()) for p in floors)
    else:
        floor_z = min(float(p[3][:, 2].min()) for p in things) if things else 0.0

    names = _assign_names(path, things)
    objects = [
        _make_object(path, name, label, idx, verts, front, floor_z)
        for (name, label, idx), (_, _, _, verts, front) in zip(names, things, strict=True)
    ]
    objects.sort(key=lambda o: (o.label, o.idx))

    if not objects:
        raise SceneFileError(
            path, "mesh file has only structural nodes (floor/ceiling/room), no objects"
        )
    if floors:
        xy = np.concatenate([p[3][:, :2] for p in floors])
        lo, hi = xy.min(axis=0), xy.max(axis=0)
    else:
        corners = np.concatenate([o.footprint() for o in objects])
        lo, hi = corners.min(axis=0) - BOUNDS_MARGIN, corners.max(axis=0) + BOUNDS_MARGIN
    try:
        return Scene(
            name=path.stem or "scene",
            bounds_min=(float(lo[0]), float(lo[1])),
            bounds_max=(float(hi[0]), float(hi[1])),
            objects=tuple(objects),
        )
    except ValidationError as exc:
        raise SceneFileError(path, problem_message(exc.errors()[0])) from None


def _assign_names(
    path: Path, parts: list[tuple[str, str, int | None, NDArray[np.float64], NDArray[np.float64]]]
) -> list[tuple[str, str, int]]:
    """``(name, label, idx)`` per part: explicit indices kept, missing ones auto-filled."""
    taken: dict[tuple[str, int], str] = {}
    for node, label, idx, _, _ in parts:
        if idx is not None:
            if (label, idx) in taken:
                raise SceneFileError(
                    path,
                    f"nodes '{taken[(label, idx)]}' and '{node}' both resolve to this name",
                    obj=f"{label}_{idx}",
                    field="name",
                )
            taken[(label, idx)] = node
    out: list[tuple[str, str, int]] = []
    for node, label, idx, _, _ in parts:
        if idx is None:
            idx = 1
            while (label, idx) in taken:
                idx += 1
            taken[(label, idx)] = node
        out.append((f"{label}_{idx}", label, idx))
    return out


def _make_object(
    path: Path,
    name: str,
    label: str,
    idx: int,
    verts: NDArray[np.float64],
    front: NDArray[np.float64],
    floor_z: float,
) -> SceneObject:
    center_xy, axes, extents = yaw_box(verts[:, :2])
    z_lo, z_hi = float(verts[:, 2].min()) - floor_z, float(verts[:, 2].max()) - floor_z
    front_xy = front[:2]
    has_facing = label in FRONTED_LABELS and float(np.linalg.norm(front_xy)) > 0.3
    candidates = np.vstack([axes, -axes])  # +u, +v, -u, -v
    reference = front_xy if has_facing else np.array([0.0, 1.0])
    k = int(np.argmax(candidates @ reference))
    facing = candidates[k]
    along = k % 2  # which box axis the facing runs along
    depth, width = float(extents[along]), float(extents[1 - along])
    height = z_hi - z_lo
    seat_v, seat_h = 0.0, 0.0
    if label in SEAT_RULES:
        rule_v, seat_h = SEAT_RULES[label]
        seat_v = height if rule_v is None else min(rule_v, height)
    try:
        return SceneObject(
            name=name,
            label=label,
            idx=idx,
            center=(_r(center_xy[0]), _r(center_xy[1]), _r((z_lo + z_hi) / 2.0)),
            size=(_r(width), _r(depth), _r(height)),
            facing=(_r(facing[0]), _r(facing[1])),
            has_facing=has_facing,
            sit_offset_horizontal=seat_h,
            sit_offset_vertical=seat_v,
            interactive=label != "wall",
        )
    except ValidationError as exc:
        err = exc.errors()[0]
        raise SceneFileError(
            path, problem_message(err), obj=name, field=problem_field(err) or None
        ) from None


def _r(value: float) -> float:
    """Round to the micrometre (float32 mesh noise) and drop negative zeros."""
    return round(float(value), 6) + 0.0

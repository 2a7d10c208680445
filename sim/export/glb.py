"""One animated, skinned GLB (binary glTF 2.0) of a whole run: scene boxes plus characters.

Frames: glTF is **Y up** (forward +z, metres). Our z-up world maps to it by
``(x, y, z) -> (x, z, -y)`` (``WORLD_TO_GLTF = BODY_TO_WORLD.T``), which makes the glTF frame
the SMPL-X body frame, so joint-local data (rest offsets, local rotations) is written as is and
only the root's translation and rotation are converted.

Layout of the file:

- node ``objects``: one box node per scene object, named as the object (``chair_3``), a unit
  cube mesh per label scaled to the object's size and turned to its facing, plus a ``floor``
  slab over the scene bounds;
- per character a group node named as the character, holding its joint hierarchy
  (``<name>:pelvis`` ... ``<name>:right_wrist``, translations = rest offsets), and a root
  skinned mesh node ``<name>:body``: the box figure of :mod:`storyteller.sim.export.box_figure` (one
  flat-shaded box per bone), each box bound rigidly to one of the 22 joints (``skin.joints`` in our joint order, inverse bind matrices of the rest pose);
- one animation ``run``: per character, root translation + 22 joint rotations (unit
  quaternions, xyzw, sign-continuous), one key per frame at the track's rate, LINEAR.

A character given a :class:`SkinnedBody` (a body mesh computed outside ``sim``, e.g. SMPL-X
from its model files, passed in as plain arrays) gets that mesh instead of the boxes, skinned to
the same 22 joint nodes with the body's own weights and inverse bind matrices; its joint nodes
sit at the body's rest joints, and its pelvis follows the SMPL ``transl`` convention of the
``.smplx.npz`` export (``pelvis = trans + J0`` of the body), so the GLB shows what the model
shows for the exported parameters. The animated local rotations are the same.

The static node transforms are the first frame's pose. Output bytes are deterministic. Every
name in the document (objects, characters, their joints, meshes, materials, skins) comes from a
scene file or a model and a glTF viewer shows it as text, so it is written through
``storyteller.sim.visible_text.plain`` (control, format, separator and surrogate characters as escapes; an
ordinary name is unchanged).
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib as gl
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from storyteller.sim.body.skeleton import (
    BODY_TO_WORLD,
    JOINT_NAMES,
    NUM_JOINTS,
    PARENTS,
    REST_OFFSETS,
    rest_positions,
)
from storyteller.sim.export.box_figure import box_mesh, character_mesh
from storyteller.sim.export.joint_rotations import JointRotations
from storyteller.sim.no_follow_writes import write_file
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.visible_text import plain
from storyteller.sim.world.character_track import CharacterTrack

WORLD_TO_GLTF = BODY_TO_WORLD.T
FLOOR_THICKNESS = 0.02  # metres, below floor_z
ANIMATION_NAME = "run"
CHARACTER_COLORS: tuple[tuple[float, float, float], ...] = (
    (0.85, 0.33, 0.25),
    (0.25, 0.55, 0.85),
    (0.35, 0.70, 0.35),
    (0.90, 0.70, 0.20),
    (0.60, 0.40, 0.75),
    (0.20, 0.75, 0.75),
    (0.85, 0.45, 0.65),
    (0.55, 0.55, 0.55),
)


@dataclass(frozen=True)
class SkinnedBody:
    """A body mesh in its rest pose, bound to our 22 joints (glTF frame = body frame, metres).

    vertices (V, 3), faces (F, 3), joints (V, 4) joint ids and weights (V, 4) summing to 1
    per vertex, bind_joints (22, 3) the rest joint positions the mesh is bound at.
    """

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    joints: NDArray[np.int64]
    weights: NDArray[np.float64]
    bind_joints: NDArray[np.float64]

    def __post_init__(self) -> None:
        v = self.vertices.shape[0]
        shapes = {
            "vertices": (self.vertices.shape, (v, 3)),
            "faces": (self.faces.shape[1:], (3,)),
            "joints": (self.joints.shape, (v, 4)),
            "weights": (self.weights.shape, (v, 4)),
            "bind_joints": (self.bind_joints.shape, (NUM_JOINTS, 3)),
        }
        for field, (got, want) in shapes.items():
            if got != want:
                raise ValueError(f"SkinnedBody.{field}: expected shape {want}, got {got}")
        if self.joints.min() < 0 or self.joints.max() >= NUM_JOINTS:
            raise ValueError(f"SkinnedBody.joints: expected ids in [0, {NUM_JOINTS})")
        if not np.allclose(self.weights.sum(axis=1), 1.0, atol=1e-4):
            raise ValueError("SkinnedBody.weights: each vertex's weights must sum to 1")


def vertex_normals(vertices: NDArray[np.float64], faces: NDArray[np.int64]) -> NDArray[np.float64]:
    """Unit area-weighted vertex normals ((0, 1, 0) for a vertex on no face)."""
    tri = vertices[faces]
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, faces[:, k], face_n)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    out: NDArray[np.float64] = np.where(length > 1e-12, normals / np.maximum(length, 1e-12), [[0.0, 1.0, 0.0]])
    return out


class _Writer:
    """Accumulates the binary buffer (4-byte aligned views) and the glTF objects."""

    def __init__(self) -> None:
        self.gltf = gl.GLTF2(asset=gl.Asset(generator="storyteller sim.export.glb", version="2.0"))
        self.blob = bytearray()

    def accessor(
        self,
        data: NDArray[Any],
        kind: str,
        component: int,
        *,
        target: int | None = None,
        bounds: bool = False,
        name: str | None = None,
    ) -> int:
        arr = np.ascontiguousarray(data)
        offset = len(self.blob)
        raw = arr.tobytes()
        self.blob += raw + b"\x00" * (-len(raw) % 4)
        self.gltf.bufferViews.append(
            gl.BufferView(buffer=0, byteOffset=offset, byteLength=len(raw), target=target)
        )
        count = arr.shape[0]
        acc = gl.Accessor(
            bufferView=len(self.gltf.bufferViews) - 1,
            componentType=component,
            count=count,
            type=kind,
            name=name,
        )
        if bounds:
            flat = arr.reshape(count, -1)
            acc.min = [float(x) for x in flat.min(axis=0)]
            acc.max = [float(x) for x in flat.max(axis=0)]
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1

    def node(self, node: gl.Node) -> int:
        self.gltf.nodes.append(node)
        return len(self.gltf.nodes) - 1

    def material(self, name: str, rgb: Sequence[float]) -> int:
        pbr = gl.PbrMetallicRoughness(
            baseColorFactor=[*map(float, rgb), 1.0], metallicFactor=0.0, roughnessFactor=0.8
        )
        self.gltf.materials.append(gl.Material(name=name, pbrMetallicRoughness=pbr))
        return len(self.gltf.materials) - 1

    def mesh(self, name: str, attributes: gl.Attributes, indices: int, material: int) -> int:
        prim = gl.Primitive(attributes=attributes, indices=indices, material=material)
        self.gltf.meshes.append(gl.Mesh(name=name, primitives=[prim]))
        return len(self.gltf.meshes) - 1


def _quat(matrices: NDArray[np.float64]) -> NDArray[np.float64]:
    """(..., 3, 3) -> (..., 4) xyzw quaternions."""
    m = np.asarray(matrices)
    return Rotation.from_matrix(m.reshape(-1, 3, 3)).as_quat().reshape(*m.shape[:-2], 4)


def _continuous(quats: NDArray[np.float64]) -> NDArray[np.float64]:
    """Flip signs along axis 0 so consecutive quaternions have a non-negative dot product."""
    if quats.shape[0] < 2:
        return quats
    dots = np.einsum("n...i,n...i->n...", quats[1:], quats[:-1])
    flips = np.cumprod(np.where(dots < 0.0, -1.0, 1.0), axis=0)
    out = quats.copy()
    out[1:] *= flips[..., None]
    return out


def _label_color(label: str) -> tuple[float, float, float]:
    h = zlib.crc32(label.encode("utf-8"))
    return (
        0.45 + 0.4 * ((h & 0xFF) / 255),
        0.45 + 0.4 * (((h >> 8) & 0xFF) / 255),
        0.45 + 0.4 * (((h >> 16) & 0xFF) / 255),
    )


def _object_trs(obj: SceneObject) -> tuple[list[float], list[float], list[float]]:
    f = np.array([obj.facing[0], obj.facing[1], 0.0])
    r = np.array([obj.facing[1], -obj.facing[0], 0.0])
    rot_world = np.column_stack([r, f, [0.0, 0.0, 1.0]])
    rot = WORLD_TO_GLTF @ rot_world @ WORLD_TO_GLTF.T
    t = WORLD_TO_GLTF @ np.array(obj.center)
    width, depth, height = (max(s, 1e-4) for s in obj.size)
    return [float(x) for x in t], [float(x) for x in _quat(rot)], [width, height, depth]


@dataclass(frozen=True)
class _SkinAccessors:
    """The accessor ids of one skinned mesh: vertex attributes, indices, inverse bind matrices."""

    position: int
    normal: int
    joints: int
    weights: int
    indices: int
    inverse_bind: int

    def attributes(self) -> gl.Attributes:
        return gl.Attributes(
            POSITION=self.position, NORMAL=self.normal, JOINTS_0=self.joints, WEIGHTS_0=self.weights
        )


def _inverse_bind(w: _Writer, bind_joints: NDArray[np.float64], name: str) -> int:
    """The accessor of the 22 inverse bind matrices of a mesh bound at ``bind_joints`` (no rotation)."""
    ibm = np.tile(np.eye(4, dtype=np.float32), (NUM_JOINTS, 1, 1))
    ibm[:, :3, 3] = -bind_joints
    return w.accessor(np.swapaxes(ibm, 1, 2).reshape(NUM_JOINTS, 16), gl.MAT4, gl.FLOAT, name=name)


def _body_accessors(w: _Writer, body: SkinnedBody, name: str) -> _SkinAccessors:
    """Accessors of a :class:`SkinnedBody`."""
    position = w.accessor(body.vertices.astype(np.float32), gl.VEC3, gl.FLOAT, target=gl.ARRAY_BUFFER, bounds=True, name=name)
    normal = w.accessor(vertex_normals(body.vertices, body.faces).astype(np.float32), gl.VEC3, gl.FLOAT, target=gl.ARRAY_BUFFER)
    joints = w.accessor(body.joints.astype(np.uint8), gl.VEC4, gl.UNSIGNED_BYTE, target=gl.ARRAY_BUFFER)
    weights = w.accessor(body.weights.astype(np.float32), gl.VEC4, gl.FLOAT, target=gl.ARRAY_BUFFER)
    wide = body.vertices.shape[0] > 65535
    indices = w.accessor(
        body.faces.reshape(-1).astype(np.uint32 if wide else np.uint16),
        gl.SCALAR,
        gl.UNSIGNED_INT if wide else gl.UNSIGNED_SHORT,
        target=gl.ELEMENT_ARRAY_BUFFER,
    )
    inverse_bind = _inverse_bind(w, body.bind_joints, f"{name}:inverse_bind")
    return _SkinAccessors(position, normal, joints, weights, indices, inverse_bind)


def _box_figure_accessors(w: _Writer) -> _SkinAccessors:
    """Accessors of the box figure (:func:`character_mesh`), shared by every character without a body."""
    positions, normals, triangles, joint_ids = character_mesh()
    position = w.accessor(
        positions.astype(np.float32), gl.VEC3, gl.FLOAT, target=gl.ARRAY_BUFFER, bounds=True, name="body"
    )
    normal = w.accessor(normals.astype(np.float32), gl.VEC3, gl.FLOAT, target=gl.ARRAY_BUFFER)
    joints4 = np.zeros((joint_ids.size, 4), dtype=np.uint8)
    joints4[:, 0] = joint_ids
    weights4 = np.zeros((joint_ids.size, 4), dtype=np.float32)
    weights4[:, 0] = 1.0
    joints = w.accessor(joints4, gl.VEC4, gl.UNSIGNED_BYTE, target=gl.ARRAY_BUFFER)
    weights = w.accessor(weights4, gl.VEC4, gl.FLOAT, target=gl.ARRAY_BUFFER)
    indices = w.accessor(
        triangles.reshape(-1).astype(np.uint16), gl.SCALAR, gl.UNSIGNED_SHORT, target=gl.ELEMENT_ARRAY_BUFFER
    )
    inverse_bind = _inverse_bind(w, rest_positions(), "inverse_bind")
    return _SkinAccessors(position, normal, joints, weights, indices, inverse_bind)


def _floor_node(scene: Scene, mesh: int) -> gl.Node:
    """The floor slab over the scene bounds, its top face at ``floor_z``."""
    lo, hi = np.array(scene.bounds_min), np.array(scene.bounds_max)
    center = WORLD_TO_GLTF @ np.array([*(lo + hi) / 2, scene.floor_z - FLOOR_THICKNESS / 2])
    size = [float(hi[0] - lo[0]), FLOOR_THICKNESS, float(hi[1] - lo[1])]
    return gl.Node(name="floor", mesh=mesh, translation=[float(x) for x in center], scale=size)


def _scene_node(w: _Writer, scene: Scene) -> int:
    """The ``objects`` node: a scaled unit cube per object (one mesh per label) and the floor."""
    pos, nrm, tri = box_mesh(np.zeros((1, 3)), np.eye(3)[None], np.full((1, 3), 0.5))
    cube_pos = w.accessor(
        pos.astype(np.float32), gl.VEC3, gl.FLOAT, target=gl.ARRAY_BUFFER, bounds=True, name="cube"
    )
    cube_nrm = w.accessor(nrm.astype(np.float32), gl.VEC3, gl.FLOAT, target=gl.ARRAY_BUFFER)
    cube_idx = w.accessor(
        tri.reshape(-1).astype(np.uint16), gl.SCALAR, gl.UNSIGNED_SHORT, target=gl.ELEMENT_ARRAY_BUFFER
    )
    label_mesh: dict[str, int] = {}
    children: list[int] = []
    for obj in [*scene.objects, None]:
        label = "floor" if obj is None else obj.label
        if label not in label_mesh:
            mat = w.material(label, (0.8, 0.8, 0.78) if obj is None else _label_color(label))
            label_mesh[label] = w.mesh(label, gl.Attributes(POSITION=cube_pos, NORMAL=cube_nrm), cube_idx, mat)
        if obj is None:
            node = _floor_node(scene, label_mesh[label])
        else:
            t, r, s = _object_trs(obj)
            node = gl.Node(name=obj.name, mesh=label_mesh[label], translation=t, rotation=r, scale=s)
        children.append(w.node(node))
    return w.node(gl.Node(name="objects", children=children))


def _track_pose(
    track: CharacterTrack, body: SkinnedBody | None, joints: JointRotations | None
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A track in the glTF frame: root translations (N, 3), sign-continuous quaternions
    (N, 22, 4) and the joints' rest offsets (22, 3) of its figure or body."""
    if body is None:
        offsets, root_world = REST_OFFSETS, track.root_positions
    else:  # the body's rest joints, and its pelvis at trans + J0 (see the module docstring)
        rest = body.bind_joints
        offsets = np.vstack([rest[:1], rest[1:] - rest[list(PARENTS[1:])]])
        root_world = track.root_positions + (rest[0] - REST_OFFSETS[0])
    root_t = root_world @ WORLD_TO_GLTF.T
    if joints is None:
        joints = JointRotations.of(track)
    quats = _continuous(joints.with_root(WORLD_TO_GLTF).as_quat().reshape(track.num_frames, NUM_JOINTS, 4))
    return root_t, quats, offsets


def _joint_nodes(
    w: _Writer, name: str, root_t: NDArray[np.float64], quats: NDArray[np.float64], offsets: NDArray[np.float64]
) -> list[int]:
    """The joint hierarchy of character ``name`` at its first frame's pose (node ids in joint order)."""
    node_ids: list[int] = []
    for j in range(NUM_JOINTS):
        offset = root_t[0] if j == 0 else offsets[j]
        node = gl.Node(
            name=f"{name}:{JOINT_NAMES[j]}",
            translation=[float(x) for x in offset],
            rotation=[float(x) for x in quats[0, j]],
        )
        node_ids.append(w.node(node))
    for j in range(1, NUM_JOINTS):
        w.gltf.nodes[node_ids[PARENTS[j]]].children.append(node_ids[j])
    return node_ids


def _skinned_body_node(w: _Writer, name: str, color: Sequence[float], skin: _SkinAccessors, node_ids: list[int]) -> int:
    """The skinned mesh node ``<name>:body`` bound to the joint nodes ``node_ids``."""
    material = w.material(f"{name}:skin", color)
    mesh = w.mesh(f"{name}:body", skin.attributes(), skin.indices, material)
    w.gltf.skins.append(
        gl.Skin(name=name, inverseBindMatrices=skin.inverse_bind, skeleton=node_ids[0], joints=node_ids)
    )
    return w.node(gl.Node(name=f"{name}:body", mesh=mesh, skin=len(w.gltf.skins) - 1))


def _animate(
    w: _Writer,
    animation: gl.Animation,
    times_acc: int,
    node_ids: list[int],
    root_t: NDArray[np.float64],
    quats: NDArray[np.float64],
) -> None:
    """One LINEAR channel for the root translation and one per joint rotation, keyed at ``times_acc``."""
    outputs = [
        (node_ids[0], gl.TRANSLATION, w.accessor(root_t.astype(np.float32), gl.VEC3, gl.FLOAT, bounds=True))
    ]
    for j in range(NUM_JOINTS):
        acc = w.accessor(np.ascontiguousarray(quats[:, j]).astype(np.float32), gl.VEC4, gl.FLOAT, bounds=True)
        outputs.append((node_ids[j], gl.ROTATION, acc))
    for node_id, path, acc in outputs:
        animation.samplers.append(gl.AnimationSampler(input=times_acc, output=acc, interpolation=gl.ANIM_LINEAR))
        target = gl.AnimationChannelTarget(node=node_id, path=path)
        animation.channels.append(gl.AnimationChannel(sampler=len(animation.samplers) - 1, target=target))


def _time_accessor(w: _Writer, cache: dict[tuple[int, float], int], track: CharacterTrack) -> int:
    """The key times of ``track``, one accessor per (frame count, rate)."""
    n = track.num_frames
    key = (n, track.fps)
    if key not in cache:
        cache[key] = w.accessor(
            track.times.astype(np.float32), gl.SCALAR, gl.FLOAT, bounds=True, name=f"time_{n}@{track.fps:g}"
        )
    return cache[key]


def _check_names(tracks: Sequence[CharacterTrack], bodies: Mapping[str, SkinnedBody]) -> None:
    names = [t.name for t in tracks]
    if len(set(names)) != len(names):
        raise ValueError(f"character names must be unique, got {names}")
    if unknown := sorted(set(bodies) - set(names)):
        raise ValueError(f"bodies for characters not in the run: {unknown}")


def build_glb(
    scene: Scene | None,
    tracks: Sequence[CharacterTrack],
    bodies: Mapping[str, SkinnedBody] | None = None,
    rotations: Mapping[str, JointRotations] | None = None,
) -> gl.GLTF2:
    """The glTF document (binary blob attached) for ``scene`` (may be None) and ``tracks``.

    ``bodies`` (by character name) replaces a character's box figure with its body mesh.
    ``rotations`` (by character name): a track's joint rotations converted once for every
    exporter (default: converted here). The writer's calls run in a fixed order (scene, box
    figure, then per character), which fixes the output bytes.
    """
    bodies = dict(bodies or {})
    _check_names(tracks, bodies)
    w = _Writer()
    top: list[int] = []
    if scene is not None:
        top.append(_scene_node(w, scene))
    figure = _box_figure_accessors(w) if any(t.name not in bodies for t in tracks) else None
    animation = gl.Animation(name=ANIMATION_NAME)
    time_accessors: dict[tuple[int, float], int] = {}
    for index, track in enumerate(tracks):
        body_of = bodies.get(track.name)
        root_t, quats, offsets = _track_pose(track, body_of, (rotations or {}).get(track.name))
        node_ids = _joint_nodes(w, track.name, root_t, quats, offsets)
        color = CHARACTER_COLORS[index % len(CHARACTER_COLORS)]
        if body_of is None:
            assert figure is not None  # built above for every character without a body
            skin = figure
        else:
            skin = _body_accessors(w, body_of, f"{track.name}:body")
        body = _skinned_body_node(w, track.name, color, skin, node_ids)
        # The skinned mesh node sits at the scene root (parent transforms never move a skin).
        top.extend([w.node(gl.Node(name=track.name, children=[node_ids[0]])), body])
        _animate(w, animation, _time_accessor(w, time_accessors, track), node_ids, root_t, quats)
    if animation.channels:
        w.gltf.animations.append(animation)
    w.gltf.scenes.append(gl.Scene(name="storyteller", nodes=top))
    w.gltf.scene = 0
    w.gltf.buffers.append(gl.Buffer(byteLength=len(w.blob)))
    _escape_names(w.gltf)
    w.gltf.set_binary_blob(bytes(w.blob))
    return w.gltf


def _escape_names(gltf: gl.GLTF2) -> None:
    """Every name of ``gltf`` through ``plain``, in place."""
    for group in (gltf.scenes, gltf.nodes, gltf.meshes, gltf.materials, gltf.skins, gltf.accessors, gltf.animations):
        for item in group:
            if item.name is not None:
                item.name = plain(item.name)


def glb_bytes(
    scene: Scene | None,
    tracks: Sequence[CharacterTrack],
    bodies: Mapping[str, SkinnedBody] | None = None,
    rotations: Mapping[str, JointRotations] | None = None,
) -> bytes:
    """The GLB file content for ``scene`` and ``tracks`` (deterministic)."""
    return b"".join(build_glb(scene, tracks, bodies, rotations).save_to_bytes())


def export_glb(
    path: str | Path,
    scene: Scene | None,
    tracks: Sequence[CharacterTrack],
    bodies: Mapping[str, SkinnedBody] | None = None,
    rotations: Mapping[str, JointRotations] | None = None,
) -> Path:
    """Write the whole run as one GLB (see the module docstring). Returns the path."""
    path = Path(path)
    write_file(path, glb_bytes(scene, tracks, bodies, rotations))
    return path

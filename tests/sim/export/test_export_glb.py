"""Whole-run GLB: read back with pygltflib (and trimesh), evaluated independently of the writer."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pygltflib as gl
import pytest
import trimesh
from pygltflib.validator import validate

from storyteller.benchmark.support.random_tracks import random_track
from storyteller.sim.body.skeleton import (
    BODY_TO_WORLD,
    JOINT_NAMES,
    PARENTS,
    forward_kinematics,
    rest_positions,
)
from storyteller.sim.export.box_figure import box_mesh, character_mesh
from storyteller.sim.export.bundle import export_run
from storyteller.sim.export.glb import export_glb, glb_bytes
from storyteller.sim.run_folder_names import file_slug
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.world.character_track import CharacterTrack
from tests.support.gltf_eval import COMPONENTS as _WIDTH
from tests.support.gltf_eval import NUMPY_DTYPES as _NUMPY
from tests.support.gltf_eval import read_accessor as _read
from tests.support.gltf_eval import world_matrices as _world_matrices


def _scene() -> Scene:
    objects = (
        SceneObject(
            name="table_0", label="table", idx=0, center=(1.0, 2.0, 0.375), size=(1.2, 0.8, 0.75)
        ),
        SceneObject(
            name="chair_0",
            label="chair",
            idx=0,
            center=(1.0, 1.3, 0.45),
            size=(0.5, 0.5, 0.9),
            facing=(0.0, 1.0),
            has_facing=True,
        ),
        SceneObject(
            name="chair_1",
            label="chair",
            idx=1,
            center=(-1.0, 0.5, 0.45),
            size=(0.5, 0.6, 0.9),
            facing=(1.0, 1.0),
            has_facing=True,
        ),
    )
    return Scene(name="tiny", bounds_min=(-3.0, -2.0), bounds_max=(4.0, 5.0), objects=objects)


def _tracks() -> list[CharacterTrack]:
    return [
        random_track("ann", 45, seed=1),
        random_track("bob", 45, seed=2),
        random_track("cy", 30, seed=3),
    ]


@pytest.fixture(scope="module")
def glb(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, gl.GLTF2]:
    path = export_glb(tmp_path_factory.mktemp("glb") / "run.glb", _scene(), _tracks())
    return path, gl.GLTF2.load(str(path))


def test_glb_validates_and_accessors_are_consistent(glb: tuple[Path, gl.GLTF2]) -> None:
    _, doc = glb
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "provisional function" notice
        validate(doc)
    blob_len = len(doc.binary_blob())
    assert doc.buffers[0].byteLength == blob_len
    for i, acc in enumerate(doc.accessors):
        view = doc.bufferViews[acc.bufferView]
        size = np.dtype(_NUMPY[acc.componentType]).itemsize * _WIDTH[acc.type] * acc.count
        assert view.byteOffset % 4 == 0 and view.byteLength == size
        assert view.byteOffset + view.byteLength <= blob_len
        data = _read(doc, i).reshape(acc.count, -1)
        assert np.isfinite(data.astype(float)).all()
        if acc.min:
            np.testing.assert_array_equal(acc.min, data.min(axis=0))
            np.testing.assert_array_equal(acc.max, data.max(axis=0))
    for mesh in doc.meshes:
        prim = mesh.primitives[0]
        position = doc.accessors[prim.attributes.POSITION]
        assert position.type == gl.VEC3 and position.min and position.max
        assert doc.accessors[prim.attributes.NORMAL].count == position.count
        indices = _read(doc, prim.indices)
        assert indices.size % 3 == 0 and indices.max() < position.count


def test_glb_nodes_skins_and_animation(glb: tuple[Path, gl.GLTF2]) -> None:
    _, doc = glb
    names = [n.name for n in doc.nodes]
    for obj in _scene().objects:
        assert names.count(obj.name) == 1
    assert "floor" in names and "objects" in names
    tracks = _tracks()
    assert len(doc.skins) == len(tracks)
    anim = doc.animations[0]
    for track, skin in zip(tracks, doc.skins, strict=True):
        assert len(skin.joints) == 22
        assert [doc.nodes[j].name for j in skin.joints] == [
            f"{track.name}:{n}" for n in JOINT_NAMES
        ]
        for j in range(1, 22):  # the hierarchy matches our parents
            assert skin.joints[j] in doc.nodes[skin.joints[PARENTS[j]]].children
        ibm = doc.accessors[skin.inverseBindMatrices]
        assert (ibm.type, ibm.count) == (gl.MAT4, 22)
        group = doc.nodes[names.index(track.name)]
        assert skin.joints[0] in group.children
        channels = [c for c in anim.channels if c.target.node in skin.joints]
        assert len(channels) == 23
        assert sorted(c.target.path for c in channels) == ["rotation"] * 22 + ["translation"]
        for c in channels:
            sampler = anim.samplers[c.sampler]
            assert sampler.interpolation == "LINEAR"
            times = _read(doc, sampler.input)
            assert (
                doc.accessors[sampler.input].count
                == track.num_frames
                == doc.accessors[sampler.output].count
            )
            np.testing.assert_allclose(times, track.times, atol=1e-6)
            assert doc.accessors[sampler.input].max == [pytest.approx(track.duration, abs=1e-6)]
            if c.target.path == "rotation":
                q = _read(doc, sampler.output)
                np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-6)
                assert (np.einsum("ni,ni->n", q[1:], q[:-1]) >= 0).all()  # sign-continuous


@pytest.mark.parametrize("frame", [0, 17, 29])
def test_glb_evaluates_to_our_joint_positions(glb: tuple[Path, gl.GLTF2], frame: int) -> None:
    """Joint nodes, evaluated from the file alone, sit where our FK puts the joints (< 1 mm)."""
    _, doc = glb
    world = _world_matrices(doc, frame)
    gltf_to_world = BODY_TO_WORLD
    for track, skin in zip(_tracks(), doc.skins, strict=True):
        ours = track.joint_positions()[frame]
        theirs = np.array([world[j][:3, 3] for j in skin.joints]) @ gltf_to_world.T
        assert np.linalg.norm(theirs - ours, axis=1).max() < 1e-3
        # Skinning: each vertex follows its joint rigidly; the bind pose puts the mesh on the bones.
        mesh = doc.meshes[doc.nodes[[n.name for n in doc.nodes].index(f"{track.name}:body")].mesh]
        prim = mesh.primitives[0]
        pos = _read(doc, prim.attributes.POSITION).astype(float)
        joint_of = _read(doc, prim.attributes.JOINTS_0)[:, 0]
        ibm = _read(doc, skin.inverseBindMatrices).reshape(22, 4, 4).transpose(0, 2, 1)
        skinning = np.array([world[j] for j in skin.joints]) @ ibm
        skinned = np.einsum(
            "vij,vj->vi", skinning[joint_of], np.column_stack([pos, np.ones(len(pos))])
        )[:, :3]
        skinned_world = skinned @ gltf_to_world.T
        # each vertex moves rigidly with its joint: ours[j] + G_j (v_rest - rest_j)
        glob = forward_kinematics(track.local_rotations[frame], track.root_positions[frame])[1]
        expected = ours[joint_of] + np.einsum(
            "vij,vj->vi", glob[joint_of], pos - rest_positions()[joint_of]
        )
        assert np.linalg.norm(skinned_world - expected, axis=1).max() < 1e-3


def test_glb_objects_sit_where_the_scene_says(glb: tuple[Path, gl.GLTF2]) -> None:
    _, doc = glb
    world = _world_matrices(doc, 0)
    names = [n.name for n in doc.nodes]
    cube = box_mesh(np.zeros((1, 3)), np.eye(3)[None], np.full((1, 3), 0.5))[0]
    for obj in _scene().objects:
        m = world[names.index(obj.name)]
        corners = (np.column_stack([cube, np.ones(len(cube))]) @ m.T)[:, :3] @ BODY_TO_WORLD.T
        np.testing.assert_allclose(corners.min(axis=0)[2], obj.z_min, atol=1e-6)
        np.testing.assert_allclose(corners.max(axis=0)[2], obj.z_max, atol=1e-6)
        footprint = obj.footprint()
        for corner in corners[:, :2]:
            assert np.min(np.linalg.norm(footprint - corner, axis=1)) < 1e-5
        # the object's own front (+y in its z-up frame) is -z in its glTF frame
        f = BODY_TO_WORLD @ (m[:3, :3] @ np.array([0.0, 0.0, -1.0]))
        np.testing.assert_allclose(f[:2] / np.linalg.norm(f[:2]), obj.facing, atol=1e-6)


def test_character_mesh_is_closed_boxes_with_outward_normals() -> None:
    positions, normals, triangles, joints = character_mesh()
    assert positions.shape == normals.shape and joints.shape == (positions.shape[0],)
    assert set(joints.tolist()) <= set(range(22))
    a, b, c = (positions[triangles[:, k]] for k in range(3))
    face_n = np.cross(b - a, c - a)
    face_n /= np.linalg.norm(face_n, axis=1, keepdims=True)
    np.testing.assert_allclose(face_n, normals[triangles[:, 0]], atol=1e-9)


def test_trimesh_loads_static_part(glb: tuple[Path, gl.GLTF2]) -> None:
    path, _ = glb
    loaded = trimesh.load(str(path))
    assert isinstance(loaded, trimesh.Scene)
    instances = loaded.graph.nodes_geometry
    assert len(instances) == len(_scene().objects) + 1 + len(_tracks())  # objects, floor, bodies
    assert {"table_0", "chair_0", "chair_1", "floor"} <= set(instances)


def test_glb_is_deterministic_and_handles_edge_cases(tmp_path: Path) -> None:
    assert glb_bytes(_scene(), _tracks()) == glb_bytes(_scene(), _tracks())
    only_scene = gl.GLTF2.load_from_bytes(glb_bytes(_scene(), []))
    assert not only_scene.animations and not only_scene.skins
    only_tracks = gl.GLTF2.load_from_bytes(glb_bytes(None, _tracks()[:1]))
    assert len(only_tracks.skins) == 1
    one_frame = gl.GLTF2.load_from_bytes(glb_bytes(None, [random_track("z", 1, seed=0)]))
    assert one_frame.accessors[one_frame.animations[0].samplers[0].input].count == 1
    with pytest.raises(ValueError, match="unique"):
        glb_bytes(None, [random_track("x", 3, seed=0), random_track("x", 3, seed=1)])


def test_export_run_writes_everything(tmp_path: Path) -> None:
    tracks = _tracks()
    out = export_run(tmp_path / "run", _scene(), tracks)
    assert all(p.is_file() and p.stat().st_size > 0 for p in out.all_paths())
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == sorted(
        ["scene.glb"]
        + [f"{t.name}.{ext}" for t in tracks for ext in ("smplx.npz", "bvh", "track.npz")]
    )
    back = CharacterTrack.load(out.tracks["bob"])
    np.testing.assert_array_equal(back.local_rotations, tracks[1].local_rotations)
    again = export_run(tmp_path / "again", _scene(), tracks)
    for a, b in zip(out.all_paths(), again.all_paths(), strict=True):
        assert a.read_bytes() == b.read_bytes()


def test_export_run_refuses_colliding_file_names(tmp_path: Path) -> None:
    assert file_slug("Dr. Who") == "Dr__Who"
    tracks = [random_track("a b", 2, seed=0), random_track("a_b", 2, seed=1)]
    with pytest.raises(ValueError, match="collide"):
        export_run(tmp_path, None, tracks)

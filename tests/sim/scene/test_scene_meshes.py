"""Instance-segmented meshes -> scenes: names, boxes, facing, up axis, floor, bad files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from storyteller.sim.scene.files import SceneFileError, load_scene
from storyteller.sim.scene.meshes import load_mesh_scene, parse_instance_name, yaw_box


@pytest.mark.parametrize(
    ("raw", "expected"),
    [
        ("chair_3", ("chair", 3)),
        ("Chair.003", ("chair", 3)),
        ("coffee maker 2", ("coffee_maker", 2)),
        ("CoffeeMaker-2", ("coffee_maker", 2)),
        ("chair3", ("chair", 3)),
        ("WaterDispenser_01", ("water_dispenser", 1)),
        ("TV", ("tv", None)),
        ("Chair", ("chair", None)),
        ("white board", ("white_board", None)),
        ("3", ("object", 3)),
        ("", ("object", None)),
        ("  Bar Counter #12 ", ("bar_counter", 12)),
    ],
)
def test_parse_instance_name(raw: str, expected: tuple[str, int | None]) -> None:
    assert parse_instance_name(raw) == expected


@settings(max_examples=60, deadline=None)
@given(
    w=st.floats(0.05, 4.0),
    d=st.floats(0.05, 4.0),
    angle=st.floats(-math.pi, math.pi),
    cx=st.floats(-10, 10),
    cy=st.floats(-10, 10),
)
def test_yaw_box_recovers_a_rotated_rectangle(
    w: float, d: float, angle: float, cx: float, cy: float
) -> None:
    u = np.array([math.cos(angle), math.sin(angle)])
    v = np.array([-u[1], u[0]])
    corners = np.array(
        [
            c + s * (w / 2) * u + t * (d / 2) * v
            for c in [np.array([cx, cy])]
            for s in (-1, 1)
            for t in (-1, 1)
        ]
    )
    inner = np.array([cx, cy]) + 0.3 * (
        corners - np.array([cx, cy])
    )  # inside points change nothing
    center, axes, extents = yaw_box(np.vstack([corners, inner]))
    assert center == pytest.approx([cx, cy], abs=1e-6)
    assert sorted(extents) == pytest.approx(sorted([w, d]), abs=1e-6)
    assert abs(abs(float(axes[0] @ u)) - 1.0) < 1e-6 or abs(float(axes[0] @ u)) < 1e-6
    assert float(axes[0][0] * axes[1][1] - axes[0][1] * axes[1][0]) == pytest.approx(
        1.0
    )  # right-handed


def test_yaw_box_degenerate_inputs() -> None:
    center, _, extents = yaw_box(np.array([[1.0, 2.0]]))
    assert center == pytest.approx([1.0, 2.0]) and extents == pytest.approx([0.0, 0.0])
    center, _, extents = yaw_box(np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 0.0]]))
    assert center == pytest.approx([1.0, 0.0]) and sorted(extents) == pytest.approx([0.0, 2.0])


def _box_z_up(size: tuple[float, float, float]) -> trimesh.Trimesh:
    """A box standing on z = 0 (z-up file frame)."""
    box: trimesh.Trimesh = trimesh.creation.box(size)
    box.apply_translation([0.0, 0.0, size[2] / 2])
    return box


def _box_y_up(size_xyz: tuple[float, float, float]) -> trimesh.Trimesh:
    """A box standing on y = 0 in a glTF (Y-up) frame; ``size_xyz`` in glTF axes."""
    box: trimesh.Trimesh = trimesh.creation.box(size_xyz)
    box.apply_translation([0.0, size_xyz[1] / 2, 0.0])
    return box


def _gltf_pose(yaw_about_up: float, position_xyz: tuple[float, float, float]) -> np.ndarray:
    transform: np.ndarray = trimesh.transformations.rotation_matrix(yaw_about_up, [0.0, 1.0, 0.0])
    transform[:3, 3] = position_xyz
    return transform


def test_glb_nodes_become_objects_with_facing_and_z_up(tmp_path: Path) -> None:
    scene = trimesh.Scene()
    # A chair 0.5 wide (x), 0.9 tall (glTF y), 0.6 deep (glTF z); front = glTF +Z.
    # Turned +90 deg about glTF's up axis, its front points to glTF +X = our +x.
    scene.add_geometry(
        _box_y_up((0.5, 0.9, 0.6)),
        node_name="Chair.003",
        geom_name="chair_mesh",
        transform=_gltf_pose(math.pi / 2, (2.0, 0.0, -1.0)),
    )
    # The same mesh, not turned: front = glTF +Z = our -y. Same geometry, auto-indexed name.
    scene.add_geometry(
        _box_y_up((0.5, 0.9, 0.6)),
        node_name="Chair",
        geom_name="chair_mesh2",
        transform=_gltf_pose(0.0, (4.0, 0.0, 0.0)),
    )
    scene.add_geometry(_box_y_up((1.2, 0.75, 0.8)), node_name="dining table", geom_name="t")
    # A coffee maker standing on the table top (glTF y = 0.75).
    scene.add_geometry(
        _box_y_up((0.25, 0.35, 0.3)),
        node_name="coffee maker 2",
        geom_name="cm",
        transform=_gltf_pose(0.0, (0.2, 0.75, 0.0)),
    )
    path = tmp_path / "room.glb"
    scene.export(path)

    loaded = load_scene(path)
    assert loaded.name == "room"
    assert sorted(loaded.object_names) == ["chair_1", "chair_3", "coffee_maker_2", "dining_table_1"]
    chair3 = loaded.get("chair_3")
    assert chair3.center == pytest.approx((2.0, 1.0, 0.45), abs=1e-6)  # glTF z = -1 -> our y = +1
    assert chair3.facing == pytest.approx((1.0, 0.0), abs=1e-6) and chair3.has_facing
    assert chair3.size == pytest.approx((0.5, 0.6, 0.9), abs=1e-6)  # width across the facing
    assert chair3.sit_offset_vertical == pytest.approx(0.45) and chair3.is_seat
    chair1 = loaded.get("chair_1")
    assert chair1.facing == pytest.approx((0.0, -1.0), abs=1e-6)
    table = loaded.get("dining_table_1")
    assert not table.has_facing and table.z_min == pytest.approx(0.0, abs=1e-6)
    assert sorted(table.size[:2]) == pytest.approx([0.8, 1.2], abs=1e-6)
    maker = loaded.get("coffee_maker_2")
    assert maker.z_min == pytest.approx(0.75, abs=1e-6)
    assert maker.size == pytest.approx((0.25, 0.3, 0.35), abs=1e-6)
    assert maker.facing == pytest.approx((0.0, -1.0), abs=1e-6)
    # bounds: footprints grown by the margin
    assert loaded.bounds_min[0] < -0.6 and loaded.bounds_max[0] > 4.25


def test_glb_yaw_rotated_node_gives_oriented_box(tmp_path: Path) -> None:
    scene = trimesh.Scene()
    angle = math.radians(30.0)
    scene.add_geometry(
        _box_y_up((2.0, 0.85, 0.9)),
        node_name="couch_1",
        geom_name="c",
        transform=_gltf_pose(angle, (0.0, 0.0, 0.0)),
    )
    path = tmp_path / "couch.glb"
    scene.export(path)
    couch = load_mesh_scene(path).get("couch_1")
    assert couch.size == pytest.approx((2.0, 0.9, 0.85), abs=1e-5)
    # glTF +Z turned 30 deg about +Y is (sin 30, 0, cos 30); in z-up that is (sin 30, -cos 30).
    assert couch.facing == pytest.approx((math.sin(angle), -math.cos(angle)), abs=1e-5)


def _obj_text(blocks: list[tuple[str, trimesh.Trimesh]]) -> str:
    lines, offset = [], 0
    for name, mesh in blocks:
        lines.append(f"o {name}")
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertices]
        lines += [f"f {a + 1 + offset} {b + 1 + offset} {c + 1 + offset}" for a, b, c in mesh.faces]
        offset += len(mesh.vertices)
    return "\n".join(lines) + "\n"


def _moved(mesh: trimesh.Trimesh, x: float, y: float, z: float = 0.0) -> trimesh.Trimesh:
    out = mesh.copy()
    out.apply_translation([x, y, z])
    return out


def test_obj_objects_with_floor_node(tmp_path: Path) -> None:
    floor = trimesh.creation.box((6.0, 5.0, 0.1))
    floor.apply_translation([3.0, 2.5, 0.95])  # top at z = 1.0: everything shifts down by 1 m
    blocks = [
        ("Floor", floor),
        ("fridge", _moved(_box_z_up((0.7, 0.7, 1.8)), 1.0, 1.0, 1.0)),
        ("stool", _moved(_box_z_up((0.4, 0.4, 0.75)), 3.0, 3.0, 1.0)),
        ("stool.001", _moved(_box_z_up((0.4, 0.4, 0.75)), 4.0, 3.0, 1.0)),
        ("potted plant", _moved(_box_z_up((0.5, 0.5, 1.2)), 5.0, 4.0, 1.0)),
    ]
    path = tmp_path / "kitchen.obj"
    path.write_text(_obj_text(blocks))
    scene = load_scene(path)
    assert sorted(scene.object_names) == ["fridge_1", "potted_plant_1", "stool_1", "stool_2"]
    assert scene.bounds_min == pytest.approx((0.0, 0.0), abs=1e-6)
    assert scene.bounds_max == pytest.approx((6.0, 5.0), abs=1e-6)
    fridge = scene.get("fridge_1")
    assert fridge.z_min == pytest.approx(0.0, abs=1e-6) and fridge.height == pytest.approx(
        1.8, abs=1e-6
    )
    assert fridge.facing == pytest.approx((0.0, -1.0), abs=1e-6)  # z-up file: front = local -y
    stool = scene.get("stool_1")
    assert stool.sit_offset_vertical == pytest.approx(0.75, abs=1e-6)  # a stool's seat is its top
    assert not stool.has_facing


def test_obj_y_up_option(tmp_path: Path) -> None:
    path = tmp_path / "y.obj"
    path.write_text(_obj_text([("tv_1", _box_y_up((1.2, 0.7, 0.08)))]))
    tv = load_mesh_scene(path, up_axis="y").get("tv_1")
    assert tv.height == pytest.approx(0.7, abs=1e-6) and tv.size[:2] == pytest.approx(
        (1.2, 0.08), abs=1e-6
    )
    assert load_mesh_scene(path).get("tv_1").height == pytest.approx(0.08, abs=1e-6)


def test_ply_single_mesh(tmp_path: Path) -> None:
    path = tmp_path / "bookshelf_4.ply"
    _box_z_up((1.0, 0.35, 1.9)).export(path)
    scene = load_scene(path)
    assert len(scene.objects) == 1 and scene.objects[0].height == pytest.approx(1.9, abs=1e-6)


def _empty_glb(path: Path) -> Path:
    gltf = pygltflib.GLTF2(scenes=[pygltflib.Scene(nodes=[])], scene=0)
    gltf.save_binary(str(path))
    return path


@pytest.mark.parametrize(
    ("case", "message", "obj"),
    [
        ("no-nodes", "no nodes with geometry", None),
        ("garbage", "cannot read mesh file", None),
        ("empty", "file is empty", None),
        ("duplicate-obj", "two OBJ objects", "table"),
        ("duplicate-resolved", "both resolve to this name", "chair_1"),
        ("only-floor", "only structural nodes", None),
        ("missing", "file not found", None),
    ],
)
def test_bad_mesh_files(tmp_path: Path, case: str, message: str, obj: str | None) -> None:
    box = _box_z_up((0.5, 0.5, 0.5))
    if case == "no-nodes":
        path = _empty_glb(tmp_path / "x.glb")
    elif case == "garbage":
        path = tmp_path / "x.glb"
        path.write_bytes(b"\x00\x01garbage" * 50)
    elif case == "empty":
        path = tmp_path / "x.obj"
        path.write_bytes(b"")
    elif case == "duplicate-obj":
        path = tmp_path / "x.obj"
        path.write_text(_obj_text([("table", box), ("table", _moved(box, 2.0, 0.0))]))
    elif case == "duplicate-resolved":
        path = tmp_path / "x.obj"
        path.write_text(_obj_text([("chair_1", box), ("Chair.001", _moved(box, 2.0, 0.0))]))
    elif case == "only-floor":
        path = tmp_path / "x.obj"
        path.write_text(_obj_text([("floor", box)]))
    else:
        path = tmp_path / "absent.glb"
    with pytest.raises(SceneFileError) as info:
        load_scene(path)
    text = str(info.value)
    assert message in text and info.value.obj == obj
    assert text.startswith(str(path)) and "\n" not in text

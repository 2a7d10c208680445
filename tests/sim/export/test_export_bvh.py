"""BVH export, read back with the independent ``bvh`` package and our own small FK."""

from __future__ import annotations

from pathlib import Path
from typing import cast

import numpy as np
import pytest
from bvh import Bvh
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from storyteller.benchmark.support.random_tracks import random_track
from storyteller.sim.body.skeleton import BODY_TO_WORLD, JOINT_NAMES, PARENTS, REST_OFFSETS
from storyteller.sim.export.bvh import END_SITES, Units, bvh_text, depth_first_order, export_bvh
from storyteller.sim.world.character_track import CharacterTrack

_AXES = {"Xrotation": "X", "Yrotation": "Y", "Zrotation": "Z"}


def _fk_from_bvh(mocap: Bvh, scale: float) -> dict[str, np.ndarray]:
    """World positions (N, 3) per joint name, computed from the parsed channels (z-up metres)."""
    values = np.array(mocap.frames, dtype=float)
    n = values.shape[0]
    positions: dict[str, np.ndarray] = {}
    rotations: dict[str, np.ndarray] = {}
    for joint in mocap.get_joints():
        name = joint.name
        start = mocap.get_joint_channels_index(name)
        channels = mocap.joint_channels(name)
        rot_names = [c for c in channels if c in _AXES]
        seq = "".join(_AXES[c] for c in rot_names)  # uppercase: intrinsic, composed left to right
        angles = values[:, [start + channels.index(c) for c in rot_names]]
        local = Rotation.from_euler(seq, angles, degrees=True).as_matrix()
        offset = np.array(mocap.joint_offset(name)) / scale
        parent = mocap.joint_parent(name)
        if parent is None:
            pos = values[
                :, [start + channels.index(c) for c in ("Xposition", "Yposition", "Zposition")]
            ]
            positions[name] = offset + pos / scale
            rotations[name] = local
        else:
            p = parent.name
            positions[name] = positions[p] + np.einsum("nij,j->ni", rotations[p], offset)
            rotations[name] = rotations[p] @ local
        assert positions[name].shape == (n, 3)
    return {k: v @ BODY_TO_WORLD.T for k, v in positions.items()}


def _read(path: Path) -> Bvh:
    return Bvh(path.read_text())


@pytest.mark.parametrize(("units", "scale"), [("m", 1.0), ("cm", 100.0)])
def test_bvh_roundtrip_with_independent_reader(tmp_path: Path, units: Units, scale: float) -> None:
    track = random_track("ann", 120, seed=11, max_joint_angle=1.5)
    path = export_bvh(track, tmp_path / "ann.bvh", units=units)
    mocap = _read(path)
    assert mocap.nframes == 120 == len(mocap.frames)
    assert mocap.frame_time == pytest.approx(1 / 30, abs=1e-8)
    assert sorted(mocap.get_joints_names()) == sorted(JOINT_NAMES)
    assert mocap.get_joints_names()[0] == "pelvis"
    for name in JOINT_NAMES[1:]:
        parent = mocap.joint_parent(name)
        assert parent is not None and parent.name == JOINT_NAMES[PARENTS[JOINT_NAMES.index(name)]]
        np.testing.assert_allclose(
            np.array(mocap.joint_offset(name)) / scale,
            REST_OFFSETS[JOINT_NAMES.index(name)],
            atol=1e-9,
        )
        assert mocap.joint_channels(name) == ["Zrotation", "Xrotation", "Yrotation"]
    assert len(mocap.joint_channels("pelvis")) == 6
    assert len(mocap.search("End")) == len(END_SITES)
    ours = track.joint_positions()
    theirs = _fk_from_bvh(mocap, scale)
    for j, name in enumerate(JOINT_NAMES):
        error = np.linalg.norm(theirs[name] - ours[:, j], axis=-1).max()
        assert error < 1e-3, f"{name}: {error * 1000:.3f} mm"


def test_bvh_check_can_fail(tmp_path: Path) -> None:
    """A file with the wrong Euler order would be caught by the same comparison."""
    track = random_track("bo", 30, seed=12)
    text = bvh_text(track).replace("Zrotation Xrotation Yrotation", "Xrotation Yrotation Zrotation")
    theirs = _fk_from_bvh(Bvh(text), 1.0)
    error = np.linalg.norm(theirs["left_wrist"] - track.joint_positions()[:, 20], axis=-1)
    assert error.max() > 0.01


def test_bvh_is_deterministic_and_depth_first(tmp_path: Path) -> None:
    track = random_track("cy", 60, seed=13)
    a = export_bvh(track, tmp_path / "a.bvh").read_bytes()
    b = export_bvh(track, tmp_path / "b.bvh").read_bytes()
    assert a == b
    order = depth_first_order()
    assert sorted(order) == list(range(22))
    seen: set[int] = set()
    for j in order:  # every parent is listed before its children
        assert j == 0 or PARENTS[j] in seen
        seen.add(j)


def test_bvh_rejects_unknown_units(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="units"):
        export_bvh(random_track("d", 2, seed=1), tmp_path / "x.bvh", units=cast(Units, "in"))  # not a Units on purpose


def test_bvh_angles_have_no_wraps(tmp_path: Path) -> None:
    """A character spinning in place keeps continuous Euler curves (no 360-degree jumps)."""
    n = 90
    base = random_track("e", n, seed=14, max_joint_angle=0.2)
    spin = Rotation.from_euler("z", np.linspace(0, 4 * np.pi, n)[:, None]).as_matrix()
    rot = np.array(base.local_rotations)
    rot[:, 0] = spin @ BODY_TO_WORLD
    track = CharacterTrack(name="e", root_positions=base.root_positions, local_rotations=rot)
    mocap = Bvh(bvh_text(track))
    values = np.array(mocap.frames, dtype=float)[:, 3:]
    assert np.abs(np.diff(values, axis=0)).max() < 30.0
    theirs = _fk_from_bvh(mocap, 1.0)
    np.testing.assert_allclose(theirs["head"], track.joint_positions()[:, 15], atol=1e-4)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(10.0, 120.0))
def test_bvh_roundtrip_property(seed: int, fps: float) -> None:
    base = random_track("f", 8, seed=seed, max_joint_angle=3.0)
    track = CharacterTrack(
        name="f", root_positions=base.root_positions, local_rotations=base.local_rotations, fps=fps
    )
    mocap = Bvh(bvh_text(track))
    assert mocap.frame_time == pytest.approx(1 / fps, abs=1e-8)
    theirs = _fk_from_bvh(mocap, 1.0)
    ours = track.joint_positions()
    for j, name in enumerate(JOINT_NAMES):
        assert np.linalg.norm(theirs[name] - ours[:, j], axis=-1).max() < 1e-3

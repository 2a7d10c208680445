"""CharacterTrack and the SMPL-X .npz export, checked through the real ``smplx`` package."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import smplx
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from storyteller.benchmark.support.random_tracks import random_track
from storyteller.sim.body.skeleton import REST_OFFSETS, axis_angle_to_matrix, forward_kinematics, rest_positions
from storyteller.sim.export.smplx_npz import export_smplx_npz, smplx_parameters
from storyteller.sim.world.character_track import CharacterTrack, CharacterTrackError, write_npz
from tests.support.smplx_standin import (
    MODEL_PARENTS,
    NUM_FACES,
    NUM_MODEL_JOINTS,
    NUM_VERTICES,
    standin_joint_positions,
    standin_model_arrays,
    write_standin_model,
)

# ----- CharacterTrack ---------------------------------------------------------------------


def _still_track(n: int = 4) -> CharacterTrack:
    rot = np.broadcast_to(np.eye(3), (n, 22, 3, 3))
    return CharacterTrack(
        name="ann", root_positions=np.tile([0.0, 0.0, 0.93], (n, 1)), local_rotations=rot
    )


def test_track_defaults_and_readonly() -> None:
    track = _still_track()
    assert track.fps == 30.0 and track.gender == "neutral" and track.num_frames == 4
    np.testing.assert_array_equal(track.betas, np.zeros(10))
    np.testing.assert_allclose(track.times, [0, 1 / 30, 2 / 30, 3 / 30])
    with pytest.raises(ValueError):
        track.root_positions[0, 0] = 1.0


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"root_positions": np.zeros((4, 2))}, "root_positions"),
        ({"root_positions": np.full((4, 3), np.nan)}, "root_positions"),
        ({"local_rotations": np.zeros((4, 22, 3, 3))}, "local_rotations"),
        ({"local_rotations": np.broadcast_to(np.eye(3), (3, 22, 3, 3))}, "local_rotations"),
        ({"local_rotations": np.broadcast_to(-np.eye(3), (4, 22, 3, 3))}, "local_rotations"),
        ({"fps": 0.0}, "fps"),
        ({"fps": 1e-300}, "fps"),  # second hostile corpus: a track of 90 frames over 1e301 s was exported
        ({"fps": 1e6}, "fps"),
        ({"betas": np.zeros(16)}, "betas"),
        ({"gender": "robot"}, "gender"),
        ({"action_labels": ("walk",)}, "action_labels"),
        ({"name": " "}, "name"),
    ],
)
def test_track_rejects_bad_input(change: dict[str, object], field: str) -> None:
    base = _still_track()
    kwargs: dict[str, Any] = {  # Any: the changes are ill-typed on purpose (the track must reject them)
        "name": base.name,
        "root_positions": base.root_positions,
        "local_rotations": base.local_rotations,
    }
    kwargs.update(change)
    with pytest.raises(CharacterTrackError) as info:
        CharacterTrack(**kwargs)
    assert info.value.field == field
    assert field in str(info.value)


def test_track_save_load_roundtrip_and_bytes(tmp_path: Path) -> None:
    track = random_track("bob", 40, seed=3)
    track = CharacterTrack(
        name=track.name,
        root_positions=track.root_positions,
        local_rotations=track.local_rotations,
        betas=np.linspace(-1, 1, 10),
        gender="female",
        action_labels=tuple("walk" if i < 20 else "sit" for i in range(40)),
    )
    a = track.save(tmp_path / "a.npz")
    b = track.save(tmp_path / "b.npz")
    assert a.read_bytes() == b.read_bytes()
    back = CharacterTrack.load(a)
    assert (back.name, back.fps, back.gender, back.action_labels) == (
        "bob",
        30.0,
        "female",
        track.action_labels,
    )
    np.testing.assert_array_equal(back.local_rotations, track.local_rotations)
    np.testing.assert_array_equal(back.root_positions, track.root_positions)
    np.testing.assert_array_equal(back.betas, track.betas)


def test_track_load_bad_files(tmp_path: Path) -> None:
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(CharacterTrackError, match=r"junk\.npz"):
        CharacterTrack.load(junk)
    other = write_npz(tmp_path / "other.npz", {"format": np.array("something/else")})
    with pytest.raises(CharacterTrackError) as info:
        CharacterTrack.load(other)
    assert info.value.field == "format"
    arrays = {
        "format": np.array("storyteller-track/1"),
        "name": np.array("x"),
        "fps": np.array(30.0),
    }
    with pytest.raises(CharacterTrackError, match="root_positions"):
        CharacterTrack.load(write_npz(tmp_path / "partial.npz", arrays))


def test_write_npz_refuses_object_arrays(tmp_path: Path) -> None:
    with pytest.raises(TypeError, match="pickling"):
        write_npz(tmp_path / "o.npz", {"x": np.array([{}, 1], dtype=object)})


# ----- SMPL-X parameters ------------------------------------------------------------------


def test_smplx_npz_layout(tmp_path: Path) -> None:
    track = random_track("cy", 50, seed=5)
    path = export_smplx_npz(track, tmp_path / "cy.npz")
    with np.load(path) as data:
        shapes = {k: data[k].shape for k in data.files}
        poses = data["poses"]
        assert str(data["gender"]) == "neutral" and float(data["mocap_frame_rate"]) == 30.0
        assert str(data["surface_model_type"]) == "smplx"
        np.testing.assert_array_equal(data["root_orient"], poses[:, :3])
        np.testing.assert_array_equal(data["pose_body"], poses[:, 3:66])
        np.testing.assert_array_equal(data["pose_jaw"], poses[:, 66:69])
        np.testing.assert_array_equal(data["pose_eye"], poses[:, 69:75])
        np.testing.assert_array_equal(data["pose_hand"], poses[:, 75:])
        np.testing.assert_allclose(data["trans"], track.root_positions - REST_OFFSETS[0])
    assert shapes["poses"] == (50, 165) and shapes["trans"] == (50, 3) and shapes["betas"] == (10,)
    assert shapes["root_orient"] == (50, 3) and shapes["pose_body"] == (50, 63)
    assert shapes["pose_hand"] == (50, 90) and shapes["pose_eye"] == (50, 6)
    assert not np.any(poses[:, 66:])  # nothing animated beyond the body
    # The axis-angles give back our rotations.
    np.testing.assert_allclose(
        axis_angle_to_matrix(poses[:, :66].reshape(50, 22, 3)), track.local_rotations, atol=1e-9
    )
    assert export_smplx_npz(track, tmp_path / "again.npz").read_bytes() == path.read_bytes()


def test_smplx_labels_and_pelvis_rest() -> None:
    base = random_track("dee", 10, seed=8)
    track = CharacterTrack(
        name="dee",
        root_positions=base.root_positions,
        local_rotations=base.local_rotations,
        action_labels=("idle",) * 10,
    )
    params = smplx_parameters(track, pelvis_rest=np.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(params["trans"], track.root_positions - [0.0, 1.0, 0.0])
    assert list(params["action_labels"]) == ["idle"] * 10


def test_standin_model_layout() -> None:
    arrays = standin_model_arrays()
    assert arrays["v_template"].shape == (NUM_VERTICES, 3)
    assert arrays["f"].shape == (NUM_FACES, 3) and arrays["f"].max() < NUM_VERTICES
    assert arrays["shapedirs"].shape == (NUM_VERTICES, 3, 400)
    assert arrays["posedirs"].shape == (NUM_VERTICES, 3, 486)
    assert arrays["J_regressor"].shape == (NUM_MODEL_JOINTS, NUM_VERTICES)
    assert arrays["weights"].shape == (NUM_VERTICES, NUM_MODEL_JOINTS)
    np.testing.assert_allclose(arrays["weights"].sum(axis=1), 1.0)
    np.testing.assert_allclose(arrays["J_regressor"].sum(axis=1), 1.0)
    assert arrays["kintree_table"].shape == (2, NUM_MODEL_JOINTS)
    assert tuple(arrays["kintree_table"][0, 1:]) == MODEL_PARENTS[1:]
    assert all(p < j for j, p in enumerate(MODEL_PARENTS[1:], start=1))
    regressed = arrays["J_regressor"] @ arrays["v_template"]
    np.testing.assert_allclose(regressed, standin_joint_positions(), atol=1e-12)
    np.testing.assert_allclose(regressed[:22], rest_positions(), atol=1e-12)


@pytest.fixture(scope="module")
def standin_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("models")
    write_standin_model(root)
    return root


def _smplx_joints(root: Path, params: dict[str, np.ndarray], chunk: int = 100) -> np.ndarray:
    """Pose the stand-in through the real smplx package; returns (N, 22, 3) world joints."""
    n = params["poses"].shape[0]
    out = np.empty((n, 22, 3))
    model = smplx.create(
        str(root),
        model_type="smplx",
        gender=str(params["gender"]),
        ext="npz",
        use_pca=False,
        flat_hand_mean=True,
        num_betas=10,
        batch_size=chunk,
    )
    poses = torch.tensor(params["poses"], dtype=torch.float32)
    trans = torch.tensor(params["trans"], dtype=torch.float32)
    betas = torch.tensor(params["betas"], dtype=torch.float32)
    for start in range(0, n, chunk):
        p = poses[start : start + chunk]
        b = p.shape[0]
        if b < chunk:  # smplx sizes its landmark buffers by the model's batch size
            p = torch.cat([p, torch.zeros(chunk - b, 165)])
        t = torch.zeros(chunk, 3)
        t[:b] = trans[start : start + chunk]
        with torch.no_grad():
            result = model(
                betas=betas.expand(chunk, -1),
                global_orient=p[:, :3],
                body_pose=p[:, 3:66],
                jaw_pose=p[:, 66:69],
                leye_pose=p[:, 69:72],
                reye_pose=p[:, 72:75],
                left_hand_pose=p[:, 75:120],
                right_hand_pose=p[:, 120:165],
                expression=torch.zeros(chunk, model.num_expression_coeffs),
                transl=t,
            )
        out[start : start + b] = result.joints[:b, :22].numpy()
    return out


@pytest.mark.slow
def test_real_smplx_reproduces_our_joints(standin_root: Path, tmp_path: Path) -> None:
    """The issue's measure: exported parameters through smplx give our FK joints (< 1 mm)."""
    tracks = [random_track(f"c{i}", 100, seed=100 + i, max_joint_angle=1.2) for i in range(3)]
    for track in tracks:
        path = export_smplx_npz(track, tmp_path / f"{track.name}.npz")
        with np.load(path) as data:
            params = {k: data[k] for k in data.files}
        ours = track.joint_positions()
        theirs = _smplx_joints(standin_root, params)
        error = np.linalg.norm(theirs - ours, axis=-1).max()
        assert error < 1e-3, f"{track.name}: max joint error {error * 1000:.3f} mm"


def test_smplx_check_can_fail(standin_root: Path) -> None:
    """Guard against a vacuous comparison: a wrong transl convention is caught."""
    track = random_track("e", 20, seed=9)
    params = smplx_parameters(track)
    params["trans"] = track.root_positions  # forgetting to subtract the pelvis joint
    error = np.linalg.norm(
        _smplx_joints(standin_root, params, chunk=20) - track.joint_positions(), axis=-1
    )
    assert error.min() > 0.5


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_axis_angle_roundtrip_matches_fk(seed: int) -> None:
    track = random_track("f", 5, seed=seed, max_joint_angle=3.0)
    poses = smplx_parameters(track)["poses"]
    rot = axis_angle_to_matrix(poses[:, :66].reshape(5, 22, 3))
    pos = forward_kinematics(rot, track.root_positions)[0]
    np.testing.assert_allclose(pos, track.joint_positions(), atol=1e-9)

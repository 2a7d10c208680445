"""Skeleton FK, action labels, procedural clips (planted feet, valid rotations) and the cache."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from storyteller.sim.body.skeleton import JOINT_INDEX, forward_kinematics, heading_to_root, rest_positions
from storyteller.sim.motion.action_labels import (
    ACTION_LABELS,
    UnknownActionLabelError,
    action_spec,
    all_database_keys,
    database_key,
    family_of,
    playable_seated,
)
from storyteller.sim.motion.cache import cached_arrays, content_key
from storyteller.sim.motion.clips import FOOT_JOINTS, MotionClip
from storyteller.sim.motion.sources.procedural_actions import action_clip, sit_idle_clip, sitting_clip
from storyteller.sim.motion.sources.procedural_library import procedural_clips
from storyteller.sim.motion.sources.procedural_locomotion import locomotion_clips
from storyteller.sim.motion.sources.procedural_rig import TOE_HEIGHT, two_bone_ik
from tests.support.reference import TEST_CASES, requires_reference


def test_rest_pose_stands_on_the_floor_and_faces_heading() -> None:
    rest = rest_positions()
    assert rest[JOINT_INDEX["left_foot"], 1] == pytest.approx(TOE_HEIGHT)
    assert 1.45 < rest[JOINT_INDEX["head"], 1] < 1.75
    assert rest[JOINT_INDEX["left_hip"], 0] > 0  # body frame: left is +x
    rot = np.broadcast_to(np.eye(3), (22, 3, 3)).copy()
    for theta in (0.0, 1.0, -2.5):
        rot[0] = heading_to_root(theta)
        pos, _ = forward_kinematics(rot, np.array([0.0, 0.0, 0.93]))
        toe = pos[JOINT_INDEX["left_foot"]] - pos[JOINT_INDEX["left_ankle"]]
        assert np.arctan2(toe[1], toe[0]) == pytest.approx(theta, abs=0.15)
        assert pos[JOINT_INDEX["head"], 2] > pos[0, 2]
    assert heading_to_root(np.zeros(5)).shape == (5, 3, 3)


@requires_reference
def test_every_reference_action_label_is_covered() -> None:
    labels: set[str] = set()
    for f in TEST_CASES.glob("*/*.json"):
        labels.update(json.loads(f.read_text())["action_labels"])
    assert len(labels) >= 35
    assert labels <= set(ACTION_LABELS)


def test_label_families_looping_and_seated_variants() -> None:
    assert family_of("walk") == "locomotion"
    assert family_of("chat") == "partner" and action_spec("chat").loops
    assert family_of("use_coffee_maker") == "in_place" and not action_spec("turn_on_tv").loops
    assert action_spec("watch_tv").loops and action_spec("dance").loops
    assert family_of("sit_down") == "sitting"
    assert database_key("drink", seated=True) == "drink@seated"
    assert family_of("drink@seated") == "sitting"
    assert database_key("idle", seated=True) == "sit_idle"
    with pytest.raises(UnknownActionLabelError, match="did you mean 'drink'"):
        database_key("drnik")
    with pytest.raises(UnknownActionLabelError):
        database_key("handshake", seated=True)
    assert "use_laptop@seated" in all_database_keys()



def test_playable_seated_is_where_the_seated_database_key_exists() -> None:
    """``playable_seated`` answers without building the error (whose difflib suggestions are
    slow): True exactly where ``database_key(label, seated=True)`` returns, for every label,
    every seated key and unknown labels; ``database_key`` keeps its errors."""
    labels = [*ACTION_LABELS, *(f"{a}@seated" for a in ACTION_LABELS), "drnik", "", "@seated", "drink@seated@seated"]
    for label in labels:
        try:
            database_key(label, seated=True)
            exists = True
        except UnknownActionLabelError:
            exists = False
        assert playable_seated(label) == exists, label
    assert playable_seated("drink") and playable_seated("idle") and playable_seated("sit_down")
    assert not playable_seated("handshake") and not playable_seated("drnik")
    for args in (("handshake", True), ("handshake@seated", False)):
        with pytest.raises(UnknownActionLabelError, match=r"^unknown action label 'handshake@seated'; did you mean 'handshake'\?$"):
            database_key(*args)

def _check_clip(clip: MotionClip) -> None:
    assert np.all(np.isfinite(clip.local_rotations)) and np.all(np.isfinite(clip.pelvis))
    r = clip.local_rotations
    eye = np.einsum("fjik,fjil->fjkl", r, r)
    assert np.abs(eye - np.eye(3)).max() < 1e-6
    assert np.abs(np.linalg.det(r) - 1).max() < 1e-6
    pos = clip.joint_positions()
    toes = pos[:, FOOT_JOINTS]
    both = clip.contacts[1:] & clip.contacts[:-1]
    speed = np.linalg.norm(np.diff(toes[:, :, :2], axis=0), axis=-1) * clip.fps
    assert speed[both].max(initial=0.0) < 1e-6, clip.name
    assert np.abs(toes[:, :, 2][clip.contacts] - TOE_HEIGHT).max() < 1e-6
    assert pos[:, :, 2].min() > -1e-6  # nothing under the floor
    assert np.abs(np.diff(pos, axis=0)).max() < 0.25  # no pops (m per frame; fast swing foot ~0.2)


def test_locomotion_clips_have_planted_feet_and_valid_rotations() -> None:
    clips = locomotion_clips()
    assert len(clips) >= 16
    for clip in clips:
        _check_clip(clip)
    walk = next(c for c in clips if c.name == "walk_1.0")
    speed = np.linalg.norm(walk.root_xy[-1] - walk.root_xy[0]) / ((walk.num_frames - 1) / 30)
    assert speed == pytest.approx(1.0, rel=0.05)
    assert 0.4 < walk.contacts.mean() < 0.8  # both feet alternate


def test_loop_clips_are_seamless() -> None:
    for clip in [*[c for c in locomotion_clips() if c.loops][:3], action_clip("chat")]:
        pos = clip.joint_positions()
        local = [forward_kinematics(clip.local_rotations[i], np.zeros(3))[0] for i in (0, -1, -2)]
        seam = np.abs(local[0] - local[1]).max()
        step = np.abs(local[1] - local[2]).max()
        assert seam < 3 * step + 0.02, clip.name
        assert np.isfinite(pos).all()


def test_action_and_sitting_clips() -> None:
    for clip in [sitting_clip("sit_down", 0.46), sitting_clip("stand_up", 0.40), sit_idle_clip(0.46),
                 action_clip("drink"), action_clip("use_laptop", seated=True), action_clip("handshake"),
                 action_clip("wave"), action_clip("use_dishwasher")]:
        _check_clip(clip)
    sit = sitting_clip("sit_down", 0.46)
    assert sit.pelvis[0, 2] > 0.85 and sit.pelvis[-1, 2] == pytest.approx(0.46 + 0.09, abs=0.01)
    assert sit.root_xy[-1, 0] == pytest.approx(sit.target[0], abs=1e-6)
    drink = action_clip("drink").joint_positions()
    head, wrist = JOINT_INDEX["head"], JOINT_INDEX["right_wrist"]
    assert np.linalg.norm(drink[:, wrist] - drink[:, head], axis=1).min() < 0.2  # hand to mouth
    wave = action_clip("wave").joint_positions()
    assert (wave[:, wrist, 2] > wave[:, head, 2]).any()


def test_procedural_library_is_deterministic() -> None:
    a = procedural_clips("chat@seated")
    b = procedural_clips("chat@seated")
    assert len(a) == 3
    assert all(np.array_equal(x.local_rotations, y.local_rotations) for x, y in zip(a, b, strict=True))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-0.9, 0.9), min_size=3, max_size=3))
def test_two_bone_ik_reaches_reachable_targets(target: list[float]) -> None:
    t = np.array(target)
    if not 0.05 < np.linalg.norm(t) < 0.75:
        return
    mid, end, _ = two_bone_ik(np.zeros(3), t, 0.4, 0.4, np.array([1.0, 0.0, 0.0]))
    assert np.allclose(end, t, atol=1e-9)
    assert np.linalg.norm(mid) == pytest.approx(0.4) and np.linalg.norm(end - mid) == pytest.approx(0.4)


def test_cache_builds_once_in_the_folder_given(tmp_path: Path) -> None:
    calls = []

    def build() -> dict[str, np.ndarray]:
        calls.append(1)
        return {"x": np.arange(3)}

    payload = {"v": 1}
    folder = tmp_path / "motion"
    assert np.array_equal(cached_arrays(payload, build, folder)["x"], np.arange(3))
    assert np.array_equal(cached_arrays(payload, build, folder)["x"], np.arange(3))
    assert len(calls) == 1
    path = tmp_path / "motion" / f"{content_key(payload)}.npz"
    assert path.exists()
    path.write_bytes(b"garbage")  # a corrupt entry is rebuilt
    assert np.array_equal(cached_arrays(payload, build, folder)["x"], np.arange(3)) and len(calls) == 2
    assert np.array_equal(cached_arrays(payload, build, None)["x"], np.arange(3)) and len(calls) == 3  # no cache
    assert [p.name for p in folder.iterdir()] == [path.name]

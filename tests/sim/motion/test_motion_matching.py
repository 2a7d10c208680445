"""Motion matching: picks the obvious frame, inertialization keeps poses continuous, root on path."""

from __future__ import annotations

import numpy as np
import pytest

from storyteller.sim.motion.clips import foot_sliding
from storyteller.sim.motion.database import build_database
from storyteller.sim.motion.features import future_from_path
from storyteller.sim.motion.inertialization import decay_spring, rotation_exp, transition_offsets
from storyteller.sim.motion.matching import (
    MatchState,
    MotionMatcher,
    MotionMatchingError,
    MotionQuery,
)
from storyteller.sim.motion.sources.procedural_library import procedural_clips

DT = 1.0 / 30.0


@pytest.fixture(scope="module")
def matcher() -> MotionMatcher:
    keys = ["walk", "idle", "chat", "turn_on_tv", "sit_down"]
    return MotionMatcher({k: build_database(k, procedural_clips(k)) for k in keys})


def _walk(
    m: MotionMatcher, state: MatchState, x0: float, frames: int, v: float = 1.0
) -> tuple[MatchState, np.ndarray, np.ndarray, np.ndarray, float]:
    """Walk along +x for ``frames``; the end state, joints, contacts and roots per frame, the end x."""
    joints, contacts, roots, x = [], [], [], x0
    for _ in range(frames):
        x += v * DT
        fut, hd = future_from_path(np.array([[x, 0.0], [x + 5.0, 0.0]]), v * DT, 0.0)
        q = MotionQuery("walk", root_xy=np.array([x, 0.0]), heading=0.0, future_xy=fut, future_heading=hd)
        state, pose = m.step(state, q, DT)
        joints.append(pose.joints())
        contacts.append(pose.contacts)
        roots.append(pose.root_xy)
    return state, np.array(joints), np.array(contacts), np.array(roots), x


def test_search_picks_the_frame_the_query_came_from(matcher: MotionMatcher) -> None:
    db = matcher.databases["walk"]
    for i in np.flatnonzero(db.searchable)[::53]:
        assert np.array_equal(db.raw_features[db.search(db.raw_features[i])[0]], db.raw_features[i])


def test_walking_stays_on_path_with_little_foot_sliding(matcher: MotionMatcher) -> None:
    s = matcher.initial_state("idle", [0.0, 0.0], 0.0)
    s, joints, contacts, roots, _ = _walk(matcher, s, 0.0, 150)
    assert roots[:, 0] == pytest.approx(np.arange(1, 151) * DT)  # root exactly on the planned path
    pelvis_x = joints[:, 0, 0]
    assert np.abs(pelvis_x - roots[:, 0]).max() < 0.15
    assert s.key == "walk" and s.searches >= 14
    assert foot_sliding(joints[30:], contacts[30:]) < 0.25
    assert np.isfinite(joints).all()


def test_switches_are_continuous(matcher: MotionMatcher) -> None:
    s = matcher.initial_state("idle", [0.0, 0.0], 0.0)
    s, joints, _, _, x = _walk(matcher, s, 0.0, 60)
    frames = [joints[-1]]
    for _ in range(40):
        q = MotionQuery("chat", root_xy=np.array([x, 0.0]), heading=0.0, target_xy=np.array([x + 1.1, 0.0]),
                        target_facing=np.pi)
        s, pose = matcher.step(s, q, DT)
        frames.append(pose.joints())
    jumps = np.linalg.norm(np.diff(np.array(frames), axis=0), axis=-1).max(axis=1)
    walking = np.linalg.norm(np.diff(joints, axis=0), axis=-1).max()  # a swinging foot's speed
    assert s.key == "chat"
    # metres per frame at any joint, including the switch frame: the blend carries on the
    # swinging foot's speed (about 0.12 m a frame at 1 m/s), it does not jump
    assert jumps.max() < min(1.5 * walking, 0.2)

    # Without blending the same switch pops.
    raw = MotionMatcher(matcher.databases, blend_halflife=1e-6)
    s2 = raw.initial_state("idle", [0.0, 0.0], 0.0)
    s2, joints2, _, _, x2 = _walk(raw, s2, 0.0, 60)
    q = MotionQuery("chat", root_xy=np.array([x2, 0.0]), heading=0.0, target_xy=np.array([x2 + 1.1, 0.0]))
    _, pose2 = raw.step(s2, q, DT)
    assert np.linalg.norm(pose2.joints() - joints2[-1], axis=-1).max() > 0.05


def test_completing_action_finishes_and_sitting_uses_root_motion(matcher: MotionMatcher) -> None:
    s = matcher.initial_state("idle", [2.0, 1.0], np.pi / 2)
    q = MotionQuery("turn_on_tv", root_xy=np.array([2.0, 1.0]), heading=np.pi / 2, target_xy=np.array([2.0, 1.55]),
                    target_facing=-np.pi / 2)
    for _ in range(120):
        s, pose = matcher.step(s, q, DT)
    assert s.key == "turn_on_tv" and s.done
    # sit down with the seat 0.33 m behind; root motion comes from the database
    s = matcher.initial_state("idle", [0.0, 0.0], 0.0)
    seat = MotionQuery("sit_down", target_xy=np.array([-0.33, 0.0]), target_facing=0.0, seat_height=0.46)
    for _ in range(90):
        s, pose = matcher.step(s, seat, DT)
    assert pose.root_xy[0] == pytest.approx(-0.33, abs=0.08)
    assert pose.pelvis[2] == pytest.approx(0.55, abs=0.05)


def test_step_is_pure_and_errors_are_typed(matcher: MotionMatcher) -> None:
    s = matcher.initial_state("idle", [0.0, 0.0], 0.0)
    q = MotionQuery("idle", root_xy=np.zeros(2), heading=0.0)
    a1, p1 = matcher.step(s, q, DT)
    a2, p2 = matcher.step(s, q, DT)
    assert np.array_equal(p1.local_rotations, p2.local_rotations) and a1.frame == a2.frame
    assert s.joints_world is None  # the input state was not touched
    _states, poses = matcher.step_many([s, s], [q, q], DT)
    assert np.array_equal(poses[0].local_rotations, p1.local_rotations)
    with pytest.raises(MotionMatchingError):
        matcher.step(s, MotionQuery("hug"), DT)


def test_inertialization_math() -> None:
    rng = np.random.default_rng(3)
    src, dst = rotation_exp(rng.normal(size=(22, 3))), rotation_exp(rng.normal(size=(22, 3)))
    z = np.zeros((22, 3))
    off, _ = transition_offsets(z, z, src, z, dst, z)
    assert np.allclose(rotation_exp(off) @ dst, src, atol=1e-9)
    x, v = np.ones(3), np.zeros(3)
    mags = []
    for _ in range(60):
        x, v = decay_spring(x, v, 0.1, DT)
        mags.append(abs(x[0]))
    assert mags[0] < 1.0 and mags[-1] < 1e-3 and np.all(np.diff(mags) <= 1e-12)


def test_future_from_path_and_foot_sliding() -> None:
    pts, hd = future_from_path(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]), 1.0 / 30, 0.0)
    assert pts[0] == pytest.approx([1 / 3, 0.0]) and pts[2] == pytest.approx([1.0, 0.0])
    assert hd[0] == pytest.approx(0.0)
    j = np.zeros((3, 22, 3))
    j[1, 10, 0] = 0.1
    assert foot_sliding(j, np.ones((3, 2), bool)) == pytest.approx(0.1 * 30 * 2 / 4)
    assert foot_sliding(j, np.zeros((3, 2), bool)) == 0.0


def _crowd_queries(frame: int, k: int, rng: np.random.Generator) -> MotionQuery:
    """A scripted query for character ``k`` at ``frame``: phases of walking, idling, chatting,
    completing an action and sitting (mixed labels; label changes at different frames)."""
    phase = ((frame + 17 * k) // 45) % 5
    x, y = 0.4 * k + 0.02 * frame, 0.3 * np.sin(0.05 * frame + k)
    h = 0.3 * np.sin(0.02 * frame + k)
    if phase == 0:
        fut, hd = future_from_path(np.array([[x, y], [x + 3 * np.cos(h), y + 3 * np.sin(h)]]), DT, h)
        return MotionQuery("walk", root_xy=np.array([x, y]), heading=h, future_xy=fut, future_heading=hd,
                           force_search=bool(rng.random() < 0.05))
    if phase == 1:
        return MotionQuery("idle", root_xy=np.array([x, y]), heading=h)
    if phase == 2:
        return MotionQuery("chat", root_xy=np.array([x, y]), heading=h, target_xy=np.array([x + 0.8, y]),
                           target_facing=np.pi)
    if phase == 3:
        return MotionQuery("turn_on_tv", root_xy=np.array([x, y]), heading=h, target_xy=np.array([x, y + 0.5]),
                           target_facing=-np.pi / 2)
    return MotionQuery("sit_down", target_xy=np.array([x - 0.33, y]), target_facing=h, seat_height=0.42 + 0.02 * k)


def test_step_many_equals_step_per_character(matcher: MotionMatcher) -> None:
    n, frames = 6, 240
    rng = np.random.default_rng(11)
    labels = ["idle", "walk", "chat", "idle", "walk", "idle"]
    solo = [matcher.initial_state(labels[k], [0.4 * k, 0.0], 0.1 * k) for k in range(n)]
    batch = list(solo)
    seen_keys: set[str] = set()
    searches = 0
    for f in range(frames):
        queries = [_crowd_queries(f, k, rng) for k in range(n)]
        dt = DT if f % 50 else DT * 1.5  # an occasional long frame advances two database frames
        batch, poses = matcher.step_many(batch, queries, dt)
        for k in range(n):
            solo[k], pose = matcher.step(solo[k], queries[k], dt)
            b, p = batch[k], poses[k]
            assert (b.key, b.frame, b.since_search, b.done, b.switches, b.searches) == (
                solo[k].key, solo[k].frame, solo[k].since_search, solo[k].done, solo[k].switches, solo[k].searches)
            np.testing.assert_allclose(p.local_rotations, pose.local_rotations, rtol=0, atol=1e-9)
            np.testing.assert_allclose(p.pelvis, pose.pelvis, rtol=0, atol=1e-9)
            np.testing.assert_allclose(p.root_xy, pose.root_xy, rtol=0, atol=1e-9)
            assert p.heading == pytest.approx(pose.heading, abs=1e-9)
            assert np.array_equal(p.contacts, pose.contacts)
            one = solo[k]
            assert b.offset_rot is not None and one.offset_rot is not None
            assert b.offset_pos is not None and one.offset_pos is not None
            np.testing.assert_allclose(b.offset_rot, one.offset_rot, rtol=0, atol=1e-9)
            np.testing.assert_allclose(b.offset_pos, one.offset_pos, rtol=0, atol=1e-9)
        seen_keys |= {s.key for s in batch}
    searches = sum(s.searches for s in batch)
    assert seen_keys == {"walk", "idle", "chat", "turn_on_tv", "sit_down"}
    assert searches > n * frames // 20 and sum(s.switches for s in batch) > n * 3
    # lazily computed joints and velocities match the pose
    assert batch[0].joints_world is not None
    np.testing.assert_allclose(batch[0].joints_world, poses[0].joints(), atol=1e-12)
    assert batch[0].joint_vel_char is not None and np.isfinite(batch[0].joint_vel_char).all()


def test_step_many_checks_lengths(matcher: MotionMatcher) -> None:
    s = matcher.initial_state("idle", [0.0, 0.0], 0.0)
    with pytest.raises(ValueError, match="queries"):
        matcher.step_many([s, s], [MotionQuery("idle")], DT)
    assert matcher.step_many([], [], DT) == ([], [])

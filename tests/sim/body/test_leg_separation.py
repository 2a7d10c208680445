"""Legs of different characters kept apart (storyteller.sim.body.leg_separation; issue 25: body-body
overlap 0 frames).

In the 50-walker Office crowd the bodies overlapped in 224 of 600 frames, leg against leg,
mostly a walker following another two cells (0.6 m) behind: its front foot swung into the
leader's back leg. Checked here on hand-made poses (a leg swung into another's) and through
the world step (a walker that comes up behind a standing one and follows it down a corridor
when it sets off), where the bodies are measured with the benchmark's own sphere model.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from storyteller.sim.body.leg_ik import LEG_JOINTS, leg_chain
from storyteller.sim.body.leg_separation import LEG_CAPSULES, MARGIN_M, separate_legs
from storyteller.sim.body.skeleton import (
    JOINT_INDEX,
    NUM_JOINTS,
    REST_OFFSETS,
    forward_kinematics,
    heading_to_root,
)
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.paths.nav_grid import build_nav_grid
from storyteller.sim.scene.model import Scene

LEFT, RIGHT = 0, 1


def _pose(xy: tuple[float, float], swing: dict[int, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pelvis (3,) and local rotations (22, 3, 3) of a character standing at ``xy`` facing +x,
    its legs (0 left, 1 right) swung forward by about ``swing`` radians (negative: back), knee bent."""
    rots = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3)).copy()
    rots[0] = heading_to_root(0.0)
    for leg, angle in (swing or {}).items():  # about the body's left (x); the knee a little bent
        rots[LEG_JOINTS[leg]] = Rotation.from_rotvec([-angle - 0.15, 0.0, 0.0]).as_matrix()
        rots[LEG_JOINTS[2 + leg]] = Rotation.from_rotvec([0.3, 0.0, 0.0]).as_matrix()
    return np.array([xy[0], xy[1], REST_OFFSETS[0, 1]]), rots


def _poses(*bodies: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    return np.stack([b[0] for b in bodies]), np.stack([b[1] for b in bodies])


def _leg_gap(pelvis: np.ndarray, rots: np.ndarray, a: int, b: int) -> float:
    """Smallest distance between the leg capsules of characters ``a`` and ``b`` less their radii
    (negative: overlap), from points sampled every few millimetres along the bones."""
    chain = leg_chain(pelvis, rots)
    joints = np.stack([chain.hip, chain.knee, chain.ankle, chain.toe], axis=2)  # (N, 2, 4, 3)
    t = np.linspace(0.0, 1.0, 200)[:, None]

    def samples(c: int) -> tuple[np.ndarray, np.ndarray]:
        pts, radii = [], []
        for leg in range(2):
            for k, r in enumerate(LEG_CAPSULES):
                pts.append(joints[c, leg, k] + t * (joints[c, leg, k + 1] - joints[c, leg, k]))
                radii.append(np.full(len(t), r))
        return np.concatenate(pts), np.concatenate(radii)

    pa, ra = samples(a)
    pb, rb = samples(b)
    gap = np.linalg.norm(pa[:, None] - pb[None], axis=-1) - ra[:, None] - rb[None]
    return float(gap.min())


def _ankles(pelvis: np.ndarray, rots: np.ndarray) -> np.ndarray:
    return forward_kinematics(rots, pelvis)[0][:, [JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]]]


def _following() -> tuple[np.ndarray, np.ndarray]:
    """A follower 0.6 m behind a leader, both facing +x: the follower's left leg swung forward,
    the leader's left leg swung back, on one line."""
    return _poses(_pose((0.0, 0.0), {LEFT: 0.6}), _pose((0.6, 0.0), {LEFT: -0.5}))


def test_a_leg_swung_into_another_is_moved_clear() -> None:
    pelvis, rots = _following()
    assert _leg_gap(pelvis, rots, 0, 1) < -0.05  # the set-up: the legs overlap
    out, report = separate_legs(pelvis, rots, np.ones(2, dtype=bool), np.zeros(2, dtype=bool))
    assert report.pairs == 1 and report.moved >= 2 and report.left == 0.0
    assert _leg_gap(pelvis, out, 0, 1) >= MARGIN_M - 2e-3
    # only the hips, knees and ankles changed, and the bones kept their lengths
    changed = np.flatnonzero(np.any(np.abs(out - rots) > 1e-12, axis=(0, 2, 3)))
    assert set(changed.tolist()) <= set(LEG_JOINTS)
    before, after = forward_kinematics(rots, pelvis)[0], forward_kinematics(out, pelvis)[0]
    for a, b in (("left_hip", "left_knee"), ("left_knee", "left_ankle"), ("left_ankle", "left_foot")):
        i, j = JOINT_INDEX[a], JOINT_INDEX[b]
        np.testing.assert_allclose(np.linalg.norm(after[:, j] - after[:, i], axis=-1),
                                   np.linalg.norm(before[:, j] - before[:, i], axis=-1), atol=1e-9)
    moved_z = np.abs(_ankles(pelvis, out)[..., 2] - _ankles(pelvis, rots)[..., 2])
    assert float(moved_z.max()) < 1e-6  # shifted horizontally
    assert float(np.linalg.norm(_ankles(pelvis, out) - _ankles(pelvis, rots), axis=-1).max()) <= 0.2 + 1e-9


def test_a_planted_foot_gives_less_than_a_swinging_one() -> None:
    # the leader stands with its right leg straight down (toe on the floor) on the line of the
    # follower's swinging left foot
    pelvis, rots = _poses(_pose((0.0, 0.0), {LEFT: 0.6}), _pose((0.42, 0.17)))
    assert _leg_gap(pelvis, rots, 0, 1) < -0.03
    out, report = separate_legs(pelvis, rots, np.ones(2, dtype=bool), np.zeros(2, dtype=bool))
    assert report.left == 0.0
    shift = np.linalg.norm(_ankles(pelvis, out) - _ankles(pelvis, rots), axis=-1)
    assert shift[0, LEFT] > 2.0 * shift[1, RIGHT] > 0.0  # with equal give the shin (moving less than its ankle) would move more


def test_legs_that_do_not_touch_come_back_as_they_were() -> None:
    pelvis, rots = _poses(_pose((0.0, 0.0), {LEFT: 0.3}), _pose((1.0, 0.0), {LEFT: -0.3}))
    out, report = separate_legs(pelvis, rots, np.ones(2, dtype=bool), np.zeros(2, dtype=bool))
    assert out is rots and report.pairs == 0 and report.moved == 0


def test_still_legs_are_obstacles_and_a_hug_may_touch() -> None:
    pelvis, rots = _following()
    out, report = separate_legs(pelvis, rots, np.zeros(2, dtype=bool), np.zeros(2, dtype=bool))
    assert out is rots and report.moved == 0
    out, report = separate_legs(pelvis, rots, np.ones(2, dtype=bool), np.ones(2, dtype=bool))
    assert out is rots and report.moved == 0
    # only the follower may move: the leader (sitting down, say) keeps its legs
    out, report = separate_legs(pelvis, rots, np.array([True, False]), np.zeros(2, dtype=bool))
    np.testing.assert_array_equal(out[1], rots[1])
    assert report.left == 0.0 and _leg_gap(pelvis, out, 0, 1) >= MARGIN_M - 2e-3


CORRIDOR = Scene(name="corridor", bounds_min=(0.0, 0.0), bounds_max=(6.3, 1.2), objects=())


@pytest.mark.slow
def test_a_walker_following_another_down_a_corridor_keeps_its_legs_out_of_the_leaders(
        motion: MotionMatcher) -> None:
    """The follower walks up to the standing leader (two cells, 0.6 m, behind it), and follows it
    when it sets off a second later. Before the legs were kept apart, 25 of the 240 frames
    overlapped (7.1 cm deep)."""
    from storyteller.benchmark.motion_metrics.bodies import body_overlap, sphere_body
    from storyteller.sim.world.events import AssignEvent, Assignment
    from storyteller.sim.world.step import World, WorldConfig, step

    grid = build_nav_grid(CORRIDOR)
    walks = {"follower": ((0.45, 0.75), (4.35, 0.75)), "leader": ((1.95, 0.75), (5.85, 0.75))}
    starts = {a: (tuple(grid.center_of(*grid.cell_of(np.asarray(s)))), 0.0) for a, (s, _) in walks.items()}
    world = World(CORRIDOR, starts, motion, grid=grid, config=WorldConfig(seed=0, initial_capacity=240))
    go = {a: AssignEvent(event_id=f"go-{a}", assignments=(Assignment(
        character=a, action="idle", target_xy=tuple(grid.center_of(*grid.cell_of(np.asarray(g)))),
        facing_xy=(1.0, 0.0)),)) for a, (_, g) in walks.items()}
    for frame in range(240):
        step(world, [go[a] for a, at in (("follower", 0), ("leader", 30)) if frame == at], world.dt)
    tracks = world.tracks()
    root = {a: tracks[a].root_positions[:, :2] for a in walks}
    for a, (_, goal) in walks.items():
        assert float(np.linalg.norm(root[a][-1] - np.asarray(goal))) < 0.3
    gap = np.linalg.norm(root["leader"] - root["follower"], axis=-1)
    following = (gap < 0.6 + 1e-6) & (np.linalg.norm(np.gradient(root["leader"], axis=0), axis=-1) > 0.01)
    assert int(following.sum()) > 30  # the follower walks 0.6 m behind the walking leader
    body = sphere_body()
    centres = [body.centres(forward_kinematics(tracks[a].local_rotations, tracks[a].root_positions)[0])
               for a in sorted(walks)]
    depth = body_overlap(centres[0], centres[1], body)
    assert int(np.sum(depth > 0.0)) == 0, f"{int(np.sum(depth > 0.0))} frames overlap, deepest {depth.max():.3f} m"

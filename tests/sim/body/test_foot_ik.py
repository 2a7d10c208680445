"""Foot IK (storyteller.sim.body.foot_ik): exact two-bone IK, feet pushed out of footprints, pinned contacts."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from storyteller.sim.body.foot_clearance import BoxGrid, _may_be_inside, _push_out_kernel
from storyteller.sim.body.foot_clearance import _depth as _box_depth
from storyteller.sim.body.foot_ik import (
    HIP_JOINTS,
    KNEE_JOINTS,
    LEG_JOINTS,
    FootIKError,
    Footprints,
    FootSolver,
    FootState,
    push_out,
    solve_legs,
)
from storyteller.sim.body.foot_kernel import LAND_M, TOE_FLOOR_M
from storyteller.sim.body.leg_ik import SHIN_LENGTH, THIGH_LENGTH, LegChain, _ik_kernel
from storyteller.sim.body.skeleton import NUM_JOINTS, REST_OFFSETS, forward_kinematics, heading_to_root
from storyteller.sim.motion.clips import ANKLE_JOINTS, FOOT_JOINTS
from storyteller.sim.scene.model import Scene, SceneObject
from tests.support.foot_reference import apply_numpy
from tests.support.leg_ik_reference import ik_kernel_arrays

_NO_BOXES = Footprints(*(np.zeros((0, 2)) for _ in range(4)))
OTHERS = [j for j in range(NUM_JOINTS) if j not in LEG_JOINTS]


def _poses(n: int, seed: int, bend: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """n bodies (pelvis, local rotations) with the knees bent by 0.7 rad like a walking body's
    (the pelvis 5 cm lower, the feet near the floor: a planted foot can stay behind), plus
    random rotations of ``bend`` rad on the legs, the spine and the arms."""
    rng = np.random.default_rng(seed)
    rots = np.broadcast_to(np.eye(3), (n, NUM_JOINTS, 3, 3)).copy()
    rots[:, 0] = heading_to_root(rng.uniform(-np.pi, np.pi, n))
    flex = {1: -0.35, 2: -0.35, 4: 0.7, 5: 0.7, 7: -0.35, 8: -0.35}  # about the body's x (left)
    for j in (*LEG_JOINTS, 3, 6, 16, 18):
        noise = rng.normal(0.0, bend, (n, 3)) + np.array([flex.get(j, 0.0), 0.0, 0.0])
        rots[:, j] = Rotation.from_rotvec(noise).as_matrix()
    pelvis = np.column_stack([rng.uniform(-3, 3, (n, 2)), np.full(n, REST_OFFSETS[0, 1] - 0.05)])
    return pelvis, rots


def _box(width: float, depth: float, center: tuple[float, float], facing: tuple[float, float] = (0.0, 1.0),
         margin: float = 0.0) -> Footprints:
    f = np.array(facing, dtype=float) / np.hypot(*facing)
    return Footprints(centers=np.array([center], dtype=float), rights=np.array([[f[1], -f[0]]]),
                      facings=f[None], halves=np.array([[width / 2 + margin, depth / 2 + margin]]))


def _depth(points: np.ndarray, fp: Footprints) -> np.ndarray:
    """Depth (>0 inside) of xy points (..., 2) in the deepest box of ``fp``."""
    d = points[..., None, :] - fp.centers
    lx = np.abs(np.einsum("...bi,bi->...b", d, fp.rights))
    ly = np.abs(np.einsum("...bi,bi->...b", d, fp.facings))
    depth: np.ndarray = np.minimum(fp.halves[:, 0] - lx, fp.halves[:, 1] - ly).max(axis=-1)
    return depth


# ----- two-bone IK ---------------------------------------------------------------------------
def test_ik_reaches_reachable_targets_exactly_and_keeps_everything_else() -> None:
    pelvis, rots = _poses(64, seed=1)
    pos, glob = forward_kinematics(rots, pelvis)
    rng = np.random.default_rng(2)
    hips = pos[:, list(HIP_JOINTS)]
    lo, hi = np.abs(THIGH_LENGTH - SHIN_LENGTH) + 0.02, THIGH_LENGTH + SHIN_LENGTH - 0.005
    reach = lo + rng.uniform(0, 1, (64, 2)) * (hi - lo)
    direction = rng.normal(0, 1, (64, 2, 3)) + np.array([0.0, 0.0, -1.5])
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    targets = hips + reach[..., None] * direction
    out = solve_legs(pelvis, rots, targets)
    pos2, glob2 = forward_kinematics(out, pelvis)
    assert np.abs(pos2[:, list(ANKLE_JOINTS)] - targets).max() < 1e-9
    # the feet keep their world orientation, so the toes follow the ankles rigidly
    assert np.abs(glob2[:, list(ANKLE_JOINTS)] - glob[:, list(ANKLE_JOINTS)]).max() < 1e-9
    foot = pos[:, list(FOOT_JOINTS)] - pos[:, list(ANKLE_JOINTS)]
    assert np.abs(pos2[:, list(FOOT_JOINTS)] - (targets + foot)).max() < 1e-9
    # bone lengths and rotation matrices stay valid
    for parent, child in ((HIP_JOINTS, KNEE_JOINTS), (KNEE_JOINTS, ANKLE_JOINTS)):
        length = np.linalg.norm(pos2[:, list(child)] - pos2[:, list(parent)], axis=-1)
        assert np.abs(length - np.linalg.norm(REST_OFFSETS[list(child)], axis=-1)).max() < 1e-12
    ortho = np.einsum("...ji,...jk->...ik", out, out)
    assert np.abs(ortho - np.eye(3)).max() < 1e-12
    assert np.allclose(np.linalg.det(out), 1.0)
    # pelvis, spine, arms, toes: exactly the input
    assert np.array_equal(out[:, OTHERS], rots[:, OTHERS])
    assert np.array_equal(pos2[:, OTHERS[:1]], pos[:, OTHERS[:1]])
    upper = [j for j in OTHERS if j not in FOOT_JOINTS]
    assert np.abs(pos2[:, upper] - pos[:, upper]).max() < 1e-12


def test_leg_chain_and_compiled_ik_match_their_references() -> None:
    pelvis, rots = _poses(16, seed=12)
    pos, glob = forward_kinematics(rots, pelvis)
    chain = LegChain(pelvis, rots)
    for name, joints in (("hip", HIP_JOINTS), ("knee", KNEE_JOINTS), ("ankle", ANKLE_JOINTS), ("toe", FOOT_JOINTS)):
        assert np.abs(getattr(chain, name) - pos[:, list(joints)]).max() < 1e-12, name
    for name, joints in (("hip_rot", HIP_JOINTS), ("knee_rot", KNEE_JOINTS), ("ankle_rot", ANKLE_JOINTS)):
        assert np.abs(getattr(chain, name) - glob[:, list(joints)]).max() < 1e-12, name
    # the numba kernel and its Python source give the same bits (incl. the degenerate branches)
    rng = np.random.default_rng(13)
    m = 32
    leg = np.arange(m) % 2
    ci = np.arange(m) // 2
    targets = chain.hip[ci, leg] + rng.normal(0, 0.5, (m, 3))
    targets[0] = chain.hip[0, 0]  # on the hip
    targets[1] = chain.hip[0, 1] + np.array([0.0, 0.0, 3.0])  # far above
    inputs = (chain.hip[ci, leg], chain.knee[ci, leg], chain.ankle[ci, leg], chain.pelvis_rot[ci],
              chain.hip_rot[ci, leg], chain.knee_rot[ci, leg], chain.ankle_rot[ci, leg], targets,
              THIGH_LENGTH[leg], SHIN_LENGTH[leg])
    args = tuple(np.ascontiguousarray(a) for a in inputs)
    # the branches random legs rarely take: a knee bent backwards against the thigh's flexion
    # axis (that axis flipped), and a flexion axis along the thigh (the axis then is any
    # perpendicular)
    flipped = args[4].copy()
    flipped[:, :, 0] *= -1.0
    kh = args[0] - args[1]
    flipped[:2, :, 0] = -kh[:2] / np.linalg.norm(kh[:2], axis=-1, keepdims=True)
    args = tuple(np.concatenate([a, flipped if k == 4 else a]) for k, a in enumerate(args))
    for x, y, z in zip(_ik_kernel(*args), _ik_kernel.py_func(*args), ik_kernel_arrays(*args), strict=True):
        assert np.isfinite(x).all()
        assert np.array_equal(x, y)
        assert np.array_equal(x, z)  # the scalar kernel does the array version's float operations


def test_ik_knee_bends_forward_from_a_straight_leg() -> None:
    pelvis, rots = _poses(8, seed=3, bend=0.0)
    rots[:, list(LEG_JOINTS)] = np.eye(3)
    # straighten both legs exactly: align the shin with the thigh
    for knee, ankle in zip(KNEE_JOINTS, ANKLE_JOINTS, strict=True):
        a, b = REST_OFFSETS[knee], REST_OFFSETS[ankle]
        rots[:, knee] = Rotation.align_vectors(a[None], b[None])[0].as_matrix()
    pos, glob = forward_kinematics(rots, pelvis)
    targets = pos[:, list(ANKLE_JOINTS)] + [0.0, 0.0, 0.15]  # lift the foot: the knee must bend
    out = solve_legs(pelvis, rots, targets)
    pos2, _ = forward_kinematics(out, pelvis)
    assert np.abs(pos2[:, list(ANKLE_JOINTS)] - targets).max() < 1e-9
    forward = glob[:, 0][:, :, 2]  # body +z in the world
    for k, knee in enumerate(KNEE_JOINTS):
        ahead = np.einsum("ni,ni->n", pos2[:, knee] - pos[:, HIP_JOINTS[k]], forward)
        assert (ahead > 0.05).all(), ahead


def test_ik_knee_is_steady_when_the_animated_leg_is_nearly_straight() -> None:
    # the animated knee bends 0.02 rad about an axis that wanders from frame to frame (the
    # plane of a nearly straight leg is noise); lifting the ankle 12 cm must bend the knee the
    # same way every frame, forward, not wherever that noise points
    rng = np.random.default_rng(14)
    pelvis, rots = _poses(1, seed=15, bend=0.0)
    knee_list = []
    for _ in range(20):
        r = rots.copy()
        r[:, list(LEG_JOINTS)] = np.eye(3)
        for knee, ankle in zip(KNEE_JOINTS, ANKLE_JOINTS, strict=True):
            a, b = REST_OFFSETS[knee], REST_OFFSETS[ankle]
            straight = Rotation.align_vectors(a[None], b[None])[0]
            axis = rng.normal(0, 1, 3)
            wobble = Rotation.from_rotvec(0.02 * axis / np.linalg.norm(axis))
            r[:, knee] = (wobble * straight).as_matrix()
        chain = LegChain(pelvis, r)
        out = solve_legs(pelvis, r, chain.ankle + np.array([0.0, 0.0, 0.12]))
        knee_list.append(LegChain(pelvis, out).knee[0])
    knees = np.array(knee_list)
    # the 0.02 rad wobble tilts the hinge by <= 0.02 / HINGE_BLEND rad: <= 2 cm at the knee;
    # following the animated plane alone would swing the knee ~20 cm
    assert np.linalg.norm(knees - knees.mean(axis=0), axis=-1).max() < 0.03


def test_a_knee_bent_backwards_is_bent_forwards_continuously() -> None:
    # the knee's flexion goes from -0.4 rad (backwards, as some source frames have it) through
    # straight to +0.4 rad; the IK, asked to keep each ankle where it is, keeps the ankles and
    # the feet but bends every knee forwards, and the knee moves smoothly through straight
    pelvis, rots = _poses(1, seed=16, bend=0.0)
    rots[:, list(LEG_JOINTS)] = np.eye(3)
    knees, ahead_list = [], []
    for flex in np.linspace(-0.4, 0.4, 41):
        r = rots.copy()
        r[:, list(KNEE_JOINTS)] = Rotation.from_rotvec([flex, 0.0, 0.0]).as_matrix()
        chain = LegChain(pelvis, r)
        out = solve_legs(pelvis, r, chain.ankle)
        after = LegChain(pelvis, out)
        assert np.abs(after.ankle - chain.ankle).max() < 1e-9
        assert np.abs(after.ankle_rot - chain.ankle_rot).max() < 1e-9
        forward = r[0, 0][:, 2]
        mid = (after.hip + after.ankle) / 2
        ahead_list.append((after.knee - mid)[0] @ forward)
        knees.append(after.knee[0])
        if flex > 0:  # a forward knee is the input
            assert np.abs(out - r).max() < 1e-9
    aheads = np.array(ahead_list)
    assert (aheads > -1e-4).all(), aheads.min()  # never behind the hip-ankle line (0.1 mm)
    assert aheads[0].min() > 0.03  # the backward knee came forward
    steps = np.linalg.norm(np.diff(np.array(knees), axis=0), axis=-1)
    assert steps.max() < 0.02  # 0.02 rad of flexion a step: no flip through straight


def test_unreachable_and_degenerate_targets_stretch_without_nan() -> None:
    pelvis, rots = _poses(6, seed=4)
    pos, _ = forward_kinematics(rots, pelvis)
    hips = pos[:, list(HIP_JOINTS)]
    far = hips + np.array([0.3, -0.2, -2.0])  # out of reach
    at_hip = hips.copy()  # zero distance
    for targets in (far, at_hip, hips + np.array([0.0, 0.0, 5.0])):
        out = solve_legs(pelvis, rots, targets)
        assert np.isfinite(out).all()
        pos2, _ = forward_kinematics(out, pelvis)
        assert np.isfinite(pos2).all()
    out = solve_legs(pelvis, rots, far)
    pos2, _ = forward_kinematics(out, pelvis)
    span = pos2[:, list(ANKLE_JOINTS)] - hips
    full = THIGH_LENGTH + SHIN_LENGTH
    assert np.abs(np.linalg.norm(span, axis=-1) - full).max() < 1e-4  # stretched as far as possible
    to_target = (far - hips) / np.linalg.norm(far - hips, axis=-1, keepdims=True)
    assert (np.einsum("nli,nli->nl", span / full[:, None], to_target) > 1 - 1e-5).all()  # towards it
    with pytest.raises(FootIKError, match="finite"):
        solve_legs(pelvis, rots, np.full_like(far, np.nan))
    with pytest.raises(FootIKError, match=r"ankle_targets \(N, 2, 3\)"):
        solve_legs(pelvis, rots, far[:, 0])


# ----- clearance -----------------------------------------------------------------------------
def test_push_out_moves_a_point_group_to_the_nearest_side() -> None:
    fp = _box(1.0, 0.6, (0.0, 0.0))  # x in [-0.5, 0.5], y in [-0.3, 0.3]
    pts = np.array([[[0.45, 0.0], [0.40, 0.1]],  # nearest exit: +x (by 0.05 for the deeper one)
                    [[0.0, -0.25], [0.1, -0.2]],  # -y (0.10 for the second point)
                    [[2.0, 2.0], [2.1, 2.0]]])  # outside: no shift
    shift = push_out(pts, fp)
    assert np.allclose(shift, [[0.10, 0.0], [0.0, -0.10], [0.0, 0.0]])
    assert (_depth(pts + shift[:, None], fp) <= 1e-12).all()
    assert np.array_equal(shift, _push_out_kernel.py_func(pts, fp.centers, fp.rights, fp.facings, fp.halves, 4))


def test_push_out_clears_overlapping_boxes() -> None:
    # a chair box under a table box: leaving the chair through its far side lands in the table
    table = _box(1.4, 0.8, (0.0, 0.0))
    chair = _box(0.6, 0.6, (0.0, -0.55), facing=(0.3, 1.0))
    fp = Footprints(*(np.concatenate([getattr(table, k), getattr(chair, k)])
                      for k in ("centers", "rights", "facings", "halves")))
    rng = np.random.default_rng(5)
    ankle = rng.uniform([-0.9, -1.0], [0.9, 0.5], (300, 2))
    pts = np.stack([ankle, ankle + rng.normal(0, 0.1, (300, 2))], axis=1)
    shift = push_out(pts, fp)
    assert (_depth(pts + shift[:, None], fp) <= 1e-9).all()
    assert np.array_equal(shift, _push_out_kernel.py_func(pts, fp.centers, fp.rights, fp.facings, fp.halves, 4))


def _foot_in_box_case(margin: float) -> tuple[FootSolver, Footprints, np.ndarray, np.ndarray]:
    pelvis, rots = _poses(1, seed=6, bend=0.15)
    pos, _ = forward_kinematics(rots, pelvis)
    pelvis[:, 2] += max(0.0, TOE_FLOOR_M - pos[0, list(FOOT_JOINTS), 2].min())  # both feet on or above the floor
    pos, _ = forward_kinematics(rots, pelvis)
    toe = pos[0, FOOT_JOINTS[0], :2]
    # a box whose edge runs 4 cm past the left toe, on the far side from the pelvis
    away = (toe - pelvis[0, :2]) / np.linalg.norm(toe - pelvis[0, :2])
    center = toe + away * (0.5 - 0.04)
    box = _box(1.0, 1.0, tuple(center), facing=tuple(away))
    return FootSolver(_box(1.0, 1.0, tuple(center), facing=tuple(away), margin=margin)), box, pelvis, rots


def test_apply_pushes_a_foot_out_of_a_box_with_the_margin() -> None:
    solver, box, pelvis, rots = _foot_in_box_case(margin=0.02)
    pos, _ = forward_kinematics(rots, pelvis)
    feet = [*FOOT_JOINTS, *ANKLE_JOINTS]
    assert _depth(pos[0, feet, :2], box).max() > 0.03  # the case really starts inside
    out, _ = solver.apply(pelvis, rots, np.zeros((1, 2), dtype=bool), solver.initial_state(1))
    pos2, _ = forward_kinematics(out, pelvis)
    assert _depth(pos2[0, feet, :2], box).max() <= -0.02 + 1e-9
    assert np.abs(pos2[0, list(ANKLE_JOINTS), 2] - pos[0, list(ANKLE_JOINTS), 2]).max() < 1e-9  # horizontal
    assert np.array_equal(out[:, OTHERS], rots[:, OTHERS])
    # the right foot was not in the box: its leg is the input (up to rounding)
    right = [HIP_JOINTS[1], KNEE_JOINTS[1], ANKLE_JOINTS[1]]
    assert np.abs(out[:, right] - rots[:, right]).max() < 1e-12
    # an inactive character is left alone
    out_off, _ = solver.apply(pelvis, rots, np.zeros((1, 2), dtype=bool), solver.initial_state(1),
                              active=np.array([False]))
    assert np.array_equal(out_off, rots)


def test_from_scene_keeps_only_floor_standing_objects() -> None:
    objs = [
        SceneObject(name="table_1", label="table", idx=1, center=(1.0, 0.0, 0.375), size=(1.2, 0.8, 0.75), facing=(0.0, 1.0)),
        SceneObject(name="lamp_1", label="lamp", idx=1, center=(3.0, 0.0, 2.2), size=(0.4, 0.4, 0.2), facing=(1.0, 0.0)),
    ]
    scene = Scene(name="t", bounds_min=(-5.0, -5.0), bounds_max=(5.0, 5.0), objects=tuple(objs))
    solver = FootSolver.from_scene(scene, margin=0.05)
    assert len(solver.footprints) == 1
    assert np.allclose(solver.footprints.halves, [[0.65, 0.45]])
    with pytest.raises(FootIKError, match="margin"):
        FootSolver.from_scene(scene, margin=-0.1)


# ----- pinning -------------------------------------------------------------------------------
def _walk(solver: FootSolver, pelvis: np.ndarray, rots: np.ndarray, contacts: np.ndarray,
          step: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Run frames: the pelvis moves by ``step`` (3,) a frame with a fixed pose; returns the
    animated and the filtered toe positions (F, 2, 3) of character 0."""
    state = solver.initial_state(1)
    anim, out_toes = [], []
    for f in range(len(contacts)):
        p = pelvis + f * step
        out, state = solver.apply(p, rots, contacts[f][None], state)
        anim.append(forward_kinematics(rots, p)[0][0, list(FOOT_JOINTS)])
        out_toes.append(forward_kinematics(out, p)[0][0, list(FOOT_JOINTS)])
    return np.array(anim), np.array(out_toes)


def test_a_contact_foot_stays_pinned_then_blends_back() -> None:
    solver = FootSolver(_NO_BOXES, max_drift=0.15, release_frames=6)
    pelvis, rots = _poses(1, seed=7, bend=0.1)
    contacts = np.zeros((30, 2), dtype=bool)
    contacts[:10, 0] = True  # left foot planted for 10 frames, then lifted
    anim, toes = _walk(solver, pelvis, rots, contacts, step=np.array([0.01, 0.0, 0.0]))
    assert np.abs(toes[:10, 0] - toes[0, 0]).max() < 1e-9  # pinned while in contact
    assert np.abs(toes[0] - anim[0]).max() < 1e-9  # locked where it was
    assert np.abs(toes[:, 1] - anim[:, 1]).max() < 1e-12  # the free foot follows the animation
    steps = np.linalg.norm(np.diff(toes[:, 0, :2], axis=0), axis=-1)
    # smooth release: the 0.10 m lag goes in 6 frames of a smoothstep (slope <= 1.5), on top of
    # the animation's own 0.01 m a frame (a snap back would be one 0.11 m step)
    assert steps.max() <= 0.10 * 1.5 / 6 + 0.01 + 1e-9
    # the foot steps back rather than sliding: lifted by up to its lag (at most 8 cm), down after
    lift = toes[:, 0, 2] - anim[:, 0, 2]
    assert 0.06 < lift[10:16].max() <= 0.08 + 1e-9 and np.abs(lift[:10]).max() < 1e-9
    assert np.abs(toes[16:, 0] - anim[16:, 0]).max() < 1e-9  # back on the animation
    assert np.abs(toes[12, 0] - anim[12, 0]).max() > 0.01  # still blending


def test_a_toe_on_the_floor_is_pinned_without_a_contact_flag() -> None:
    """A blend can put a foot down before (or after) its clip's contact flag: a toe within
    ``LAND_M`` of its standing-flat height is pinned all the same; a higher one is not."""
    solver = FootSolver(_NO_BOXES, max_drift=0.15, release_frames=6)
    pelvis, rots = _poses(1, seed=7, bend=0.1)
    toe0 = forward_kinematics(rots, pelvis)[0][0, list(FOOT_JOINTS)]
    no_flags = np.zeros((8, 2), dtype=bool)
    step = np.array([0.01, 0.0, 0.0])
    for above, pinned in ((0.5 * LAND_M, True), (LAND_M + 0.01, False)):
        low = pelvis.copy()
        low[0, 2] += TOE_FLOOR_M + above - toe0[:, 2].min()  # the lower toe that far above the floor
        anim, toes = _walk(solver, low, rots, no_flags, step=step)
        k = int(np.argmin(anim[0, :, 2]))
        moved = np.abs(toes[:, k] - toes[0, k]).max()
        assert (moved < 1e-9) if pinned else (np.abs(toes[:, k] - anim[:, k]).max() < 1e-12), (above, moved)


def test_a_drifting_lock_is_released() -> None:
    solver = FootSolver(_NO_BOXES, max_drift=0.15, release_frames=4)
    pelvis, rots = _poses(1, seed=8, bend=0.1)
    contacts = np.ones((40, 2), dtype=bool)
    anim, toes = _walk(solver, pelvis, rots, contacts, step=np.array([0.0, 0.02, 0.0]))
    lag = np.linalg.norm(toes - anim, axis=-1)
    assert lag.max() <= 0.15 + 0.02 + 1e-9  # never dragged further than the drift bound
    assert np.abs(toes[:7] - toes[0]).max() < 1e-9  # pinned until 0.15 m of drift
    assert not np.allclose(toes[10], toes[0])  # then released, and locked again later
    assert np.isfinite(toes).all()


def test_unreachable_lock_stretches_without_nan() -> None:
    solver = FootSolver(_NO_BOXES, max_drift=10.0, max_reach=1.0)
    pelvis, rots = _poses(1, seed=9, bend=0.1)
    contacts = np.ones((6, 2), dtype=bool)
    _, toes = _walk(solver, pelvis, rots, contacts, step=np.array([0.0, 0.0, 0.4]))  # the body flies up
    assert np.isfinite(toes).all()
    assert toes[-1, 0, 2] > toes[0, 0, 2] + 1.0  # the foot cannot stay: the leg is at full stretch


def test_a_lock_out_of_reach_is_released_before_the_leg_is_straight() -> None:
    full = THIGH_LENGTH + SHIN_LENGTH
    pelvis, rots = _poses(1, seed=9, bend=0.1)
    contacts = np.ones((40, 2), dtype=bool)
    for max_reach, straight in ((0.97, False), (1.0, True)):
        solver = FootSolver(_NO_BOXES, max_drift=10.0, max_reach=max_reach, release_frames=4)
        state = solver.initial_state(1)
        span_list = []
        for f in range(len(contacts)):
            p = pelvis + np.array([0.0, 0.0, 0.004 * f])  # the body rises: the planted feet fall behind
            out, state = solver.apply(p, rots, contacts[f][None], state)
            chain = LegChain(p, out)
            span_list.append(np.linalg.norm(chain.ankle - chain.hip, axis=-1)[0] / full)
        spans = np.array(span_list)
        anim = LegChain(pelvis, rots)
        anim_span = np.linalg.norm(anim.ankle - anim.hip, axis=-1)[0] / full
        assert (anim_span < 0.96).all()  # the case: the animation's own legs are bent
        assert (spans.max() > 1 - 1e-5) == straight, (max_reach, spans.max())
        if not straight:  # released at 0.97 of the leg and held there while blending back
            assert spans.max() <= 0.97 + 1e-9
            assert spans.max() > 0.97 - 1e-3


def test_apply_is_deterministic_and_its_state_copies() -> None:
    pelvis, rots = _poses(5, seed=10)
    solver, *_ = _foot_in_box_case(margin=0.03)
    rng = np.random.default_rng(11)
    contacts = rng.random((20, 5, 2)) < 0.6

    def run(state: FootState, frames: range) -> tuple[list[np.ndarray], FootState]:
        outs = []
        for f in frames:
            out, state = solver.apply(pelvis + np.array([0.01 * f, 0.0, 0.0]), rots, contacts[f], state)
            outs.append(out)
        return outs, state

    a, _ = run(solver.initial_state(5), range(20))
    b, _ = run(solver.initial_state(5), range(20))
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    _, mid = run(solver.initial_state(5), range(10))
    snap = copy.deepcopy(mid)
    c, _ = run(mid, range(10, 20))
    d, _ = run(snap, range(10, 20))
    assert all(np.array_equal(x, y) for x, y in zip(c, d, strict=True))
    assert all(np.array_equal(x, y) for x, y in zip(a[10:], c, strict=True))


def test_apply_rejects_bad_input() -> None:
    solver, _, pelvis, rots = _foot_in_box_case(margin=0.0)
    state = solver.initial_state(1)
    with pytest.raises(FootIKError, match="state holds 2"):
        solver.apply(pelvis, rots, np.zeros((1, 2), dtype=bool), solver.initial_state(2))
    with pytest.raises(FootIKError, match="contacts"):
        solver.apply(pelvis, rots, np.zeros(2, dtype=bool), state)
    bad = rots.copy()
    bad[0, 4, 0, 0] = np.inf
    with pytest.raises(FootIKError, match="finite"):
        solver.apply(pelvis, bad, np.zeros((1, 2), dtype=bool), state)
    with pytest.raises(FootIKError, match="release_frames"):
        FootSolver(solver.footprints, release_frames=-1)
    empty, _ = solver.apply(np.zeros((0, 3)), np.zeros((0, NUM_JOINTS, 3, 3)), np.zeros((0, 2), dtype=bool),
                            solver.initial_state(0))
    assert empty.shape == (0, NUM_JOINTS, 3, 3)


@pytest.mark.parametrize("release_frames", [6, 0])
def test_compiled_apply_equals_the_array_steps(release_frames: int) -> None:
    # Walking bodies (pelvis moving, random contacts), some inactive on some frames (of those,
    # some pinned all the same), a box the feet run into: every lock, release, blend, lift, push
    # and IK step of the kernel must match.
    pelvis, rots = _poses(6, seed=21)
    toe = forward_kinematics(rots, pelvis)[0][0, FOOT_JOINTS[0], :2]
    box = _box(0.6, 0.6, (float(toe[0]) + 0.5, float(toe[1])), margin=0.03)  # character 0 walks into it
    solver = FootSolver(box, release_frames=release_frames)
    rng = np.random.default_rng(22)
    contacts = rng.random((60, 6, 2)) < 0.7
    active = rng.random((60, 6)) < 0.85
    pinned = rng.random((60, 6)) < 0.5
    heading = np.array([1.0, 0.5, 0.0])
    fast = slow = solver.initial_state(6)
    locks = pushed = 0
    for f in range(60):
        p = pelvis + 0.02 * f * heading
        a, fast = solver.apply(p, rots, contacts[f], fast, active=active[f], pinned=pinned[f])
        b, slow = apply_numpy(solver, p, rots, contacts[f], slow, active=active[f], pinned=pinned[f])
        assert np.allclose(a, b, rtol=0.0, atol=1e-12)
        for name in ("locked", "release", "drifted"):
            assert np.array_equal(getattr(fast, name), getattr(slow, name)), (f, name)
        for name in ("lock", "offset"):
            assert np.allclose(getattr(fast, name), getattr(slow, name), rtol=0.0, atol=1e-12), (f, name)
        locks += int(fast.locked.sum())
        pushed += int(_depth(forward_kinematics(rots, p)[0][0, list(FOOT_JOINTS), :2], box).max() > 0)
    assert locks > 20 and pushed > 3  # the scenario really pins feet and walks a foot into the box


@pytest.mark.parametrize("seed", range(4))
def test_box_grid_finds_every_box_a_point_is_in(seed: int) -> None:
    # The grid filter of the push-out equals testing every box (rotated boxes, points on and
    # around their edges, points outside the grid).
    rng = np.random.default_rng(seed)
    n = 40
    ang = rng.uniform(-np.pi, np.pi, n)
    rights = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    fp = Footprints(centers=rng.uniform(0, 12, (n, 2)), rights=rights, facings=np.stack([-rights[:, 1], rights[:, 0]], axis=1),
                    halves=rng.uniform(0.05, 1.5, (n, 2)))
    grid = BoxGrid.of(fp, cell=0.7)
    pts = rng.uniform(-2, 14, (3000, 2, 2))
    corner = fp.centers[:, None] + fp.rights[:, None] * fp.halves[:, :1, None] + fp.facings[:, None] * fp.halves[:, 1:, None]
    pts[:n, 0] = corner[:, 0]  # exactly on a corner: not inside that box
    got = _may_be_inside(pts, fp.centers, fp.rights, fp.facings, fp.halves, grid.origin, grid.cell, *grid.shape,
                         grid.starts, grid.items)
    want = np.array([any(_box_depth(x, y, fp.centers, fp.rights, fp.facings, fp.halves, b) > 0.0
                         for x, y in pts[m] for b in range(n)) for m in range(len(pts))])
    assert np.array_equal(got, want)
    assert 0 < want.sum() < len(want)


def test_a_pinned_inactive_foot_stays_planted_and_is_not_pushed() -> None:
    # Sitting down by a table: the feet stay where they were planted, even inside a footprint.
    solver, box, pelvis, rots = _foot_in_box_case(margin=0.02)
    contacts = np.ones((1, 2), dtype=bool)
    state = solver.initial_state(1)
    toes0 = forward_kinematics(rots, pelvis)[0][0, list(FOOT_JOINTS)]
    for f in range(8):
        p = pelvis + np.array([[-0.01 * f, 0.0, -0.01 * f]])  # the body moves back and down
        out, state = solver.apply(p, rots, contacts, state, active=np.array([False]), pinned=np.array([True]))
        toes = forward_kinematics(out, p)[0][0, list(FOOT_JOINTS)]
        assert np.abs(toes - toes0).max() < 1e-6  # planted where they started, box or not
    assert _depth(toes[:, :2], box).max() > 0.0  # the left toe is still inside the footprint

"""``FootSolver.apply`` as numpy array steps: the oracle of the compiled
``storyteller.sim.body.foot_kernel.apply_frame``.

``apply_numpy(solver, ...)`` takes what ``FootSolver.apply`` takes and gives the same rotations
and states to rounding (1e-12); ``tests/sim/body/test_foot_ik.py`` compares them on a walking crowd. The
steps, in order: pinning (release, blend, lock), the reach clamp, the footprint push, lock
starts, the IK. Inputs are not checked here. Not used by the simulation.
"""

from __future__ import annotations

import numpy as np

from storyteller.sim.body.foot_clearance import push_out
from storyteller.sim.body.foot_ik import FootSolver, FootState
from storyteller.sim.body.foot_kernel import LAND_M, REPLANT_LIFT_M, TOE_FLOOR_M
from storyteller.sim.body.leg_ik import SHIN_LENGTH, THIGH_LENGTH, LegChain, solve_chain

_REACH_EPS = 1e-9  # m: reach comparisons of a lock start (the kernel's literal 1e-9)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    y: np.ndarray = x * x * (3.0 - 2.0 * x)
    return y


def apply_numpy(solver: FootSolver, pelvis: np.ndarray, rots: np.ndarray, contacts: np.ndarray, state: FootState,
                active: np.ndarray | None = None, pinned: np.ndarray | None = None) -> tuple[np.ndarray, FootState]:
    """``solver.apply(pelvis, rots, contacts, state, active, pinned)`` as array steps."""
    pelvis = np.asarray(pelvis, dtype=float)
    rots = np.asarray(rots, dtype=float)
    contacts = np.asarray(contacts)
    n = len(pelvis)
    act = np.ones(n, dtype=bool) if active is None else np.asarray(active, dtype=bool).reshape(n)
    pin = act if pinned is None else act | np.asarray(pinned, dtype=bool).reshape(n)
    chain = LegChain(pelvis, rots)
    toe = chain.toe  # (N, 2, 3)
    contact = (contacts.astype(bool) | (toe[..., 2] < TOE_FLOOR_M + LAND_M)) & pin[:, None]
    foot = toe - chain.ankle  # the foot keeps its animated world orientation

    # pinning: release, blend, lock
    full = solver.max_reach * (THIGH_LENGTH + SHIN_LENGTH)  # (2,) left, right
    drift = np.linalg.norm(state.lock - toe, axis=-1)
    overreach = np.linalg.norm(state.lock - foot - chain.hip, axis=-1) > full
    lost = state.locked & ~contact
    drifted_now = state.locked & contact & ((drift > solver.max_drift) | overreach)
    released = lost | drifted_now
    offset = np.where(released[..., None], state.lock - toe, state.offset)
    release = np.where(released, solver.release_frames,
                       np.where(state.locked, 0, np.maximum(state.release - 1, 0)))
    locked = state.locked & ~released
    drifted = (state.drifted | drifted_now) & contact & (release > 0)
    weight = _smoothstep(release / solver.release_frames) if solver.release_frames > 0 else np.zeros(release.shape)
    offset = np.where((release > 0)[..., None], offset, 0.0)
    target = np.where(locked[..., None], state.lock, toe + offset * weight[..., None])
    if solver.release_frames > 0:  # a released foot steps back to the animation, not a slide
        u = 1.0 - release / solver.release_frames
        h = np.minimum(REPLANT_LIFT_M, np.sqrt(offset[..., 0] * offset[..., 0] + offset[..., 1] * offset[..., 1]))
        stepping = (release > 0) & pin[:, None]
        target[..., 2] += np.where(stepping, h * np.sqrt(np.maximum(np.sin(np.pi * u), 0.0)), 0.0)
    target[..., 2] = np.where(pin[:, None], np.maximum(target[..., 2], TOE_FLOOR_M), target[..., 2])
    # a pinned or blending foot stays within max_reach of the leg (or the animation's own
    # reach, if longer), pulled towards the hip: the IK then seldom straightens the knee
    ankle_to = target - foot - chain.hip
    dist = np.linalg.norm(ankle_to, axis=-1)
    limit = np.maximum(full, np.linalg.norm(chain.ankle - chain.hip, axis=-1))
    far = dist > limit
    if far.any():
        scale = np.where(far, limit / np.maximum(dist, 1e-12), 1.0)[..., None]
        target = np.where(far[..., None], chain.hip + ankle_to * scale + foot, target)

    # clearance: the rigid foot (ankle, toe) out of every footprint, horizontally
    shift = np.zeros((n, 2, 2))
    if len(solver.footprints) and act.any():
        pts = np.stack([target - foot, target], axis=2)[act][..., :2]  # (A, 2 feet, 2 points, 2)
        shift[act] = push_out(pts.reshape(-1, 2, 2), solver.footprints, solver.passes).reshape(-1, 2, 2)
    target = target.copy()
    target[..., :2] += shift

    # (a target clamped to the reach sits on it up to rounding: a tolerance keeps that a start)
    start = contact & ~locked & ~drifted & (np.linalg.norm(target - foot - chain.hip, axis=-1) <= full + _REACH_EPS)
    lock = np.where(start[..., None], target, state.lock)
    locked = locked | start
    release = np.where(start, 0, release)
    offset = np.where(start[..., None], 0.0, offset)
    new_state = FootState(locked=locked, lock=np.where(locked[..., None], lock, 0.0),
                          offset=offset, release=release, drifted=drifted)

    # every leg of an active character goes through the IK (a leg whose target is its own
    # ankle comes back as it was, up to rounding, unless its knee bent backwards), so a
    # lock or a push never switches the knee rule on in the middle of a stride
    solve = (np.linalg.norm(target - toe, axis=-1) > 0.0) | act[:, None]
    return solve_chain(chain, rots, target - foot, solve), new_state

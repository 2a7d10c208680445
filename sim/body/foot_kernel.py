"""One compiled pass of ``FootSolver.apply`` (``storyteller.sim.body.foot_ik``) over all characters and legs.

``FootSolver.apply`` is a chain of small array steps (leg forward kinematics, the pinning
state machine, the reach clamp, the footprint push, lock starts, the IK); on a crowd of ten
characters each step costs more in numpy call overhead than in arithmetic. ``apply_frame``
does the same steps per character and leg in one numba kernel, calling the same compiled
push-out and IK kernels (``storyteller.sim.body.foot_clearance``, ``storyteller.sim.body.leg_ik``). Its per-leg
arithmetic works on scalars and writes into preallocated rows (no temporary 3-vectors, which
cost a heap allocation each), with the float operations in the same order, so the result is
bit for bit the one of the vector form. The array version is
kept as a test oracle (``tests/support/foot_reference.py``); ``tests/sim/body/test_foot_ik.py`` checks
both give the same rotations and states (to 1e-12) on a recorded crowd.

numba's on-disk cache of ``apply_frame`` is checked against this file only: the kernels it
calls (``leg_ik._ik_kernel``, ``foot_clearance``) are compiled into it, so a change to them
reaches ``apply_frame`` only once this file changes too (or its ``__pycache__`` entries go).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from storyteller.sim.body.foot_clearance import _may_be_inside, _push_out_kernel
from storyteller.sim.body.leg_ik import (
    _ANKLE_OFF,
    _HIP_OFF,
    _KNEE_OFF,
    _TOE_OFF,
    HIP_JOINTS,
    KNEE_JOINTS,
    _ik_kernel,
)
from storyteller.sim.body.skeleton import JOINT_INDEX, REST_OFFSETS
from storyteller.sim.motion.clips import ANKLE_JOINTS

__all__ = ["LAND_M", "REPLANT_LIFT_M", "TOE_FLOOR_M", "apply_frame"]

TOE_FLOOR_M = float(REST_OFFSETS[0, 1] + sum(
    REST_OFFSETS[JOINT_INDEX[j], 1] for j in ("left_hip", "left_knee", "left_ankle", "left_foot")))
"""Height (m) of the toe joint (SMPL's ``*_foot``, the ball of the foot) above the floor (z = 0,
the height the motion is placed on) when the foot stands flat: an active character's toe
target is never lower (a blend between two clips can swing a leg through the floor)."""

LAND_M = 0.02
"""A toe (the animated pose's) lower than ``TOE_FLOOR_M + LAND_M`` is on the floor, flagged in
contact or not: it is pinned like a flagged one. Blends between clips (inertialization) and
clip switches put a foot down some frames before, or after, the clip's contact flag says so; it
then slid along the floor (50-walker crowd: 242 of 799 skating foot-frames had no flag at all,
210 more started a lock late)."""

REPLANT_LIFT_M = 0.08
"""Highest lift (m) of a released foot on its way back to the animation (its lock left behind
when the contact ended, or lost while in contact, too far from the hip): it takes a quick step
there instead of sliding along the floor; its horizontal distance when that is less."""

_HIP_J = np.array(HIP_JOINTS, dtype=np.int64)  # (left, right)
_KNEE_J = np.array(KNEE_JOINTS, dtype=np.int64)
_ANKLE_J = np.array(ANKLE_JOINTS, dtype=np.int64)


@njit(cache=True, inline="always")
def _hyp3(x: float, y: float, z: float) -> float:  # pragma: no cover - compiled
    """``_norm3`` of the vector (x, y, z), the same float operations."""
    return math.sqrt(x * x + y * y + z * z)


@njit(cache=True)
def _affine_into(p: NDArray[np.float64], a: NDArray[np.float64], v: NDArray[np.float64],
                 out: NDArray[np.float64]) -> None:  # pragma: no cover - compiled
    """``out = p + _matvec3(a, v)``, the same float operations, without a temporary array."""
    for i in range(3):
        out[i] = p[i] + (a[i, 0] * v[0] + a[i, 1] * v[1] + a[i, 2] * v[2])


@njit(cache=True)
def _matmul3_into(a: NDArray[np.float64], b: NDArray[np.float64], out: NDArray[np.float64]) -> None:  # pragma: no cover
    """``out = _matmul3(a, b)`` without a temporary array."""
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]


@njit(cache=True)
def apply_frame(
    pelvis: NDArray[np.float64], rots: NDArray[np.float64], contacts: NDArray[np.bool_], act: NDArray[np.float64],
    pin: NDArray[np.bool_],
    locked: NDArray[np.bool_], lock: NDArray[np.float64], offset: NDArray[np.float64], release: NDArray[np.int64],
    drifted: NDArray[np.bool_],
    full: NDArray[np.float64], thigh: NDArray[np.float64], shin: NDArray[np.float64], max_drift: float, release_frames: int,
    centers: NDArray[np.float64], rights: NDArray[np.float64], facings: NDArray[np.float64], halves: NDArray[np.float64], passes: int,
    grid_origin: NDArray[np.float64], grid_cell: float, grid_nx: int, grid_ny: int, grid_starts: NDArray[np.int64],
    grid_items: NDArray[np.int64],
) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64], NDArray[np.float64], NDArray[np.int64], NDArray[np.bool_]]:  # pragma: no cover
    """(rotations, locked, lock, offset, release, drifted) after one frame; see
    ``apply_numpy`` in ``tests/support/foot_reference.py`` for the steps (the same, per character
    and leg). ``grid_*``: the footprints' ``BoxGrid``; only the feet it finds inside a box run
    the push-out (the others it would leave in place)."""
    n = pelvis.shape[0]
    out = rots.copy()
    n_locked = np.zeros((n, 2), dtype=np.bool_)
    n_lock = np.zeros((n, 2, 3))
    n_offset = np.zeros((n, 2, 3))
    n_release = np.zeros((n, 2), dtype=np.int64)
    n_drifted = np.zeros((n, 2), dtype=np.bool_)
    hip = np.empty((n, 2, 3))
    knee = np.empty((n, 2, 3))
    ankle = np.empty((n, 2, 3))
    toe = np.empty((n, 2, 3))
    hip_r = np.empty((n, 2, 3, 3))
    knee_r = np.empty((n, 2, 3, 3))
    ankle_r = np.empty((n, 2, 3, 3))
    target = np.empty((n, 2, 3))
    foot = np.empty((n, 2, 3))
    for c in range(n):
        g0 = rots[c, 0]
        for leg in range(2):
            # forward kinematics of the leg (the float operations of ``_matvec3`` / ``_matmul3``,
            # written into the outputs: no temporary arrays per character)
            _affine_into(pelvis[c], g0, _HIP_OFF[leg], hip[c, leg])
            _matmul3_into(g0, rots[c, _HIP_J[leg]], hip_r[c, leg])
            _affine_into(hip[c, leg], hip_r[c, leg], _KNEE_OFF[leg], knee[c, leg])
            _matmul3_into(hip_r[c, leg], rots[c, _KNEE_J[leg]], knee_r[c, leg])
            _affine_into(knee[c, leg], knee_r[c, leg], _ANKLE_OFF[leg], ankle[c, leg])
            _matmul3_into(knee_r[c, leg], rots[c, _ANKLE_J[leg]], ankle_r[c, leg])
            _affine_into(ankle[c, leg], ankle_r[c, leg], _TOE_OFF[leg], toe[c, leg])
            for i in range(3):
                foot[c, leg, i] = toe[c, leg, i] - ankle[c, leg, i]
            lk, tp, ft, hp = lock[c, leg], toe[c, leg], foot[c, leg], hip[c, leg]
            contact = (contacts[c, leg] or tp[2] < TOE_FLOOR_M + LAND_M) and pin[c]
            # pinning: release, blend, lock
            drift = _hyp3(lk[0] - tp[0], lk[1] - tp[1], lk[2] - tp[2])
            overreach = _hyp3(lk[0] - ft[0] - hp[0], lk[1] - ft[1] - hp[1], lk[2] - ft[2] - hp[2]) > full[leg]
            was = locked[c, leg]
            drifted_now = was and contact and (drift > max_drift or overreach)
            released = (was and not contact) or drifted_now
            if released:
                o0, o1, o2 = lk[0] - tp[0], lk[1] - tp[1], lk[2] - tp[2]
            else:
                o0, o1, o2 = offset[c, leg, 0], offset[c, leg, 1], offset[c, leg, 2]
            if released:
                rel = release_frames
            elif was:
                rel = 0
            else:
                rel = max(release[c, leg] - 1, 0)
            still = was and not released
            dr = (drifted[c, leg] or drifted_now) and contact and rel > 0
            if release_frames > 0:
                x = min(max(rel / release_frames, 0.0), 1.0)
                weight = x * x * (3.0 - 2.0 * x)
            else:
                weight = 0.0
            if rel <= 0:
                o0, o1, o2 = 0.0, 0.0, 0.0
            if still:
                t0, t1, t2 = lk[0], lk[1], lk[2]
            else:
                t0, t1, t2 = tp[0] + o0 * weight, tp[1] + o1 * weight, tp[2] + o2 * weight
            if rel > 0 and pin[c]:  # a released foot steps back to the animation, it does not slide
                u = 1.0 - rel / release_frames
                t2 += min(REPLANT_LIFT_M, math.sqrt(o0 * o0 + o1 * o1)) * math.sqrt(math.sin(math.pi * u))
            if pin[c] and t2 < TOE_FLOOR_M:  # never through the floor
                t2 = TOE_FLOOR_M
            # a pinned or blending foot stays within reach of the leg, pulled towards the hip
            a0, a1, a2 = t0 - ft[0] - hp[0], t1 - ft[1] - hp[1], t2 - ft[2] - hp[2]
            dist = _hyp3(a0, a1, a2)
            an = ankle[c, leg]
            limit = max(full[leg], _hyp3(an[0] - hp[0], an[1] - hp[1], an[2] - hp[2]))
            if dist > limit:
                f = limit / max(dist, 1e-12)
                t0, t1, t2 = hp[0] + a0 * f + ft[0], hp[1] + a1 * f + ft[1], hp[2] + a2 * f + ft[2]
            target[c, leg, 0], target[c, leg, 1], target[c, leg, 2] = t0, t1, t2
            n_locked[c, leg] = still
            n_offset[c, leg, 0], n_offset[c, leg, 1], n_offset[c, leg, 2] = o0, o1, o2
            n_release[c, leg] = rel
            n_drifted[c, leg] = dr
    # clearance: the rigid foot (ankle, toe) of every active character out of every footprint
    if centers.shape[0] > 0:
        m_act = 0
        for c in range(n):
            if act[c]:
                m_act += 2
        if m_act > 0:
            pts = np.empty((m_act, 2, 2))
            k = 0
            for c in range(n):
                if act[c]:
                    for leg in range(2):
                        for j in range(2):
                            pts[k, 0, j] = target[c, leg, j] - foot[c, leg, j]
                            pts[k, 1, j] = target[c, leg, j]
                        k += 1
            inside = _may_be_inside(pts, centers, rights, facings, halves, grid_origin, grid_cell, grid_nx, grid_ny,
                                    grid_starts, grid_items)
            shift = np.zeros((m_act, 2))
            sel = np.flatnonzero(inside)
            if sel.shape[0] > 0:
                shift[sel] = _push_out_kernel(pts[sel], centers, rights, facings, halves, passes)
            k = 0
            for c in range(n):
                if act[c]:
                    for leg in range(2):
                        target[c, leg, 0] += shift[k, 0]
                        target[c, leg, 1] += shift[k, 1]
                        k += 1
    # lock starts, the new state, the legs to solve
    m_solve = 0
    solve = np.zeros((n, 2), dtype=np.bool_)
    for c in range(n):
        for leg in range(2):
            tg, ft, hp, tp = target[c, leg], foot[c, leg], hip[c, leg], toe[c, leg]
            contact = (contacts[c, leg] or tp[2] < TOE_FLOOR_M + LAND_M) and pin[c]
            reach = _hyp3(tg[0] - ft[0] - hp[0], tg[1] - ft[1] - hp[1], tg[2] - ft[2] - hp[2])
            start = contact and not n_locked[c, leg] and not n_drifted[c, leg] and reach <= full[leg] + 1e-9  # m: reach tolerance of a lock start
            lk = tg if start else lock[c, leg]
            if start:
                n_locked[c, leg] = True
                n_release[c, leg] = 0
                n_offset[c, leg, 0], n_offset[c, leg, 1], n_offset[c, leg, 2] = 0.0, 0.0, 0.0
            for i in range(3):
                n_lock[c, leg, i] = lk[i] if n_locked[c, leg] else 0.0
            solve[c, leg] = _hyp3(tg[0] - tp[0], tg[1] - tp[1], tg[2] - tp[2]) > 0.0 or act[c]
            if solve[c, leg]:
                m_solve += 1
    if m_solve > 0:
        s_hip = np.empty((m_solve, 3))
        s_knee = np.empty((m_solve, 3))
        s_ankle = np.empty((m_solve, 3))
        s_pel = np.empty((m_solve, 3, 3))
        s_hr = np.empty((m_solve, 3, 3))
        s_kr = np.empty((m_solve, 3, 3))
        s_ar = np.empty((m_solve, 3, 3))
        s_tg = np.empty((m_solve, 3))
        s_th = np.empty(m_solve)
        s_sh = np.empty(m_solve)
        k = 0
        for c in range(n):
            for leg in range(2):
                if solve[c, leg]:
                    s_hip[k] = hip[c, leg]
                    s_knee[k] = knee[c, leg]
                    s_ankle[k] = ankle[c, leg]
                    s_pel[k] = rots[c, 0]
                    s_hr[k] = hip_r[c, leg]
                    s_kr[k] = knee_r[c, leg]
                    s_ar[k] = ankle_r[c, leg]
                    for i in range(3):
                        s_tg[k, i] = target[c, leg, i] - foot[c, leg, i]
                    s_th[k] = thigh[leg]
                    s_sh[k] = shin[leg]
                    k += 1
        new_hip, new_knee, new_ankle = _ik_kernel(s_hip, s_knee, s_ankle, s_pel, s_hr, s_kr, s_ar, s_tg, s_th, s_sh)
        k = 0
        for c in range(n):
            for leg in range(2):
                if solve[c, leg]:
                    out[c, _HIP_J[leg]] = new_hip[k]
                    out[c, _KNEE_J[leg]] = new_knee[k]
                    out[c, _ANKLE_J[leg]] = new_ankle[k]
                    k += 1
    return out, n_locked, n_lock, n_offset, n_release, n_drifted

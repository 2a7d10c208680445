"""Legs of different characters kept apart: a pose filter after the foot IK.

Why: the planner keeps pelvises ``2 * body_radius`` apart and, for two walkers that both move
in a step, their legs as one segment each (``storyteller.sim.paths.move_tables.striding_safe``); a pair
that starts closer than that model allows gets no closer, so a walker may follow another two
cells (0.6 m) behind for a whole corridor. The animated legs reach further than the segment
(toes about 0.42 m ahead of the pelvis, ankles 0.46 m behind), so the follower's front foot
swings into the leader's back leg. The planner rules that kept such walkers a stride apart
left overlaps and cost the crowd 10-40% of its errands (``benchmark/results/2026-12-07-motion.md``:
the planner cannot shorten a step), so the feet make room instead, as people's do.

What: each leg is three capsules, thigh (hip-knee), shin (knee-ankle) and foot (ankle-toe),
radii ``LEG_CAPSULES``. Wherever two characters' legs come closer than their radii plus
``MARGIN_M``, the two ankles are shifted horizontally apart along the line between the
closest points, by what that contact needs (a point between hip and ankle moves about its
share of the ankle's shift), shared by how free each foot is: a foot on the floor gives
``GIVE_PLANTED`` of what a lifted one does, so a planted foot hardly slides and a swinging
one lands beside or short of the other's. The legs are then solved onto the shifted ankles
with the analytic two-bone IK (``storyteller.sim.body.leg_ik``; the foot keeps its orientation),
and found again, up to ``PASSES`` times; only pairs with a moved leg are looked at again.

Guarantee: a pose comes back with no two characters' leg capsules overlapping, unless an
ankle would have to move more than ``MAX_SHIFT_M`` from where the foot IK put it, ``PASSES``
did not settle it, or the legs meet across more than ``PAIR_REACH_M`` between the pelvises;
the report (``LegContacts.left``) gives what is left of the first two. Characters
whose legs stay as animated (``movable`` False: seated, sitting down, standing up) are
obstacles only; two characters both ``touching`` (a hug) may touch. Only the hips, knees and
ankles of moved legs change; a frame with no contact comes back as the same array. Not
checked: a moved foot against furniture (the foot IK's push-out ran before) and a leg against
its own other leg. Pure and deterministic: a function of one frame's poses.

The work is one numba kernel (``_separate``); numba's on-disk cache of it is checked against
this file only, so a change to ``leg_ik._ik_kernel``, which is compiled into it, reaches it
once this file changes too (or its ``__pycache__`` entries go).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from storyteller.sim.body.foot_kernel import TOE_FLOOR_M, _affine_into, _matmul3_into
from storyteller.sim.body.leg_ik import (
    _ANKLE_OFF,
    _HIP_OFF,
    _KNEE_OFF,
    _TOE_OFF,
    HIP_JOINTS,
    KNEE_JOINTS,
    SHIN_LENGTH,
    THIGH_LENGTH,
    _ik_kernel,
)
from storyteller.sim.motion.clips import ANKLE_JOINTS

__all__ = ["GIVE_PLANTED", "LEG_CAPSULES", "MARGIN_M", "MAX_SHIFT_M", "PASSES", "TOUCHING_ACTIONS", "LegContacts",
           "separate_legs"]

LEG_CAPSULES = (0.07, 0.05, 0.04)
"""Radii (m) of a leg's thigh (hip-knee), shin (knee-ankle) and foot (ankle-toe) capsules, for an
adult of about 1.72 m (the skeleton's rest proportions); the same round figures as the
benchmark's body model (``storyteller.benchmark.motion_metrics.bodies``), which measures on
its own."""
MARGIN_M = 0.01
"""Metres kept between two legs' capsules beyond their radii."""
MAX_SHIFT_M = 0.2
"""Farthest (m, horizontal) an ankle is moved from where the foot IK put it."""
PASSES = 8
"""Most rounds of finding contacts and solving the legs in one frame (a knee against a knee
takes a few: the IK moves a knee less than its ankle)."""
GIVE_PLANTED = 0.15
"""How far a foot on the floor moves against a swinging one (1: as far); it rises to 1 as
the toe lifts ``LIFT_M`` off the floor."""
LIFT_M = 0.04
TOUCHING_ACTIONS = frozenset({"hug"})
"""Actions whose bodies touch by design: the legs of two characters both doing one are left alone."""
PAIR_REACH_M = 1.3
"""Pelvises further apart than this (xy, m) are not looked at: their legs would have to reach
more than 0.57 m from the pelvis each (a walker's toes reach about 0.45 m)."""
_LEVER_MIN = 0.2  # a contact point this near the hip (share of the hip-ankle distance) moves as if there
_SETTLED_M = 1e-3  # a contact within the margin by less than this is left as it is (no further pass)
_RADII = np.array(LEG_CAPSULES, dtype=np.float64)
_HIP_J = np.array(HIP_JOINTS, dtype=np.int64)  # (left, right)
_KNEE_J = np.array(KNEE_JOINTS, dtype=np.int64)
_ANKLE_J = np.array(ANKLE_JOINTS, dtype=np.int64)
_THIGH = np.asarray(THIGH_LENGTH, dtype=np.float64)
_SHIN = np.asarray(SHIN_LENGTH, dtype=np.float64)


@dataclass(frozen=True)
class LegContacts:
    """What ``separate_legs`` found in one frame: ``pairs`` of characters whose legs touched,
    ``moved`` legs, and ``left``: the deepest overlap (m) it could not undo (0: none)."""

    pairs: int
    moved: int
    left: float


def separate_legs(pelvis: NDArray[np.float64], rots: NDArray[np.float64], movable: NDArray[np.bool_],
                  touching: NDArray[np.bool_]) -> tuple[NDArray[np.float64], LegContacts]:
    """Local rotations (N, 22, 3, 3) with the legs of different characters apart (see the
    module docstring), and what was found. ``pelvis`` (N, 3) world, ``rots`` (N, 22, 3, 3) local
    rotations (joint 0 in world), ``movable`` and ``touching`` (N,) bool. ``rots`` itself comes
    back when no legs touch."""
    if len(pelvis) < 2:
        return rots, LegContacts(0, 0, 0.0)
    out, pairs, moved, left = _separate(
        np.ascontiguousarray(pelvis, dtype=np.float64), np.ascontiguousarray(rots, dtype=np.float64),
        np.ascontiguousarray(movable, dtype=np.bool_), np.ascontiguousarray(touching, dtype=np.bool_),
        _RADII, MARGIN_M, GIVE_PLANTED, LIFT_M, TOE_FLOOR_M, PAIR_REACH_M, MAX_SHIFT_M, PASSES)
    return (rots if moved == 0 else out), LegContacts(pairs, moved, left)


@njit(cache=True)
def _separate(pelvis: NDArray[np.float64], rots: NDArray[np.float64], movable: NDArray[np.bool_],
              touching: NDArray[np.bool_], radii: NDArray[np.float64], margin: float, give_planted: float,
              lift: float, toe_floor: float, reach: float, max_shift: float, passes: int,
              ) -> tuple[NDArray[np.float64], int, int, float]:  # pragma: no cover - compiled
    """(rotations, pairs touching at first, legs moved, deepest overlap left) of
    ``separate_legs``: up to ``passes`` rounds of leg forward kinematics, shifts, IK."""
    n = pelvis.shape[0]
    near = _near_pairs(pelvis, movable, touching, reach)
    if near.shape[0] == 0:
        return rots, 0, 0, 0.0
    out, copied = rots, False
    legs = np.empty((n, 2, 4, 3))  # hip, knee, ankle, toe (world)
    frames = np.empty((n, 2, 3, 3, 3))  # world rotations of hip, knee, ankle
    moved = np.zeros((n, 2), dtype=np.bool_)
    total = np.zeros((n, 2, 2))  # each ankle's shift so far (xy)
    pairs, left = 0, 0.0
    for k in range(passes + 1):
        _leg_kinematics(pelvis, out, near, legs, frames)
        shift, found, left = _leg_shifts(pelvis, legs, near, movable, radii, margin, give_planted, lift, toe_floor,
                                         max_shift)
        if k == 0:
            pairs = found
        if k == passes:
            break
        which = np.zeros((n, 2), dtype=np.bool_)
        m = 0
        for c in range(n):
            for leg in range(2):
                if shift[c, leg, 0] == 0.0 and shift[c, leg, 1] == 0.0:
                    continue
                # at most max_shift from where the foot IK put the ankle, over all passes
                x, y = total[c, leg, 0] + shift[c, leg, 0], total[c, leg, 1] + shift[c, leg, 1]
                f = min(1.0, max_shift / max(math.sqrt(x * x + y * y), 1e-12))
                shift[c, leg, 0], shift[c, leg, 1] = x * f - total[c, leg, 0], y * f - total[c, leg, 1]
                total[c, leg, 0], total[c, leg, 1] = x * f, y * f
                if abs(shift[c, leg, 0]) + abs(shift[c, leg, 1]) > 1e-9:
                    which[c, leg] = True
                    moved[c, leg] = True
                    m += 1
        if m == 0:
            break
        if not copied:
            out, copied = rots.copy(), True
        _solve(out, legs, frames, shift, which, m)
        near = _with_moved(near, moved)  # only where a leg moved can legs meet anew (or still)
    return out, pairs, int(moved.sum()), left


@njit(cache=True)
def _near_pairs(pelvis: NDArray[np.float64], movable: NDArray[np.bool_], touching: NDArray[np.bool_],
                reach: float) -> NDArray[np.int64]:  # pragma: no cover - compiled
    """(P, 2) pairs (a, b), a < b, of characters whose legs may touch: pelvises within ``reach``
    (xy), one of them movable, not both touching; found by a sweep along x (a crowd costs about
    its pairs, not its square), in the order of the sweep."""
    n = pelvis.shape[0]
    order = np.argsort(pelvis[:, 0], kind="mergesort")
    r2 = reach * reach
    count = 0
    for sweep in range(2):  # count, then fill
        out = np.empty((count, 2), dtype=np.int64)
        k = 0
        for u in range(n):
            a = order[u]
            for v in range(u + 1, n):
                b = order[v]
                dx = pelvis[b, 0] - pelvis[a, 0]
                if dx > reach:
                    break
                dy = pelvis[b, 1] - pelvis[a, 1]
                if dx * dx + dy * dy <= r2 and (movable[a] or movable[b]) and not (touching[a] and touching[b]):
                    if sweep == 1:
                        out[k, 0], out[k, 1] = min(a, b), max(a, b)
                    k += 1
        count = k
    return out


@njit(cache=True)
def _with_moved(near: NDArray[np.int64], which: NDArray[np.bool_]) -> NDArray[np.int64]:  # pragma: no cover
    """The pairs of ``near`` with a character one of whose legs ``which`` (N, 2) marks."""
    keep = np.zeros(near.shape[0], dtype=np.bool_)
    for p in range(near.shape[0]):
        a, b = near[p, 0], near[p, 1]
        keep[p] = which[a, 0] or which[a, 1] or which[b, 0] or which[b, 1]
    return near[keep]


@njit(cache=True)
def _leg_kinematics(pelvis: NDArray[np.float64], rots: NDArray[np.float64], near: NDArray[np.int64],
                    legs: NDArray[np.float64], frames: NDArray[np.float64]) -> None:  # pragma: no cover - compiled
    """World hip, knee, ankle, toe (into ``legs``) and world rotations of hip, knee, ankle (into
    ``frames``) of both legs of every character in ``near``."""
    done = np.zeros(pelvis.shape[0], dtype=np.bool_)
    for p in range(near.shape[0]):
        for c in (near[p, 0], near[p, 1]):
            if done[c]:
                continue
            done[c] = True
            for leg in range(2):
                _matmul3_into(rots[c, 0], rots[c, _HIP_J[leg]], frames[c, leg, 0])
                _matmul3_into(frames[c, leg, 0], rots[c, _KNEE_J[leg]], frames[c, leg, 1])
                _matmul3_into(frames[c, leg, 1], rots[c, _ANKLE_J[leg]], frames[c, leg, 2])
                _affine_into(pelvis[c], rots[c, 0], _HIP_OFF[leg], legs[c, leg, 0])
                _affine_into(legs[c, leg, 0], frames[c, leg, 0], _KNEE_OFF[leg], legs[c, leg, 1])
                _affine_into(legs[c, leg, 1], frames[c, leg, 1], _ANKLE_OFF[leg], legs[c, leg, 2])
                _affine_into(legs[c, leg, 2], frames[c, leg, 2], _TOE_OFF[leg], legs[c, leg, 3])


@njit(cache=True)
def _closest(p: NDArray[np.float64], i: int, q: NDArray[np.float64], j: int) -> tuple[float, float]:  # pragma: no cover
    """Parameters (s, t) in [0, 1] of the closest points of segments p[i]-p[i+1] and q[j]-q[j+1]."""
    d1x, d1y, d1z = p[i + 1, 0] - p[i, 0], p[i + 1, 1] - p[i, 1], p[i + 1, 2] - p[i, 2]
    d2x, d2y, d2z = q[j + 1, 0] - q[j, 0], q[j + 1, 1] - q[j, 1], q[j + 1, 2] - q[j, 2]
    rx, ry, rz = p[i, 0] - q[j, 0], p[i, 1] - q[j, 1], p[i, 2] - q[j, 2]
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    f = d2x * rx + d2y * ry + d2z * rz
    if a <= 1e-12 and e <= 1e-12:
        return 0.0, 0.0
    if a <= 1e-12:
        return 0.0, min(max(f / e, 0.0), 1.0)
    c = d1x * rx + d1y * ry + d1z * rz
    if e <= 1e-12:
        return min(max(-c / a, 0.0), 1.0), 0.0
    b = d1x * d2x + d1y * d2y + d1z * d2z
    den = a * e - b * b
    s = min(max((b * f - c * e) / den, 0.0), 1.0) if den > 1e-12 else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t, s = 0.0, min(max(-c / a, 0.0), 1.0)
    elif t > 1.0:
        t, s = 1.0, min(max((b - c) / a, 0.0), 1.0)
    return s, t


@njit(cache=True)
def _leg_shifts(pelvis: NDArray[np.float64], legs: NDArray[np.float64], near: NDArray[np.int64],
                movable: NDArray[np.bool_], radii: NDArray[np.float64], margin: float, give_planted: float,
                lift: float, toe_floor: float, max_shift: float,
                ) -> tuple[NDArray[np.float64], int, float]:  # pragma: no cover - compiled
    """Horizontal ankle shifts (N, 2, 3) that part the touching legs of the ``near`` pairs, the
    number of pairs with legs touching, and the deepest overlap (m, radii only) found."""
    shift = np.zeros((pelvis.shape[0], 2, 3))
    pairs = 0
    deepest = 0.0
    reach = 2.0 * radii.max() + margin  # legs whose joints' boxes are further apart cannot touch
    qa, qb = np.empty(3), np.empty(3)  # the closest points of the deepest contact
    for p in range(near.shape[0]):
        a, b = near[p, 0], near[p, 1]
        hit = False
        for la in range(2):
            for lb in range(2):
                pa, pb = legs[a, la], legs[b, lb]
                if not _boxes_meet(pa, pb, reach):
                    continue
                over, need = _deepest_contact(pa, pb, radii, qa, qb)
                deepest = max(deepest, over)
                if over + margin <= _SETTLED_M:
                    continue
                hit = True
                wa = _give(pa[3, 2], give_planted, lift, toe_floor) if movable[a] else 0.0
                wb = _give(pb[3, 2], give_planted, lift, toe_floor) if movable[b] else 0.0
                hx, hy, vz = qa[0] - qb[0], qa[1] - qb[1], qa[2] - qb[2]
                h = math.sqrt(hx * hx + hy * hy)
                grow = math.sqrt(max((need + margin) ** 2 - vz * vz, 0.0)) - h  # horizontal metres still needed
                if wa + wb <= 0.0 or grow <= 0.0:
                    continue
                if h > 1e-6:
                    ux, uy = hx / h, hy / h
                else:  # one right above the other: apart along the line between the pelvises
                    dx, dy = pelvis[a, 0] - pelvis[b, 0], pelvis[a, 1] - pelvis[b, 1]
                    g = math.sqrt(dx * dx + dy * dy)
                    ux, uy = (dx / g, dy / g) if g > 1e-9 else (1.0, 0.0)
                _push(shift[a, la], pa, qa, ux, uy, grow * wa / (wa + wb), max_shift)
                _push(shift[b, lb], pb, qb, -ux, -uy, grow * wb / (wa + wb), max_shift)
        if hit:
            pairs += 1
    return shift, pairs, max(deepest, 0.0)


@njit(cache=True)
def _deepest_contact(pa: NDArray[np.float64], pb: NDArray[np.float64], radii: NDArray[np.float64],
                     qa: NDArray[np.float64], qb: NDArray[np.float64]) -> tuple[float, float]:  # pragma: no cover
    """The deepest overlap (m; negative: the smallest gap) between the capsules of two legs
    ``pa`` and ``pb`` (hip, knee, ankle, toe: (4, 3)) and the sum of those two capsules' radii;
    their closest points go into ``qa`` and ``qb``."""
    best, need = -math.inf, 0.0
    for i in range(3):
        for j in range(3):
            s, t = _closest(pa, i, pb, j)
            ax = pa[i, 0] + s * (pa[i + 1, 0] - pa[i, 0])
            ay = pa[i, 1] + s * (pa[i + 1, 1] - pa[i, 1])
            az = pa[i, 2] + s * (pa[i + 1, 2] - pa[i, 2])
            bx = pb[j, 0] + t * (pb[j + 1, 0] - pb[j, 0])
            by = pb[j, 1] + t * (pb[j + 1, 1] - pb[j, 1])
            bz = pb[j, 2] + t * (pb[j + 1, 2] - pb[j, 2])
            over = radii[i] + radii[j] - math.sqrt((ax - bx) ** 2 + (ay - by) ** 2 + (az - bz) ** 2)
            if over > best:
                best, need = over, radii[i] + radii[j]
                qa[0], qa[1], qa[2], qb[0], qb[1], qb[2] = ax, ay, az, bx, by, bz
    return best, need


@njit(cache=True)
def _push(shift: NDArray[np.float64], leg: NDArray[np.float64], at: NDArray[np.float64], ux: float, uy: float,
          amount: float, max_shift: float) -> None:  # pragma: no cover - compiled
    """Add to ``shift`` (3,) the ankle shift along (ux, uy) that moves the point ``at`` of the leg
    ``leg`` (hip, knee, ankle, toe) by ``amount`` metres: a point between hip and ankle moves
    about its share of the hip-ankle distance (the IK swings the leg about the hip)."""
    hp, an = leg[0], leg[2]
    if amount <= 0.0:
        return
    share = math.sqrt((at[0] - hp[0]) ** 2 + (at[1] - hp[1]) ** 2 + (at[2] - hp[2]) ** 2)
    full = math.sqrt((an[0] - hp[0]) ** 2 + (an[1] - hp[1]) ** 2 + (an[2] - hp[2]) ** 2)
    move = min(amount / max(share / max(full, 1e-9), _LEVER_MIN), max_shift)
    shift[0] += ux * move
    shift[1] += uy * move


@njit(cache=True)
def _boxes_meet(p: NDArray[np.float64], q: NDArray[np.float64], gap: float) -> bool:  # pragma: no cover - compiled
    """Whether the boxes around the joints ``p`` and ``q`` (4, 3) come within ``gap`` on every axis."""
    for i in range(3):
        lo_p = min(min(p[0, i], p[1, i]), min(p[2, i], p[3, i]))
        hi_p = max(max(p[0, i], p[1, i]), max(p[2, i], p[3, i]))
        lo_q = min(min(q[0, i], q[1, i]), min(q[2, i], q[3, i]))
        hi_q = max(max(q[0, i], q[1, i]), max(q[2, i], q[3, i]))
        if lo_p > hi_q + gap or lo_q > hi_p + gap:
            return False
    return True


@njit(cache=True)
def _give(toe_z: float, give_planted: float, lift: float, toe_floor: float) -> float:  # pragma: no cover - compiled
    """How free a foot whose toe is at height ``toe_z`` is to move (``give_planted`` .. 1)."""
    u = min(max((toe_z - toe_floor) / lift, 0.0), 1.0)
    return give_planted + (1.0 - give_planted) * u


@njit(cache=True)
def _solve(out: NDArray[np.float64], legs: NDArray[np.float64], frames: NDArray[np.float64], shift: NDArray[np.float64],
           which: NDArray[np.bool_], m: int) -> None:  # pragma: no cover - compiled
    """Two-bone IK (``leg_ik._ik_kernel``) of the ``which`` legs onto their shifted ankles, into ``out``."""
    hip, knee, ankle, target = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3))
    pel_r, hip_r, knee_r, ankle_r = np.empty((m, 3, 3)), np.empty((m, 3, 3)), np.empty((m, 3, 3)), np.empty((m, 3, 3))
    thigh, shin = np.empty(m), np.empty(m)
    k = 0
    for c in range(which.shape[0]):
        for leg in range(2):
            if which[c, leg]:
                hip[k], knee[k], ankle[k] = legs[c, leg, 0], legs[c, leg, 1], legs[c, leg, 2]
                target[k] = legs[c, leg, 2] + shift[c, leg]
                pel_r[k], hip_r[k], knee_r[k], ankle_r[k] = out[c, 0], frames[c, leg, 0], frames[c, leg, 1], frames[c, leg, 2]
                thigh[k], shin[k] = _THIGH[leg], _SHIN[leg]
                k += 1
    new_hip, new_knee, new_ankle = _ik_kernel(hip, knee, ankle, pel_r, hip_r, knee_r, ankle_r, target, thigh, shin)
    k = 0
    for c in range(which.shape[0]):
        for leg in range(2):
            if which[c, leg]:
                out[c, _HIP_J[leg]] = new_hip[k]
                out[c, _KNEE_J[leg]] = new_knee[k]
                out[c, _ANKLE_J[leg]] = new_ankle[k]
                k += 1

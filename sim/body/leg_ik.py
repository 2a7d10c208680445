"""Analytic two-bone IK of the legs (hip-knee-ankle) on the 22-joint skeleton.

``solve_legs(pelvis, rots, ankle_targets, which)`` puts each selected leg's ankle on its
target and returns new local rotations: the knee's interior angle comes from the law of
cosines, turned about the normal of the animated leg's plane (hip, knee, ankle), so the knee
bends where the animation bent it; as the animated leg straightens, its plane becomes noise
(undefined when straight), so the hinge is blended towards the thigh's flexion axis (its
local x, about which the knee bends towards the front of the leg; equal weights 14 degrees
from straight, ``HINGE_BLEND``); a knee the animation bends backwards (some source frames do,
by up to ~55 degrees) is bent forwards instead (the hinge's backward component is mirrored,
which is continuous); a
second turn about the bent leg's own plane keeps the reach exact. The whole leg then swings about
the hip onto the target with the smallest rotation. The ankle's local rotation is recomputed
so that the foot keeps its world orientation (the toe follows the ankle rigidly). Targets out
of reach are clamped to the bones' range along the hip-target line (stretched or folded as far
as possible); a target on the hip keeps the animated direction. Pelvis, spine, arms and toes
are never touched.

The per-leg math is one numba kernel (``_ik_kernel``) on scalars: no temporary arrays per leg
(it runs for every leg of a crowd every frame). ``tests/sim/body/test_foot_ik.py`` checks it bit for bit
against ``_ik_kernel.py_func`` (the same code in Python) and against the same math written with
small arrays (``tests/support/leg_ik_reference.py``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import JOINT_INDEX, NUM_JOINTS, REST_OFFSETS
from storyteller.sim.motion.clips import ANKLE_JOINTS, FOOT_JOINTS

__all__ = [
    "HIP_JOINTS",
    "KNEE_JOINTS",
    "LEG_JOINTS",
    "SHIN_LENGTH",
    "THIGH_LENGTH",
    "FootIKError",
    "LegChain",
    "leg_chain",
    "solve_chain",
    "solve_legs",
]

HIP_JOINTS = (JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"])
KNEE_JOINTS = (JOINT_INDEX["left_knee"], JOINT_INDEX["right_knee"])
LEG_JOINTS = (*HIP_JOINTS, *KNEE_JOINTS, *ANKLE_JOINTS)
THIGH_LENGTH = np.linalg.norm(REST_OFFSETS[list(KNEE_JOINTS)], axis=-1)  # (2,) left, right
SHIN_LENGTH = np.linalg.norm(REST_OFFSETS[list(ANKLE_JOINTS)], axis=-1)
_HIP_OFF = REST_OFFSETS[list(HIP_JOINTS)]
_KNEE_OFF = REST_OFFSETS[list(KNEE_JOINTS)]
_ANKLE_OFF = REST_OFFSETS[list(ANKLE_JOINTS)]
_TOE_OFF = REST_OFFSETS[list(FOOT_JOINTS)]
HINGE_BLEND = 0.25  # sin of the knee angle from straight where animated plane and body right weigh the same


class FootIKError(ValueError):
    """Input the leg IK or the foot solver cannot use (wrong shapes, non-finite values, a
    state for another number of characters, bad settings)."""


class LegChain:
    """World positions (N, 2, 3) of hips, knees, ankles, toes (left, right) and world rotations
    of the pelvis (N, 3, 3) and of hips, knees, ankles (N, 2, 3, 3): the legs' part of the
    forward kinematics (``sim.body.skeleton.forward_kinematics`` gives the same up to rounding)."""

    __slots__ = ("ankle", "ankle_rot", "hip", "hip_rot", "knee", "knee_rot", "pelvis_rot", "toe")

    def __init__(self, pelvis: NDArray[np.float64], rots: NDArray[np.float64]) -> None:
        g0 = rots[:, 0]
        self.pelvis_rot = g0
        self.hip = pelvis[:, None] + np.einsum("nij,lj->nli", g0, _HIP_OFF)
        self.hip_rot = g0[:, None] @ rots[:, list(HIP_JOINTS)]
        self.knee = self.hip + np.einsum("nlij,lj->nli", self.hip_rot, _KNEE_OFF)
        self.knee_rot = self.hip_rot @ rots[:, list(KNEE_JOINTS)]
        self.ankle = self.knee + np.einsum("nlij,lj->nli", self.knee_rot, _ANKLE_OFF)
        self.ankle_rot = self.knee_rot @ rots[:, list(ANKLE_JOINTS)]
        self.toe = self.ankle + np.einsum("nlij,lj->nli", self.ankle_rot, _TOE_OFF)


def leg_chain(pelvis: NDArray[np.float64], rots: NDArray[np.float64]) -> LegChain:
    """The legs' forward kinematics of poses (pelvis (N, 3), local rotations (N, 22, 3, 3))."""
    return LegChain(np.asarray(pelvis, dtype=np.float64), np.asarray(rots, dtype=np.float64))


Vec3 = tuple[float, float, float]


@njit(cache=True, inline="always")
def _sub(a: Vec3, b: Vec3) -> Vec3:  # pragma: no cover - compiled
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit(cache=True, inline="always")
def _scale(a: Vec3, s: float) -> Vec3:  # pragma: no cover - compiled
    """a * s (s a scalar)."""
    return (a[0] * s, a[1] * s, a[2] * s)


@njit(cache=True, inline="always")
def _div(a: Vec3, s: float) -> Vec3:  # pragma: no cover - compiled
    return (a[0] / s, a[1] / s, a[2] / s)


@njit(cache=True, inline="always")
def _cross(a: Vec3, b: Vec3) -> Vec3:  # pragma: no cover - compiled
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, inline="always")
def _dot3(a: Vec3, b: Vec3) -> float:  # pragma: no cover - compiled
    dot: float = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    return dot


@njit(cache=True, inline="always")
def _norm3(a: Vec3) -> float:  # pragma: no cover - compiled
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@njit(cache=True, inline="always")
def _row(a: NDArray[np.float64]) -> Vec3:  # pragma: no cover - compiled
    return (a[0], a[1], a[2])


@njit(cache=True)
def _perpendicular(v: Vec3) -> Vec3:  # pragma: no cover - compiled
    """A unit vector perpendicular to the unit vector v."""
    k = 0
    for i in range(1, 3):
        if abs(v[i]) < abs(v[k]):
            k = i
    e = (1.0 if k == 0 else 0.0, 1.0 if k == 1 else 0.0, 1.0 if k == 2 else 0.0)
    p = _cross(v, e)
    return _div(p, _norm3(p))


@njit(cache=True)
def _rotation(ax: float, ay: float, az: float, angle: float, r: NDArray[np.float64]) -> None:  # pragma: no cover - compiled
    """r = the rotation matrix about the unit axis (ax, ay, az) by ``angle`` (Rodrigues)."""
    s = math.sin(angle)
    c = math.cos(angle)
    t = 1.0 - c
    r[0, 0] = c + t * ax * ax
    r[0, 1] = t * ax * ay - s * az
    r[0, 2] = t * ax * az + s * ay
    r[1, 0] = t * ax * ay + s * az
    r[1, 1] = c + t * ay * ay
    r[1, 2] = t * ay * az - s * ax
    r[2, 0] = t * ax * az - s * ay
    r[2, 1] = t * ay * az + s * ax
    r[2, 2] = c + t * az * az


@njit(cache=True, inline="always")
def _matmul3(a: NDArray[np.float64], b: NDArray[np.float64], out: NDArray[np.float64]) -> None:  # pragma: no cover - compiled
    """out = a @ b (out may not alias a or b)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]


@njit(cache=True, inline="always")
def _matvec3(a: NDArray[np.float64], v: Vec3) -> Vec3:  # pragma: no cover - compiled
    return (a[0, 0] * v[0] + a[0, 1] * v[1] + a[0, 2] * v[2],
            a[1, 0] * v[0] + a[1, 1] * v[1] + a[1, 2] * v[2],
            a[2, 0] * v[0] + a[2, 1] * v[1] + a[2, 2] * v[2])


@njit(cache=True, inline="always")
def _tmatmul3(a: NDArray[np.float64], b: NDArray[np.float64], out: NDArray[np.float64]) -> None:  # pragma: no cover - compiled
    """out = a.T @ b"""
    for i in range(3):
        for j in range(3):
            out[i, j] = a[0, i] * b[0, j] + a[1, i] * b[1, j] + a[2, i] * b[2, j]


@njit(cache=True)
def _hinge(kh: Vec3, ka: Vec3, e1: Vec3, n: Vec3, b_len: float, cos_knee: float,
           out: NDArray[np.float64]) -> None:  # pragma: no cover - compiled
    """out = the turn about the unit axis n (normal to the thigh kh) that brings the interior
    knee angle between kh and the shin ka to acos(cos_knee), as close as the axis allows."""
    e2 = _cross(n, e1)
    c1 = _dot3(ka, e1)
    c2 = _dot3(ka, e2)
    phi0 = math.atan2(c2, c1)
    in_plane = max(math.hypot(c1, c2), 1e-12)
    phi1 = math.acos(min(max(b_len * cos_knee / in_plane, -1.0), 1.0))
    _rotation(n[0], n[1], n[2], phi1 - phi0, out)


@njit(cache=True, inline="always")
def _swing(a: Vec3, d: Vec3, n: Vec3, out: NDArray[np.float64]) -> None:  # pragma: no cover - compiled
    """out = the swing of the leg about the hip from its direction ``a`` onto the target
    direction ``d`` (unit vectors): the smallest rotation, or, when they are opposite, a half
    turn about the hinge ``n`` (made normal to ``a``)."""
    axis = _cross(a, d)
    s = _norm3(axis)
    c = min(max(_dot3(a, d), -1.0), 1.0)
    if s < 1e-9 and c < 0.0:  # opposite: a half turn about the hinge
        f = _sub(n, _scale(a, _dot3(n, a)))
        fn = _norm3(f)
        axis = _div(f, fn) if fn > 1e-9 else _perpendicular(a)
    else:
        axis = _div(axis, max(s, 1e-12))
    _rotation(axis[0], axis[1], axis[2], math.atan2(s, c), out)


@njit(cache=True)
def _ik_kernel(hip: NDArray[np.float64], knee: NDArray[np.float64], ankle: NDArray[np.float64], pelvis_rot: NDArray[np.float64],
               hip_rot: NDArray[np.float64], knee_rot: NDArray[np.float64], ankle_rot: NDArray[np.float64], target: NDArray[np.float64],
               thigh: NDArray[np.float64], shin: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:  # pragma: no cover - compiled
    """New local rotations (hip, knee, ankle) (M, 3, 3) of M legs putting the ankle on
    ``target`` (M, 3); positions (M, 3), world rotations (M, 3, 3), bone lengths (M,).

    Vectors are tuples and matrices rows of preallocated scratch (no temporary arrays per
    leg); the float operations are those of the array version kept as the test oracle
    (``tests/support/leg_ik_reference.py``), in the same order, so the bits are the same."""
    m_count = hip.shape[0]
    out_hip = np.empty((m_count, 3, 3))
    out_knee = np.empty((m_count, 3, 3))
    out_ankle = np.empty((m_count, 3, 3))
    bend = np.empty((3, 3))
    turn = np.empty((3, 3))
    both = np.empty((3, 3))
    swing = np.empty((3, 3))
    new_hip = np.empty((3, 3))
    new_knee = np.empty((3, 3))
    tmp = np.empty((3, 3))
    for m in range(m_count):
        a_len = thigh[m]
        b_len = shin[m]
        hp, kn, an = _row(hip[m]), _row(knee[m]), _row(ankle[m])
        kh = _sub(hp, kn)
        ka = _sub(an, kn)
        e1 = _div(kh, max(_norm3(kh), 1e-12))
        # hinge: the animated plane's normal, blended towards the thigh's own flexion axis (its
        # local -x, the body's right in the rest pose) as the animated leg straightens (the
        # plane of a nearly straight leg is noise; it flips from frame to frame): equal weights
        # when the knee is 14 degrees from straight
        right = (-hip_rot[m, 0, 0], -hip_rot[m, 1, 0], -hip_rot[m, 2, 0])
        fb = _sub(right, _scale(e1, _dot3(right, e1)))
        fbn = _norm3(fb)
        fb = _div(fb, fbn) if fbn > 1e-6 else _perpendicular(e1)
        n_raw = _cross(kh, ka)
        back = _dot3(n_raw, fb)
        if back < 0.0:  # a knee bent backwards (a defect of some source frames): mirrored forward
            n_raw = _sub(n_raw, _scale(fb, 2.0 * back))
        blend = HINGE_BLEND * a_len * b_len
        nv = (n_raw[0] + blend * fb[0], n_raw[1] + blend * fb[1], n_raw[2] + blend * fb[2])
        n = _div(nv, max(_norm3(nv), 1e-12))
        # reach along the target direction, clamped to what the bones allow
        tv = _sub(_row(target[m]), hp)
        dist = _norm3(tv)
        if dist > 1e-9:
            d = _div(tv, dist)
        else:
            av = _sub(an, hp)
            d = _div(av, max(_norm3(av), 1e-12))
        reach = min(max(dist, abs(a_len - b_len) + 1e-6), a_len + b_len - 1e-6)
        cos_knee = (a_len * a_len + b_len * b_len - reach * reach) / (2.0 * a_len * b_len)
        _hinge(kh, ka, e1, n, b_len, cos_knee, bend)
        ka1 = _matvec3(bend, ka)
        # the blended hinge is not quite normal to the shin, which can leave the knee a little
        # short of straight: a second turn about the bent leg's own plane normal is exact
        n1 = _cross(kh, ka1)
        n1n = _norm3(n1)
        if n1n > 1e-9 * a_len * b_len:
            _hinge(kh, ka1, e1, _div(n1, n1n), b_len, cos_knee, turn)
            _matmul3(turn, bend, both)
            bend[:, :] = both
        bk = _matvec3(bend, ka)
        ankle1 = (kn[0] + bk[0], kn[1] + bk[1], kn[2] + bk[2])
        av = _sub(ankle1, hp)
        a = _div(av, max(_norm3(av), 1e-12))
        _swing(a, d, n, swing)
        _matmul3(swing, hip_rot[m], new_hip)
        _matmul3(bend, knee_rot[m], tmp)
        _matmul3(swing, tmp, new_knee)
        _tmatmul3(pelvis_rot[m], new_hip, out_hip[m])
        _tmatmul3(new_hip, new_knee, out_knee[m])
        _tmatmul3(new_knee, ankle_rot[m], out_ankle[m])
    return out_hip, out_knee, out_ankle


def solve_chain(chain: LegChain, rots: NDArray[np.float64], ankle_targets: NDArray[np.float64], which: NDArray[np.float64]) -> NDArray[np.float64]:
    """``solve_legs`` on poses whose leg chain is already known (no input checks)."""
    out = np.array(rots, dtype=np.float64, copy=True)
    if not which.any():
        return out
    ci, leg = np.nonzero(which)
    cols = np.array(LEG_JOINTS).reshape(3, 2)[:, leg]  # (3 joints, M): hip, knee, ankle
    new = _ik_kernel(
        np.ascontiguousarray(chain.hip[ci, leg]), np.ascontiguousarray(chain.knee[ci, leg]),
        np.ascontiguousarray(chain.ankle[ci, leg]), np.ascontiguousarray(chain.pelvis_rot[ci]),
        np.ascontiguousarray(chain.hip_rot[ci, leg]), np.ascontiguousarray(chain.knee_rot[ci, leg]),
        np.ascontiguousarray(chain.ankle_rot[ci, leg]), np.ascontiguousarray(ankle_targets[ci, leg]),
        THIGH_LENGTH[leg], SHIN_LENGTH[leg])
    for k in range(3):
        out[ci, cols[k]] = new[k]
    return out


def solve_legs(pelvis: NDArray[np.float64], rots: NDArray[np.float64], ankle_targets: NDArray[np.float64],
               which: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
    """Local rotations (N, 22, 3, 3) with the ankles of the legs ``which`` (N, 2) bool
    (default all) on ``ankle_targets`` (N, 2, 3) (world, m; left, right), the feet keeping their
    world orientation; other joints and legs keep their input rotations exactly.

    Raises ``FootIKError`` for wrong shapes or non-finite input."""
    pelvis = np.asarray(pelvis, dtype=np.float64)
    rots = np.asarray(rots, dtype=np.float64)
    targets = np.asarray(ankle_targets, dtype=np.float64)
    n = len(pelvis)
    if pelvis.shape != (n, 3) or rots.shape != (n, NUM_JOINTS, 3, 3) or targets.shape != (n, 2, 3):
        raise FootIKError(
            f"need pelvis (N, 3), rots (N, {NUM_JOINTS}, 3, 3), ankle_targets (N, 2, 3); got "
            f"{pelvis.shape}, {rots.shape}, {targets.shape}")
    if not (np.isfinite(pelvis).all() and np.isfinite(rots).all() and np.isfinite(targets).all()):
        raise FootIKError("pelvis, rotations and ankle targets must be finite")
    mask = np.ones((n, 2), dtype=bool) if which is None else np.asarray(which, dtype=bool).reshape(n, 2)
    return solve_chain(LegChain(pelvis, rots), rots, targets, mask)

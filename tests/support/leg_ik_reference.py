"""The leg IK kernel as it was written with small numpy arrays: the oracle of the compiled
``storyteller.sim.body.leg_ik._ik_kernel``, which does the same float operations on scalars (no temporary
arrays). ``tests/sim/body/test_foot_ik.py`` checks both give the same bits, including the degenerate
branches (a target on the hip, a straight leg, a knee bent backwards). Not used by the simulation.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from storyteller.sim.body.leg_ik import HINGE_BLEND


@njit(cache=True)
def _rotation(ax: float, ay: float, az: float, angle: float) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """Rotation matrix about the unit axis (ax, ay, az) by ``angle`` (Rodrigues)."""
    s = math.sin(angle)
    c = math.cos(angle)
    t = 1.0 - c
    r = np.empty((3, 3))
    r[0, 0] = c + t * ax * ax
    r[0, 1] = t * ax * ay - s * az
    r[0, 2] = t * ax * az + s * ay
    r[1, 0] = t * ax * ay + s * az
    r[1, 1] = c + t * ay * ay
    r[1, 2] = t * ay * az - s * ax
    r[2, 0] = t * ax * az - s * ay
    r[2, 1] = t * ay * az + s * ax
    r[2, 2] = c + t * az * az
    return r


@njit(cache=True)
def _cross(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:  # pragma: no cover - compiled
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@njit(cache=True)
def _dot3(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:  # pragma: no cover - compiled
    dot: float = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    return dot


@njit(cache=True)
def _norm3(a: NDArray[np.float64]) -> float:  # pragma: no cover - compiled
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@njit(cache=True)
def _perpendicular(v: NDArray[np.float64]) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """A unit vector perpendicular to the unit vector v."""
    k = 0
    for i in range(1, 3):
        if abs(v[i]) < abs(v[k]):
            k = i
    e = np.zeros(3)
    e[k] = 1.0
    p = _cross(v, e)
    return p / _norm3(p)


@njit(cache=True)
def _matmul3(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:  # pragma: no cover - compiled
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]
    return out


@njit(cache=True)
def _matvec3(a: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:  # pragma: no cover - compiled
    return np.array([a[0, 0] * v[0] + a[0, 1] * v[1] + a[0, 2] * v[2],
                     a[1, 0] * v[0] + a[1, 1] * v[1] + a[1, 2] * v[2],
                     a[2, 0] * v[0] + a[2, 1] * v[1] + a[2, 2] * v[2]])


@njit(cache=True)
def _tmatmul3(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """a.T @ b"""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = a[0, i] * b[0, j] + a[1, i] * b[1, j] + a[2, i] * b[2, j]
    return out


@njit(cache=True)
def _hinge(kh: NDArray[np.float64], ka: NDArray[np.float64], e1: NDArray[np.float64], n: NDArray[np.float64], b_len: float,
           cos_knee: float) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """The turn about the unit axis n (normal to the thigh kh) that brings the interior knee
    angle between kh and the shin ka to acos(cos_knee), as close as the axis allows."""
    e2 = _cross(n, e1)
    c1 = _dot3(ka, e1)
    c2 = _dot3(ka, e2)
    phi0 = math.atan2(c2, c1)
    in_plane = max(math.hypot(c1, c2), 1e-12)
    phi1 = math.acos(min(max(b_len * cos_knee / in_plane, -1.0), 1.0))
    return _rotation(n[0], n[1], n[2], phi1 - phi0)


@njit(cache=True)
def ik_kernel_arrays(hip: NDArray[np.float64], knee: NDArray[np.float64], ankle: NDArray[np.float64], pelvis_rot: NDArray[np.float64],
               hip_rot: NDArray[np.float64], knee_rot: NDArray[np.float64], ankle_rot: NDArray[np.float64], target: NDArray[np.float64],
               thigh: NDArray[np.float64], shin: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:  # pragma: no cover - compiled
    """New local rotations (hip, knee, ankle) (M, 3, 3) of M legs putting the ankle on
    ``target`` (M, 3); positions (M, 3), world rotations (M, 3, 3), bone lengths (M,)."""
    m_count = hip.shape[0]
    out_hip = np.empty((m_count, 3, 3))
    out_knee = np.empty((m_count, 3, 3))
    out_ankle = np.empty((m_count, 3, 3))
    for m in range(m_count):
        a_len = thigh[m]
        b_len = shin[m]
        kh = hip[m] - knee[m]
        ka = ankle[m] - knee[m]
        e1 = kh / max(_norm3(kh), 1e-12)
        # hinge: the animated plane's normal, blended towards the thigh's own flexion axis (its
        # local -x, the body's right in the rest pose) as the animated leg straightens (the
        # plane of a nearly straight leg is noise; it flips from frame to frame): equal weights
        # when the knee is 14 degrees from straight
        right = np.array([-hip_rot[m, 0, 0], -hip_rot[m, 1, 0], -hip_rot[m, 2, 0]])
        fb = right - _dot3(right, e1) * e1
        fbn = _norm3(fb)
        fb = fb / fbn if fbn > 1e-6 else _perpendicular(e1)
        n_raw = _cross(kh, ka)
        back = _dot3(n_raw, fb)
        if back < 0.0:  # a knee bent backwards (a defect of some source frames): mirrored forward
            n_raw = n_raw - 2.0 * back * fb
        nv = n_raw + (HINGE_BLEND * a_len * b_len) * fb
        n = nv / max(_norm3(nv), 1e-12)
        # reach along the target direction, clamped to what the bones allow
        tv = target[m] - hip[m]
        dist = _norm3(tv)
        if dist > 1e-9:
            d = tv / dist
        else:
            av = ankle[m] - hip[m]
            d = av / max(_norm3(av), 1e-12)
        reach = min(max(dist, abs(a_len - b_len) + 1e-6), a_len + b_len - 1e-6)
        cos_knee = (a_len * a_len + b_len * b_len - reach * reach) / (2.0 * a_len * b_len)
        bend = _hinge(kh, ka, e1, n, b_len, cos_knee)
        ka1 = _matvec3(bend, ka)
        # the blended hinge is not quite normal to the shin, which can leave the knee a little
        # short of straight: a second turn about the bent leg's own plane normal is exact
        n1 = _cross(kh, ka1)
        n1n = _norm3(n1)
        if n1n > 1e-9 * a_len * b_len:
            bend = _matmul3(_hinge(kh, ka1, e1, n1 / n1n, b_len, cos_knee), bend)
        ankle1 = knee[m] + _matvec3(bend, ka)
        av = ankle1 - hip[m]
        a = av / max(_norm3(av), 1e-12)
        # swing the leg about the hip onto the target direction (smallest rotation)
        axis = _cross(a, d)
        s = _norm3(axis)
        c = min(max(_dot3(a, d), -1.0), 1.0)
        if s < 1e-9 and c < 0.0:  # opposite: a half turn about the hinge
            f = n - _dot3(n, a) * a
            fn = _norm3(f)
            axis = f / fn if fn > 1e-9 else _perpendicular(a)
        else:
            axis = axis / max(s, 1e-12)
        swing = _rotation(axis[0], axis[1], axis[2], math.atan2(s, c))
        new_hip = _matmul3(swing, hip_rot[m])
        new_knee = _matmul3(swing, _matmul3(bend, knee_rot[m]))
        out_hip[m] = _tmatmul3(pelvis_rot[m], new_hip)
        out_knee[m] = _tmatmul3(new_hip, new_knee)
        out_ankle[m] = _tmatmul3(new_knee, ankle_rot[m])
    return out_hip, out_knee, out_ankle

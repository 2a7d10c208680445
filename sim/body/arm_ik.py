"""Analytic two-bone IK of the arms (shoulder-elbow-wrist) on the 22-joint skeleton.

``solve_arms(pelvis, rots, side, targets, weights)`` moves one wrist per character towards a
world target and returns new local rotations: the wrist goes to ``wrist + weight * (target -
wrist)`` (``weight`` 0: the pose as animated, exactly; 1: on the target), the elbow stays on
the side the animation bent it to (the animated elbow's offset from the shoulder-target line
is the pole; a straight animated arm bends its elbow down and out), the elbow's interior angle
comes from the law of cosines. The upper arm and then the forearm turn by the smallest
rotation onto their new directions; the hand keeps its local rotation (it follows the forearm).
A target out of reach is clamped to the arm's length along the shoulder-target line (the arm
stretched towards it). Collars, spine, pelvis and legs are never touched.

The legs' counterpart is ``storyteller.sim.body.leg_ik`` (a compiled kernel: it runs for every leg of a
crowd every frame); the arms are solved only for the few characters whose hands work on an
object in a frame, so this is plain numpy, batched over them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import JOINT_INDEX, NUM_JOINTS, REST_OFFSETS, forward_kinematics

__all__ = ["ARM_LENGTH", "COLLAR_JOINTS", "ELBOW_JOINTS", "SHOULDER_JOINTS", "WRIST_JOINTS", "ArmIKError",
           "solve_arms"]

COLLAR_JOINTS = (JOINT_INDEX["left_collar"], JOINT_INDEX["right_collar"])
SHOULDER_JOINTS = (JOINT_INDEX["left_shoulder"], JOINT_INDEX["right_shoulder"])
ELBOW_JOINTS = (JOINT_INDEX["left_elbow"], JOINT_INDEX["right_elbow"])
WRIST_JOINTS = (JOINT_INDEX["left_wrist"], JOINT_INDEX["right_wrist"])
_UPPER = np.linalg.norm(REST_OFFSETS[list(ELBOW_JOINTS)], axis=-1)  # (2,) left, right
_FORE = np.linalg.norm(REST_OFFSETS[list(WRIST_JOINTS)], axis=-1)
ARM_LENGTH = _UPPER + _FORE
"""Shoulder to wrist, arm straight (metres; left, right)."""


class ArmIKError(ValueError):
    """Input the arm IK cannot use (wrong shapes, non-finite values, a side other than 0 / 1)."""


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.asarray(v / np.maximum(n, 1e-12))


def _rotation_between(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """The smallest rotations (M, 3, 3) turning directions ``a`` onto ``b`` (M, 3) (Rodrigues);
    identity where they agree; about any perpendicular axis where they are opposite."""
    a, b = _unit(a), _unit(b)
    axis = np.cross(a, b)
    s = np.linalg.norm(axis, axis=-1)
    c = np.clip(np.einsum("mi,mi->m", a, b), -1.0, 1.0)
    flip = (s < 1e-9) & (c < 0.0)
    if flip.any():  # opposite: any axis perpendicular to a
        other = np.where(np.abs(a[flip, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        axis[flip] = np.cross(a[flip], other)
        s[flip] = np.linalg.norm(axis[flip], axis=-1)
    k = axis / np.maximum(s, 1e-12)[:, None]
    angle = np.arctan2(s, c)
    kx = np.zeros((len(a), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    kx[:, 1, 0], kx[:, 2, 0], kx[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    sa, ca = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.asarray(np.eye(3) + sa * kx + (1.0 - ca) * (kx @ kx))


def solve_arms(pelvis: NDArray[np.float64], rots: NDArray[np.float64], side: NDArray[np.int64],
               targets: NDArray[np.float64], weights: NDArray[np.float64]) -> NDArray[np.float64]:
    """Local rotations (M, 22, 3, 3) with the wrist ``side`` (M,) (0 left, 1 right) of each pose
    (pelvis (M, 3) world, local rotations (M, 22, 3, 3), joint 0 in world) moved ``weights``
    (M,) in [0, 1] of the way to ``targets`` (M, 3) (world, metres); see the module docstring.
    Poses with weight 0 come back unchanged. Raises ``ArmIKError`` for wrong input."""
    pelvis = np.asarray(pelvis, dtype=np.float64)
    rots = np.asarray(rots, dtype=np.float64)
    side = np.asarray(side).astype(np.int64)
    targets = np.asarray(targets, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    m = len(pelvis)
    if (pelvis.shape != (m, 3) or rots.shape != (m, NUM_JOINTS, 3, 3) or side.shape != (m,)
            or targets.shape != (m, 3) or weights.shape != (m,)):
        raise ArmIKError(f"need pelvis (M, 3), rots (M, {NUM_JOINTS}, 3, 3), side (M,), targets (M, 3), weights (M,); "
                         f"got {pelvis.shape}, {rots.shape}, {side.shape}, {targets.shape}, {weights.shape}")
    if not (np.isfinite(pelvis).all() and np.isfinite(rots).all() and np.isfinite(targets).all()
            and np.isfinite(weights).all()):
        raise ArmIKError("pelvis, rotations, targets and weights must be finite")
    if ((side != 0) & (side != 1)).any():
        raise ArmIKError("side must be 0 (left) or 1 (right)")
    out = np.array(rots, copy=True)
    act = np.flatnonzero(np.clip(weights, 0.0, 1.0) > 0.0)
    if len(act) == 0:
        return out
    s = side[act]
    w = np.clip(weights[act], 0.0, 1.0)[:, None]
    pos, glob = forward_kinematics(rots[act], pelvis[act])
    rows = np.arange(len(act))
    col, sh, el, wr = (np.array(j)[s] for j in (COLLAR_JOINTS, SHOULDER_JOINTS, ELBOW_JOINTS, WRIST_JOINTS))
    S, E, W = pos[rows, sh], pos[rows, el], pos[rows, wr]
    Rc, Rs, Re = glob[rows, col], glob[rows, sh], glob[rows, el]
    a, b = _UPPER[s], _FORE[s]
    T = W + w * (targets[act] - W)
    st = T - S
    dist = np.linalg.norm(st, axis=-1)
    u = np.where((dist > 1e-9)[:, None], st / np.maximum(dist, 1e-12)[:, None], _unit(W - S))
    d = np.clip(dist, np.abs(a - b) + 1e-4, a + b - 1e-4)
    # pole: the animated elbow's side of the shoulder-target line (else down, a little out)
    se = E - S
    v = se - np.einsum("mi,mi->m", se, u)[:, None] * u
    vn = np.linalg.norm(v, axis=-1)
    straight = vn < 1e-3
    if straight.any():
        down = np.array([0.0, 0.0, -1.0])
        alt = down - (u[straight] @ down)[:, None] * u[straight]
        alt_n = np.linalg.norm(alt, axis=-1)
        alt[alt_n < 1e-6] = np.cross(u[straight][alt_n < 1e-6], [1.0, 0.0, 0.0])
        v[straight] = alt
    v = _unit(v)
    cos_a = np.clip((a * a + d * d - b * b) / (2.0 * a * d), -1.0, 1.0)
    sin_a = np.sqrt(1.0 - cos_a * cos_a)
    E1 = S + a[:, None] * (cos_a[:, None] * u + sin_a[:, None] * v)
    W1 = S + d[:, None] * u
    R1 = _rotation_between(se, E1 - S)
    fore = np.einsum("mij,mj->mi", R1, W - E)
    R2 = _rotation_between(fore, W1 - E1)
    new_s = R1 @ Rs
    new_e = R2 @ R1 @ Re
    out[act, sh] = np.swapaxes(Rc, -1, -2) @ new_s
    out[act, el] = np.swapaxes(new_s, -1, -2) @ new_e
    return out

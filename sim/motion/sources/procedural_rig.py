"""Turn per-frame body targets into SMPL-X joint rotations (the procedural clips' solver).

A generator describes a clip by *targets* in the z-up world: the root's ground point and
heading, the pelvis offset and tilt, spine and head angles, where each toe joint touches the
ground (with foot yaw and heel lift), and where each wrist should be. ``solve_body`` places
the pelvis and spine directly and reaches the toes and wrists with analytic two-bone IK
(knees bend forward, elbows down and back), returning local rotations for forward
kinematics. Every operation is vectorised over frames.

Angles are radians. Body-frame angles follow the skeleton's body frame (x left, y up, z
forward): ``pitch`` leans forward, ``yaw`` turns left, ``roll`` tilts toward the right side.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from storyteller.sim.body.skeleton import JOINT_INDEX, NUM_JOINTS, PARENTS, REST_OFFSETS, heading_to_root

J = JOINT_INDEX
LEG_CHAINS = ((J["left_hip"], J["left_knee"], J["left_ankle"], J["left_foot"]),
              (J["right_hip"], J["right_knee"], J["right_ankle"], J["right_foot"]))
ARM_CHAINS = ((J["left_shoulder"], J["left_elbow"], J["left_wrist"]),
              (J["right_shoulder"], J["right_elbow"], J["right_wrist"]))
SPINE = (J["spine1"], J["spine2"], J["spine3"])

THIGH = float(np.linalg.norm(REST_OFFSETS[J["left_knee"]]))
SHIN = float(np.linalg.norm(REST_OFFSETS[J["left_ankle"]]))
UPPER_ARM = float(np.linalg.norm(REST_OFFSETS[J["left_elbow"]]))
FOREARM = float(np.linalg.norm(REST_OFFSETS[J["left_wrist"]]))
LEG_LENGTH = THIGH + SHIN  # hip to ankle, metres
# Height of the toe joint above the floor when the foot is flat (rest pose).
TOE_HEIGHT = float(REST_OFFSETS[:1, 1].sum() + sum(REST_OFFSETS[j, 1] for j in LEG_CHAINS[0]))
ANKLE_HEIGHT = TOE_HEIGHT - float(REST_OFFSETS[J["left_foot"], 1])
STANDING_PELVIS_HEIGHT = float(REST_OFFSETS[0, 1])
# Shoulder height above the pelvis in the rest pose (metres).
SHOULDER_ABOVE_PELVIS = float(
    sum(REST_OFFSETS[j, 1] for j in (J["spine1"], J["spine2"], J["spine3"], J["left_collar"], J["left_shoulder"]))
)
SHOULDER_HALF_WIDTH = float(REST_OFFSETS[J["left_collar"], 0] + REST_OFFSETS[J["left_shoulder"], 0])


def body_euler(angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """(..., 3) [pitch, yaw, roll] in the body frame -> (..., 3, 3) = Ry(yaw) Rx(pitch) Rz(roll)."""
    a = np.asarray(angles, dtype=np.float64)
    flat = a.reshape(-1, 3)
    m = Rotation.from_euler("YXZ", flat[:, [1, 0, 2]]).as_matrix()
    return m.reshape(*a.shape[:-1], 3, 3)


def rot_z(theta: NDArray[np.float64]) -> NDArray[np.float64]:
    """(...,) angles -> (..., 3, 3) rotations about the world z axis."""
    t = np.asarray(theta, dtype=np.float64)
    c, s = np.cos(t), np.sin(t)
    m = np.zeros((*t.shape, 3, 3))
    m[..., 0, 0], m[..., 0, 1], m[..., 1, 0], m[..., 1, 1], m[..., 2, 2] = c, -s, s, c, 1.0
    return m


def char_to_world(root_xy: NDArray[np.float64], heading: NDArray[np.float64], local: NDArray[np.float64]) -> NDArray[np.float64]:
    """Points (..., 3) in the character frame (x forward, y left, z up from the floor) -> world."""
    w: NDArray[np.float64] = np.einsum("...ij,...j->...i", rot_z(heading), local)
    w[..., 0] += root_xy[..., 0]
    w[..., 1] += root_xy[..., 1]
    return w


def _normalize(v: NDArray[np.float64], fallback: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    n: NDArray[np.float64] = np.linalg.norm(v, axis=-1, keepdims=True)
    out = v / np.maximum(n, 1e-12)
    if fallback is not None:
        out = np.where(n > 1e-9, out, fallback)
    return out


def _frame(u: NDArray[np.float64], s: NDArray[np.float64]) -> NDArray[np.float64]:
    """Orthonormal frame (..., 3, 3) with columns u, s orthogonalised to u, u x s."""
    u = _normalize(u)
    s = s - np.sum(s * u, axis=-1, keepdims=True) * u
    s = _normalize(s)
    return np.stack([u, s, np.cross(u, s)], axis=-1)


def _align(u0: NDArray[np.float64], s0: NDArray[np.float64], u1: NDArray[np.float64], s1: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation taking direction u0 to u1 exactly, and side vector s0 as close as possible to s1."""
    f0 = _frame(np.broadcast_to(u0, u1.shape), np.broadcast_to(s0, s1.shape))
    return _frame(u1, s1) @ np.swapaxes(f0, -1, -2)


def two_bone_ik(
    root: NDArray[np.float64], target: NDArray[np.float64], l1: float, l2: float, pole: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Analytic two-bone IK. Returns (middle joint, reached end, hinge side vector), each (..., 3).

    The middle joint bends toward ``pole``; targets beyond reach are pulled in along the line
    to 99.9 % of full extension (so the end may miss a too-far target).
    """
    d = target - root
    dist = np.linalg.norm(d, axis=-1, keepdims=True)
    direction = _normalize(d, np.array([0.0, 0.0, -1.0]))
    dist = np.clip(dist, abs(l1 - l2) + 1e-4, (l1 + l2) * 0.999)
    x = (l1 * l1 - l2 * l2 + dist * dist) / (2 * dist)
    h = np.sqrt(np.maximum(l1 * l1 - x * x, 0.0))
    perp = pole - np.sum(pole * direction, axis=-1, keepdims=True) * direction
    alt = np.cross(direction, np.array([0.0, 1.0, 0.0]))
    perp = _normalize(perp, _normalize(alt, np.array([1.0, 0.0, 0.0])))
    middle = root + direction * x + perp * h
    end = root + direction * dist
    side = _normalize(np.cross(perp, direction))
    return middle, end, side


@dataclass(frozen=True)
class BodyTargets:
    """Per-frame targets of one clip (F frames). Character frame: x forward, y left, z up.

    root_xy (F,2) world ground point of the root; heading (F,) world yaw of the character.
    pelvis_offset (F,3): pelvis position in the character frame (z = height above floor).
    pelvis_tilt, spine, head (F,3): [pitch, yaw, roll] of the pelvis, of the whole spine
    (spread over spine1-3) and of neck + head (spread over both).
    toes (F,2,3): world position of the left/right toe joint; foot_yaw (F,2) world yaw of
    each foot; heel_lift (F,2) heel-raise angle (pivot about the toe joint).
    hands (F,2,3): left/right wrist targets in the character frame relative to the shoulder
    joint; elbow_pole (F,2,3) direction (character frame) the elbows point to.
    """

    root_xy: NDArray[np.float64]
    heading: NDArray[np.float64]
    pelvis_offset: NDArray[np.float64]
    pelvis_tilt: NDArray[np.float64]
    spine: NDArray[np.float64]
    head: NDArray[np.float64]
    toes: NDArray[np.float64]
    foot_yaw: NDArray[np.float64]
    heel_lift: NDArray[np.float64]
    hands: NDArray[np.float64]
    elbow_pole: NDArray[np.float64]


def pelvis_height_limit(t: BodyTargets, reach: float = 0.985) -> NDArray[np.float64]:
    """Highest pelvis height (F,) per frame at which both ankles reach their targets."""
    pelvis_rot = heading_to_root(t.heading) @ body_euler(t.pelvis_tilt)
    pelvis_xy = char_to_world(t.root_xy, t.heading, t.pelvis_offset * np.array([1.0, 1.0, 0.0]))
    limit = np.full(t.heading.shape, np.inf)
    for side, (hip, _, _, toe) in enumerate(LEG_CHAINS):
        hip_off = np.einsum("fij,j->fi", pelvis_rot, REST_OFFSETS[hip])
        ankle = _ankle_from_toe(t, side, toe)
        dxy = np.linalg.norm(pelvis_xy[:, :2] + hip_off[:, :2] - ankle[:, :2], axis=-1)
        r = reach * LEG_LENGTH
        dz = np.sqrt(np.maximum(r * r - dxy * dxy, 0.0))
        limit = np.minimum(limit, ankle[:, 2] + dz - hip_off[:, 2])
    return limit


def _foot_rotation(t: BodyTargets, side: int) -> NDArray[np.float64]:
    pitch = np.stack([t.heel_lift[:, side], np.zeros_like(t.heel_lift[:, side]),
                      np.zeros_like(t.heel_lift[:, side])], axis=-1)
    return heading_to_root(t.foot_yaw[:, side]) @ body_euler(pitch)


def _ankle_from_toe(t: BodyTargets, side: int, toe: int) -> NDArray[np.float64]:
    rf = _foot_rotation(t, side)
    offsets: NDArray[np.float64] = np.einsum("fij,j->fi", rf, REST_OFFSETS[toe])
    return t.toes[:, side] - offsets


def solve_body(t: BodyTargets) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Solve a clip's targets. Returns (local rotations (F,22,3,3), pelvis positions (F,3))."""
    n = t.heading.shape[0]
    glob = np.zeros((n, NUM_JOINTS, 3, 3))
    pos = np.zeros((n, NUM_JOINTS, 3))
    glob[:] = np.eye(3)
    pelvis_rot = heading_to_root(t.heading) @ body_euler(t.pelvis_tilt)
    pelvis = char_to_world(t.root_xy, t.heading, t.pelvis_offset)
    glob[:, 0], pos[:, 0] = pelvis_rot, pelvis

    def place(j: int, local: NDArray[np.float64] | None) -> None:
        p = PARENTS[j]
        pos[:, j] = pos[:, p] + np.einsum("fij,j->fi", glob[:, p], REST_OFFSETS[j])
        glob[:, j] = glob[:, p] if local is None else glob[:, p] @ local

    spine_local = body_euler(t.spine / 3.0)
    head_local = body_euler(t.head / 2.0)
    for j in SPINE:
        place(j, spine_local)
    place(J["neck"], head_local)
    place(J["head"], head_local)
    place(J["left_collar"], None)
    place(J["right_collar"], None)

    forward = np.stack([np.cos(t.heading), np.sin(t.heading), np.zeros(n)], axis=-1)
    for side, (hip, knee, ankle, toe) in enumerate(LEG_CHAINS):
        place(hip, None)
        foot_rot = _foot_rotation(t, side)
        ankle_target = _ankle_from_toe(t, side, toe)
        foot_fwd = np.stack([np.cos(t.foot_yaw[:, side]), np.sin(t.foot_yaw[:, side]), np.zeros(n)], -1)
        pole = _normalize(foot_fwd + forward)
        knee_p, ankle_p, side_v = two_bone_ik(pos[:, hip], ankle_target, THIGH, SHIN, pole)
        x_axis = np.array([1.0, 0.0, 0.0])
        glob[:, hip] = _align(REST_OFFSETS[knee], x_axis, knee_p - pos[:, hip], side_v)
        glob[:, knee] = _align(REST_OFFSETS[ankle], x_axis, ankle_p - knee_p, side_v)
        pos[:, knee], pos[:, ankle] = knee_p, ankle_p
        glob[:, ankle] = foot_rot
        pos[:, toe] = ankle_p + np.einsum("fij,j->fi", foot_rot, REST_OFFSETS[toe])
        glob[:, toe] = foot_rot

    rz = rot_z(t.heading)
    for side, (shoulder, elbow, wrist) in enumerate(ARM_CHAINS):
        place(shoulder, None)
        target = pos[:, shoulder] + np.einsum("fij,fj->fi", rz, t.hands[:, side])
        pole = np.einsum("fij,fj->fi", rz, t.elbow_pole[:, side])
        elbow_p, wrist_p, side_v = two_bone_ik(pos[:, shoulder], target, UPPER_ARM, FOREARM, pole)
        s0 = np.array([0.0, -1.0, 0.0]) if side == 0 else np.array([0.0, 1.0, 0.0])
        glob[:, shoulder] = _align(REST_OFFSETS[elbow], s0, elbow_p - pos[:, shoulder], side_v)
        glob[:, elbow] = _align(REST_OFFSETS[wrist], s0, wrist_p - elbow_p, side_v)
        glob[:, wrist] = glob[:, elbow]

    local = np.empty_like(glob)
    local[:, 0] = glob[:, 0]
    for j in range(1, NUM_JOINTS):
        local[:, j] = np.swapaxes(glob[:, PARENTS[j]], -1, -2) @ glob[:, j]
    return local, pelvis

"""The 22-joint SMPL-X body skeleton: names, parents, our own rest offsets, forward kinematics.

Frames: the skeleton's *body frame* follows SMPL-X (y up, the body faces +z, its left is +x).
The world is z up. ``BODY_TO_WORLD`` (+90 degrees about x) stands a body upright in the world;
it then faces world -y. A character whose *heading* (the world xy direction it faces) has
angle ``theta`` gets the root rotation ``heading_to_root(theta) = Rz(theta + pi/2) @ BODY_TO_WORLD``.

Forward kinematics takes the pelvis position directly (``root_position``); ``REST_OFFSETS[0]``
is the pelvis height above the floor in the rest pose (body frame). Exports convert to the
SMPL ``transl`` convention (pelvis = template pelvis joint + transl).

Rotations are 3x3 matrices in numpy arrays; axis-angle conversion uses scipy.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

JOINT_NAMES: tuple[str, ...] = (
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
)
NUM_JOINTS = len(JOINT_NAMES)
PARENTS: tuple[int, ...] = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19)
JOINT_INDEX: dict[str, int] = {name: i for i, name in enumerate(JOINT_NAMES)}

# Rest offsets of each joint from its parent, in the body frame (metres). Our own
# proportions for an adult of about 1.72 m; the pelvis offset is its height above the floor
# when standing.
REST_OFFSETS = np.array(
    [
        [0.000, 0.930, 0.000],  # pelvis (from the floor origin)
        [0.085, -0.080, -0.010],  # left_hip
        [-0.085, -0.080, -0.010],  # right_hip
        [0.000, 0.110, -0.020],  # spine1
        [0.010, -0.385, 0.005],  # left_knee
        [-0.010, -0.385, 0.005],  # right_knee
        [0.000, 0.135, 0.010],  # spine2
        [-0.005, -0.400, -0.035],  # left_ankle
        [0.005, -0.400, -0.035],  # right_ankle
        [0.000, 0.055, 0.025],  # spine3
        [0.015, -0.055, 0.120],  # left_foot
        [-0.015, -0.055, 0.120],  # right_foot
        [0.000, 0.215, -0.030],  # neck
        [0.075, 0.120, -0.005],  # left_collar
        [-0.075, 0.120, -0.005],  # right_collar
        [0.000, 0.090, 0.050],  # head
        [0.110, 0.040, -0.015],  # left_shoulder
        [-0.110, 0.040, -0.015],  # right_shoulder
        [0.260, -0.010, -0.020],  # left_elbow
        [-0.260, -0.010, -0.020],  # right_elbow
        [0.250, 0.005, 0.000],  # left_wrist
        [-0.250, 0.005, 0.000],  # right_wrist
    ],
    dtype=np.float64,
)
assert REST_OFFSETS.shape == (NUM_JOINTS, 3)

# Body frame (y up, facing +z) -> world frame (z up): +90 degrees about x.
BODY_TO_WORLD = Rotation.from_euler("x", 90, degrees=True).as_matrix()


def rest_positions() -> NDArray[np.float64]:
    """Joint positions (22, 3) of the rest pose in the body frame (feet near y = 0)."""
    return forward_kinematics(np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3)), REST_OFFSETS[0])[0]


def forward_kinematics(
    local_rotations: NDArray[np.float64], root_position: NDArray[np.float64], offsets: NDArray[np.float64] = REST_OFFSETS
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Batched FK.

    local_rotations: (..., 22, 3, 3), each joint's rotation relative to its parent; joint 0's is
    the root rotation in the output frame. root_position: (..., 3), the pelvis position.
    Returns (positions (..., 22, 3), global rotations (..., 22, 3, 3)).
    """
    local_rotations = np.asarray(local_rotations, dtype=np.float64)
    root_position = np.asarray(root_position, dtype=np.float64)
    batch = local_rotations.shape[:-3]
    # one 4x4 rigid transform per joint (rotation + offset from the parent), chained by one
    # matrix product per joint (half the numpy calls of separate rotation / position updates)
    t = np.zeros((*batch, NUM_JOINTS, 4, 4))
    t[..., :3, :3] = local_rotations
    t[..., 1:, :3, 3] = np.asarray(offsets, dtype=np.float64)[..., 1:, :]
    t[..., 0, :3, 3] = root_position
    t[..., 3, 3] = 1.0
    for j in range(1, NUM_JOINTS):
        np.matmul(t[..., PARENTS[j], :, :], t[..., j, :, :], out=t[..., j, :, :])
    return np.ascontiguousarray(t[..., :3, 3]), np.ascontiguousarray(t[..., :3, :3])


def heading_to_root(theta: float | NDArray[np.float64]) -> NDArray[np.float64]:
    """Root rotation(s) (..., 3, 3) that stand the body upright facing world angle ``theta``."""
    theta = np.asarray(theta, dtype=np.float64)
    rz = Rotation.from_euler("z", (theta + np.pi / 2).reshape(-1, 1)).as_matrix()
    return (rz @ BODY_TO_WORLD).reshape(*theta.shape, 3, 3)


def axis_angle_to_matrix(axis_angle: NDArray[np.float64]) -> NDArray[np.float64]:
    """(..., 3) axis-angle -> (..., 3, 3) rotation matrices."""
    aa = np.asarray(axis_angle, dtype=np.float64)
    return Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(*aa.shape[:-1], 3, 3)


def matrix_to_axis_angle(matrix: NDArray[np.float64]) -> NDArray[np.float64]:
    """(..., 3, 3) rotation matrices -> (..., 3) axis-angle."""
    m = np.asarray(matrix, dtype=np.float64)
    return Rotation.from_matrix(m.reshape(-1, 3, 3)).as_rotvec().reshape(*m.shape[:-2], 3)

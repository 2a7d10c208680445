"""Inertialization: carry the pose difference at a clip switch as an offset that decays.

At a switch from a source pose to a destination pose the offset is (source - destination)
for positions and log(source * destination^-1) for rotations, with matching velocity
offsets; the offset then decays to zero with a critically damped spring, so the output is
continuous in position and velocity. Pure functions of their inputs and ``dt`` (seconds);
``halflife`` is the time (s) for the offset to halve.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

LN2 = float(np.log(2.0))


def decay_spring(x: NDArray[np.float64], v: NDArray[np.float64], halflife: float, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Exact critically damped decay of offset ``x`` with velocity ``v`` toward zero."""
    y = 2.0 * LN2 / max(halflife, 1e-5) / 2.0
    j1 = v + x * y
    eydt = np.exp(-y * dt)
    return eydt * (x + j1 * dt), eydt * (v - j1 * y * dt)


def rotation_log(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """(..., 3, 3) rotation matrices -> rotation vectors (..., 3).

    The inputs are products of rotation matrices (orthonormal to rounding), so scipy's
    projection onto SO(3) (an SVD per matrix, ~6x the cost) is skipped (``assume_valid``)."""
    return Rotation.from_matrix(m.reshape(-1, 3, 3), assume_valid=True).as_rotvec().reshape(*m.shape[:-2], 3)


def rotation_exp(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation vectors (..., 3) -> (..., 3, 3)."""
    return Rotation.from_rotvec(v.reshape(-1, 3)).as_matrix().reshape(*v.shape[:-1], 3, 3)


def angular_velocity(r0: NDArray[np.float64], r1: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
    """Angular velocity (..., 3) rad/s (world-of-parent axes) taking r0 to r1 in ``dt``."""
    return rotation_log(r1 @ np.swapaxes(r0, -1, -2)) / dt


def transition_offsets(
    offset_rot: NDArray[np.float64], offset_ang_vel: NDArray[np.float64], src_rot: NDArray[np.float64], src_ang_vel: NDArray[np.float64],
    dst_rot: NDArray[np.float64], dst_ang_vel: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """New rotation offsets at a switch so that exp(offset) @ dst == exp(old offset) @ src."""
    shown = rotation_exp(offset_rot) @ src_rot
    new_rot = rotation_log(shown @ np.swapaxes(dst_rot, -1, -2))
    return new_rot, offset_ang_vel + src_ang_vel - dst_ang_vel


def transition_offsets_linear(
    offset: NDArray[np.float64], offset_vel: NDArray[np.float64], src: NDArray[np.float64], src_vel: NDArray[np.float64],
    dst: NDArray[np.float64], dst_vel: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Position-offset counterpart of ``transition_offsets``."""
    return offset + src - dst, offset_vel + src_vel - dst_vel


def apply_rotation_offsets(offset_rot: NDArray[np.float64], rot: NDArray[np.float64]) -> NDArray[np.float64]:
    return rotation_exp(offset_rot) @ rot

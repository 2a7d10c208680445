"""The stand-in figure: one flat-shaded box per bone, in the rest pose (pure geometry).

The GLB export skins this figure to the 22 joints of a character given no body mesh, and the
viewer poses the same mesh per frame. Frame: the glTF frame = the SMPL-X body frame (Y up,
metres). Each vertex belongs to exactly one box and is bound with weight 1 to the joint whose
bone the box covers; box geometry is a deterministic function of the rest skeleton.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import JOINT_INDEX, JOINT_NAMES, NUM_JOINTS, PARENTS, rest_positions
from storyteller.sim.export.bvh import END_SITES

# Bone boxes: (from joint, to joint or end site, owner joint, width, depth) in metres.
_BONE_SIZES: dict[str, tuple[float, float]] = {
    "left_hip": (0.14, 0.14),
    "right_hip": (0.14, 0.14),
    "spine1": (0.30, 0.18),
    "left_knee": (0.13, 0.13),
    "right_knee": (0.13, 0.13),
    "spine2": (0.30, 0.18),
    "left_ankle": (0.10, 0.10),
    "right_ankle": (0.10, 0.10),
    "spine3": (0.32, 0.19),
    "left_foot": (0.09, 0.06),
    "right_foot": (0.09, 0.06),
    "neck": (0.09, 0.09),
    "left_collar": (0.10, 0.10),
    "right_collar": (0.10, 0.10),
    "head": (0.09, 0.09),
    "left_shoulder": (0.10, 0.10),
    "right_shoulder": (0.10, 0.10),
    "left_elbow": (0.10, 0.10),
    "right_elbow": (0.10, 0.10),
    "left_wrist": (0.08, 0.08),
    "right_wrist": (0.08, 0.08),
}
_END_SIZES: dict[str, tuple[float, float]] = {
    "head": (0.17, 0.19),
    "left_wrist": (0.09, 0.04),
    "right_wrist": (0.09, 0.04),
    "left_foot": (0.09, 0.05),
    "right_foot": (0.09, 0.05),
}
# Unit cube corners (bit 0: +x, bit 1: +y, bit 2: +z) and its 6 outward quads.
_CORNERS = np.array([[(i >> k) & 1 for k in range(3)] for i in range(8)], dtype=np.float64) - 0.5
_QUADS = np.array(
    [[1, 3, 7, 5], [0, 4, 6, 2], [2, 6, 7, 3], [0, 1, 5, 4], [4, 5, 7, 6], [0, 2, 3, 1]]
)
_QUAD_NORMALS = np.array(
    [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64
)
_QUAD_TRIANGLES = np.array([[0, 1, 2], [0, 2, 3]])


def box_mesh(
    centers: NDArray[np.float64], axes: NDArray[np.float64], half_sizes: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Flat-shaded boxes, vectorised over B boxes.

    centers (B, 3); axes (B, 3, 3) with the box's unit axes as columns (right-handed);
    half_sizes (B, 3). Returns positions (B*24, 3), normals (B*24, 3), triangles (B*12, 3).
    """
    b = centers.shape[0]
    corners = centers[:, None, :] + np.einsum(
        "bij,bcj->bci", axes, _CORNERS[None] * 2.0 * half_sizes[:, None, :]
    )
    positions = corners[:, _QUADS.reshape(-1)]  # (B, 24, 3)
    normals = np.repeat(np.einsum("bij,fj->bfi", axes, _QUAD_NORMALS), 4, axis=1)
    local_tris = (np.arange(6)[:, None, None] * 4 + _QUAD_TRIANGLES[None]).reshape(12, 3)
    triangles = (np.arange(b)[:, None, None] * 24 + local_tris[None]).reshape(-1, 3)
    return positions.reshape(-1, 3), normals.reshape(-1, 3), triangles


def character_mesh() -> tuple[
    NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]
]:
    """The figure in the rest pose (glTF frame = body frame): positions, normals, triangles, joint ids.

    Each vertex is bound to one joint (weight 1), the joint whose bone the box belongs to.
    """
    rest = rest_positions()
    starts, ends, owners, sizes = [], [], [], []
    for j in range(1, NUM_JOINTS):
        starts.append(rest[PARENTS[j]])
        ends.append(rest[j])
        owners.append(PARENTS[j])
        sizes.append(_BONE_SIZES[JOINT_NAMES[j]])
    for name, offset in END_SITES.items():
        j = JOINT_INDEX[name]
        starts.append(rest[j])
        ends.append(rest[j] + np.array(offset))
        owners.append(j)
        sizes.append(_END_SIZES[name])
    a, e = np.array(starts), np.array(ends)
    length = np.linalg.norm(e - a, axis=1)
    along = (e - a) / length[:, None]
    ref = np.where(np.abs(along[:, 2:3]) > 0.9, [[1.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]])
    side = np.cross(along, ref)
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    front = np.cross(side, along)
    axes = np.stack([side, along, front], axis=2)  # columns: width, length, depth
    wd = np.array(sizes)
    half = np.column_stack([wd[:, 0] / 2, length / 2 + 0.02, wd[:, 1] / 2])
    positions, normals, triangles = box_mesh((a + e) / 2, axes, half)
    joints = np.repeat(np.array(owners), 24)
    return positions, normals, triangles, joints

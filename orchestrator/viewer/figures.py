"""The stand-in figure as a skinned mesh: the GLB export's box body, posed per frame (pure).

The mesh is :func:`storyteller.sim.export.box_figure.character_mesh` (one flat-shaded box per bone, in the
rest pose, body frame), each vertex bound with weight 1 to one of the 22 joints. Bones are
given as world transforms: in the bind pose bone ``j`` has no rotation and sits at the rest
joint position, so a vertex ``v`` of bone ``j`` lands at ``G_j (v - r_j) + p_j`` with ``G_j``,
``p_j`` the joint's world rotation and position from
:func:`storyteller.sim.body.skeleton.forward_kinematics` -- the same pose the GLB and BVH exports carry.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from storyteller.sim.body.skeleton import NUM_JOINTS, forward_kinematics, rest_positions
from storyteller.sim.world.character_track import CharacterTrack


@dataclass(frozen=True)
class FigureRig:
    """A skinned mesh in its bind pose: vertices (V, 3), faces (F, 3), weights (V, 22), bones (22, 3)."""

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    skin_weights: NDArray[np.float64]
    bind_positions: NDArray[np.float64]


@dataclass(frozen=True)
class BonePoses:
    """Per-frame world transforms of the 22 bones: wxyz (N, 22, 4) and positions (N, 22, 3)."""

    wxyz: NDArray[np.float64]
    positions: NDArray[np.float64]

    @property
    def num_frames(self) -> int:
        return int(self.positions.shape[0])

    def then(self, more: BonePoses) -> BonePoses:
        """These poses followed by ``more`` (the next frames)."""
        return BonePoses(
            wxyz=np.concatenate([self.wxyz, more.wxyz]), positions=np.concatenate([self.positions, more.positions])
        )

    def at(self, frame: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The pose at ``frame``, held at the last frame past the end."""
        k = min(max(frame, 0), self.num_frames - 1)
        return self.wxyz[k], self.positions[k]


def standin_rig() -> FigureRig:
    """The box figure of the GLB export, bound rigidly to the skeleton."""
    from storyteller.sim.export.box_figure import character_mesh

    positions, _normals, triangles, joints = character_mesh()
    weights = np.zeros((positions.shape[0], NUM_JOINTS))
    weights[np.arange(positions.shape[0]), joints] = 1.0
    return FigureRig(
        vertices=positions, faces=triangles.astype(np.int64), skin_weights=weights, bind_positions=rest_positions()
    )


def bone_poses(track: CharacterTrack, start: int = 0) -> BonePoses:
    """World bone transforms of the frames of ``track`` from ``start`` on (unit quaternions).

    Each frame's pose depends on that frame only, so the poses of a growing track are the
    poses already computed followed by ``bone_poses(track, start=computed)`` (:meth:`BonePoses.then`).
    """
    positions, rotations = forward_kinematics(track.local_rotations[start:], track.root_positions[start:])
    xyzw = Rotation.from_matrix(rotations.reshape(-1, 3, 3)).as_quat().reshape(*rotations.shape[:-2], 4)
    wxyz = np.concatenate([xyzw[..., 3:], xyzw[..., :3]], axis=-1)
    return BonePoses(wxyz=wxyz, positions=positions)


def figure_points(rig: FigureRig, poses: BonePoses, frame: int) -> NDArray[np.float64]:
    """World vertex positions of the posed figure (what the browser's skinning computes)."""
    wxyz, pos = poses.at(frame)
    rot = Rotation.from_quat(np.concatenate([wxyz[:, 1:], wxyz[:, :1]], axis=1)).as_matrix()
    bone = rig.skin_weights.argmax(axis=1)
    local = rig.vertices - rig.bind_positions[bone]
    points: NDArray[np.float64] = np.einsum("vij,vj->vi", rot[bone], local) + pos[bone]
    return points

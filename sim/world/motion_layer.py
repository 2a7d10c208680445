"""The world's motion layer: one call per character per frame, behind a small interface.

The world decides *where* a character's root is (the navigator's position while walking, the
seat path while sitting down) and *which way it faces*; the motion layer decides the body
pose. ``MotionLayer.step(state, query, dt) -> (state, Pose)`` is pure: the per-character
motion state is plain data owned by the world (so snapshots copy it), the layer holds only
read-only data (databases).

``compose_poses`` puts the layer's poses on the world's roots: the pelvis xy is set to the
root exactly (the clearance guarantee is about this point), the pelvis height comes from the
pose, and the root rotation keeps the pose's lean and sway but turns its yaw to the world's
heading.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import NUM_JOINTS
from storyteller.sim.motion.matching import MotionQuery, Pose, PoseBatch

__all__ = ["FUTURE_FRAMES", "BatchedMotionLayer", "MotionLayer", "MotionQuery", "Pose", "PoseBatch", "compose_poses",
           "root_yaw"]

FUTURE_FRAMES = (10, 20, 30)


class MotionLayer(Protocol):
    """A pure per-character motion synthesizer (``sim.motion.matching.MotionMatcher`` is one).

    The world builds one ``MotionQuery`` per character per frame with the root it chose
    (``root_xy``, ``heading``), the planned future at +10/+20/+30 frames, the action label,
    and the seat / partner / object target; it keeps the returned state for the next frame.
    """

    def initial_state(self, label: str, root_xy: Sequence[float] | NDArray[np.float64], heading: float, seated: bool = False) -> Any:
        """Motion state of a character at ``root_xy`` facing ``heading`` doing ``label``."""
        ...

    def step(self, state: Any, query: MotionQuery, dt: float) -> tuple[Any, Pose]:
        """Advance one frame of ``dt`` seconds; returns the new state and the pose."""
        ...


@runtime_checkable
class BatchedMotionLayer(MotionLayer, Protocol):
    """A motion layer that steps all characters at once and gives the poses as arrays
    (``sim.motion.matching.MotionMatcher.step_batch``), with the same result as ``step`` on
    each character: the world reads the arrays without per-character pose objects."""

    def step_batch(self, states: Sequence[Any], queries: Sequence[MotionQuery], dt: float) -> tuple[list[Any], PoseBatch]:
        """Advance every character one frame; returns the new states and the poses as arrays."""
        ...


def root_yaw(rotations: NDArray[np.float64]) -> NDArray[np.float64]:
    """World yaw (..., ) of the body's forward axis (body +z) of root rotations (..., 3, 3)."""
    return np.asarray(np.arctan2(rotations[..., 1, 2], rotations[..., 0, 2]), dtype=np.float64)


def compose_poses(
    local_rotations: np.ndarray, pelvis_z: np.ndarray, root_xy: np.ndarray, heading: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Poses (N, 22, 3, 3) with heights (N,) placed on roots (N, 2) facing ``heading`` (N,).

    Returns (pelvis positions (N, 3), local rotations (N, 22, 3, 3)); joint 0 becomes
    ``Rz(heading - yaw) @ R_root``, so pitch and roll of the pose survive.
    """
    rot = np.array(local_rotations, dtype=float, copy=True)
    assert rot.shape[1:] == (NUM_JOINTS, 3, 3)
    d = heading - root_yaw(rot[:, 0])
    c, s = np.cos(d), np.sin(d)
    rz = np.zeros((len(d), 3, 3))
    rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1], rz[:, 2, 2] = c, -s, s, c, 1.0
    rot[:, 0] = rz @ rot[:, 0]
    pelvis = np.column_stack([root_xy, pelvis_z])
    return pelvis, rot

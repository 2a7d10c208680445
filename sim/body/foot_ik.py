"""Leg IK after motion matching: feet kept out of furniture, planted feet pinned.

The world puts each pelvis exactly on its planned path (a disc clear of furniture) and motion
matching picks the body pose, so a stride can reach into the footprint of a chair or a table
and a planted foot slides with the root. ``FootSolver.apply`` is a per-frame filter over all
characters that moves only the feet, with the legs' local rotations:

1. *pinning*: a foot in contact (flagged so by the motion, or with its animated toe within
   ``foot_kernel.LAND_M`` of its standing-flat height) is locked where its toe is when the contact starts
   (the foot keeps the animation's world orientation, so it rolls about the pinned toe); the
   lock is released when the contact ends, or while in contact when the lock drifts more than
   ``max_drift`` from the animated toe or needs more than ``max_reach`` of the leg's length
   (a planted foot left behind a walking body would drag a straight leg), and the foot then
   blends back to the animation over ``release_frames`` frames (a smoothstep on the offset it
   had at the release), lifted on the way (up to ``foot_kernel.REPLANT_LIFT_M``, the offset
   when that is less) so that it steps rather than slides; a contact starts no lock out
   of that reach, and a blending foot is
   held within it (or within the animation's reach, if longer) by pulling it towards the hip;
   An active character's toe target is never below the floor (``foot_kernel.TOE_FLOOR_M``, the
   toe's height standing flat): a blend between two clips can swing a leg through it.
2. *clearance*: the foot (ankle and toe joints, as one rigid piece) is moved horizontally out
   of every floor-standing footprint grown by ``margin``, by the shortest shift that clears
   all of them (``storyteller.sim.body.foot_clearance.push_out``);
3. *two-bone IK* on hip-knee-ankle (``storyteller.sim.body.leg_ik``) reaches the ankle target: the knee
   bends in the animated leg's plane (blended towards the thigh's own flexion axis as the
   animated leg straightens), then the leg swings to the target with the
   smallest rotation; the ankle's local rotation is recomputed so the foot keeps its world
   orientation. An unreachable target stretches the leg towards it (or folds it as far as the
   bones allow).

Only the local rotations of hips, knees and ankles change; the pelvis position and every other
joint's local rotation are returned untouched. A foot that is neither locked, blending,
pushed nor below the floor keeps its input rotations up to rounding (1e-15), except a knee that the animation
bends backwards, which the IK bends forwards; an inactive character's legs come back exactly
as they were (once any release blend is over). ``apply`` is a pure function of its inputs and the
state it returns (plain arrays in a frozen dataclass, never modified in place), so world
snapshots can copy it. Characters whose feet belong under furniture (seated at a table) should
be passed as inactive: their feet are then neither pinned nor pushed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.body.foot_clearance import BoxGrid, Footprints, push_out
from storyteller.sim.body.foot_kernel import apply_frame
from storyteller.sim.body.leg_ik import (
    HIP_JOINTS,
    KNEE_JOINTS,
    LEG_JOINTS,
    SHIN_LENGTH,
    THIGH_LENGTH,
    FootIKError,
    solve_legs,
)
from storyteller.sim.body.skeleton import NUM_JOINTS
from storyteller.sim.scene.model import Scene

__all__ = [
    "HIP_JOINTS",
    "KNEE_JOINTS",
    "LEG_JOINTS",
    "FootIKError",
    "FootSolver",
    "FootState",
    "Footprints",
    "push_out",
    "solve_legs",
]


@dataclass(frozen=True)
class FootState:
    """Per character and foot (N, 2, ...): ``locked`` feet and their pinned toe position
    ``lock`` (world, m); ``offset`` (toe, m) being blended out over ``release`` more frames
    after a release; ``drifted``: released for drift during this contact (no relock until the
    blend is over or the contact ends)."""

    locked: NDArray[np.bool_]
    lock: NDArray[np.float64]
    offset: NDArray[np.float64]
    release: NDArray[np.int64]
    drifted: NDArray[np.bool_]

    @classmethod
    def initial(cls, n: int) -> FootState:
        return cls(
            locked=np.zeros((n, 2), dtype=bool),
            lock=np.zeros((n, 2, 3)),
            offset=np.zeros((n, 2, 3)),
            release=np.zeros((n, 2), dtype=np.int64),
            drifted=np.zeros((n, 2), dtype=bool),
        )

    @property
    def characters(self) -> int:
        return int(self.locked.shape[0])


class FootSolver:
    """Keeps feet out of floor-standing footprints and pins planted feet (see the module doc).

    ``FootSolver.from_scene(scene)``, then per frame
    ``rots, state = solver.apply(pelvis, rots, contacts, state)`` starting from
    ``solver.initial_state(n)``."""

    def __init__(self, footprints: Footprints, *, max_drift: float = 0.25, max_reach: float = 0.99,
                 release_frames: int = 6, passes: int = 4) -> None:
        if max_drift <= 0 or not 0 < max_reach <= 1 or release_frames < 0 or passes < 1:
            raise FootIKError(
                "need max_drift > 0, 0 < max_reach <= 1, release_frames >= 0 and passes >= 1, got "
                f"{max_drift}, {max_reach}, {release_frames}, {passes}")
        self.footprints = footprints
        self._grid = BoxGrid.of(footprints)
        self.max_drift = float(max_drift)
        self.max_reach = float(max_reach)
        self.release_frames = int(release_frames)
        self.passes = int(passes)

    @classmethod
    def from_scene(cls, scene: Scene, *, margin: float = 0.03, floor_support: float = 0.10,
                   max_drift: float = 0.25, max_reach: float = 0.99, release_frames: int = 6) -> FootSolver:
        """A solver for ``scene``'s floor-standing objects, footprints grown by ``margin`` m."""
        if margin < 0:
            raise FootIKError(f"margin must be >= 0 m, got {margin}")
        return cls(Footprints.from_scene(scene, margin, floor_support), max_drift=max_drift,
                   max_reach=max_reach, release_frames=release_frames)

    @staticmethod
    def initial_state(n: int) -> FootState:
        return FootState.initial(n)

    def apply(self, pelvis: NDArray[np.float64], rots: NDArray[np.float64], contacts: NDArray[np.float64], state: FootState,
              active: NDArray[np.float64] | None = None,
              pinned: NDArray[np.bool_] | None = None) -> tuple[NDArray[np.float64], FootState]:
        """One frame for N characters.

        pelvis (N, 3) world positions (unchanged), rots (N, 22, 3, 3) local rotations (joint 0
        in world), contacts (N, 2) left/right foot contact flags, state from the previous frame
        (or ``initial_state(N)``); ``active`` (N,) bool, default all: an inactive character's
        feet are neither pinned nor pushed (a held lock is released smoothly); ``pinned`` (N,)
        bool, default none: characters whose feet are pinned (and kept above the floor) though
        inactive, so not pushed (sitting down or standing up by a table: feet may go under it). Returns the new
        local rotations (a copy; only hips, knees and ankles differ) and the new state."""
        pelvis = np.asarray(pelvis, dtype=np.float64)
        rots = np.asarray(rots, dtype=np.float64)
        contacts = np.asarray(contacts)
        n = len(pelvis)
        if pelvis.shape != (n, 3) or rots.shape != (n, NUM_JOINTS, 3, 3) or contacts.shape != (n, 2):
            raise FootIKError(
                f"need pelvis (N, 3), rots (N, {NUM_JOINTS}, 3, 3), contacts (N, 2); got "
                f"{pelvis.shape}, {rots.shape}, {contacts.shape}")
        if state.characters != n:
            raise FootIKError(f"state holds {state.characters} characters, the frame has {n}")
        if not (np.isfinite(pelvis).all() and np.isfinite(rots).all()):
            raise FootIKError("pelvis and rotations must be finite")
        act = np.ones(n, dtype=bool) if active is None else np.asarray(active, dtype=bool).reshape(n)
        pin = act if pinned is None else act | np.asarray(pinned, dtype=bool).reshape(n)
        fp, g = self.footprints, self._grid
        out, locked, lock, offset, release, drifted = apply_frame(
            np.ascontiguousarray(pelvis), np.ascontiguousarray(rots), np.ascontiguousarray(contacts, dtype=bool),
            np.ascontiguousarray(act), np.ascontiguousarray(pin), state.locked, state.lock, state.offset, state.release, state.drifted,
            self.max_reach * (THIGH_LENGTH + SHIN_LENGTH), THIGH_LENGTH, SHIN_LENGTH, self.max_drift,
            self.release_frames, fp.centers, fp.rights, fp.facings, fp.halves, self.passes,
            g.origin, g.cell, g.shape[0], g.shape[1], g.starts, g.items)
        return out, FootState(locked=locked, lock=lock, offset=offset, release=release, drifted=drifted)

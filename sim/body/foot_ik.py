"""Leg IK after motion matching: feet kept out of furniture, planted feet pinned.

The world puts each pelvis exactly on its planned path (a disc clear of furniture) and motion
matching picks the body pose, so a stride can reach into the footprint of a chair or a table
and a planted foot slides with the root. ``FootSolver.apply`` is a per-frame filter over all
characters that moves only the feet, with the legs' local rotations:

1. *pinning*: a foot flagged in contact is locked where its toe is when the contact starts
   (the foot keeps the animation's world orientation, so it rolls about the pinned toe); the
   lock is released when the contact ends, or while in contact when the lock drifts more than
   ``max_drift`` from the animated toe or needs more than ``max_reach`` of the leg's length
   (a planted foot left behind a walking body would drag a straight leg), and the foot then
   blends back to the animation over ``release_frames`` frames (a smoothstep on the offset it
   had at the release); a contact starts no lock out of that reach, and a blending foot is
   held within it (or within the animation's reach, if longer) by pulling it towards the hip;
2. *clearance*: the foot (ankle and toe joints, as one rigid piece) is moved horizontally out
   of every floor-standing footprint grown by ``margin``, by the shortest shift that clears
   all of them (``sim.body.foot_clearance.push_out``);
3. *two-bone IK* on hip-knee-ankle (``sim.body.leg_ik``) reaches the ankle target: the knee
   bends in the animated leg's plane (blended towards the thigh's own flexion axis as the
   animated leg straightens), then the leg swings to the target with the
   smallest rotation; the ankle's local rotation is recomputed so the foot keeps its world
   orientation. An unreachable target stretches the leg towards it (or folds it as far as the
   bones allow).

Only the local rotations of hips, knees and ankles change; the pelvis position and every other
joint's local rotation are returned untouched. A foot that is neither locked, blending nor
pushed keeps its input rotations up to rounding (1e-15), except a knee that the animation
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

from sim.body.foot_clearance import Footprints, push_out
from sim.body.foot_kernel import apply_frame
from sim.body.leg_ik import (
    HIP_JOINTS,
    KNEE_JOINTS,
    LEG_JOINTS,
    SHIN_LENGTH,
    THIGH_LENGTH,
    FootIKError,
    LegChain,
    solve_chain,
    solve_legs,
)
from sim.body.skeleton import NUM_JOINTS
from sim.scene.model import Scene

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


_REACH_EPS = 1e-9  # m: reach comparisons of a lock start


def _smoothstep(x: NDArray[np.float64]) -> NDArray[np.float64]:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


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
              active: NDArray[np.float64] | None = None) -> tuple[NDArray[np.float64], FootState]:
        """One frame for N characters.

        pelvis (N, 3) world positions (unchanged), rots (N, 22, 3, 3) local rotations (joint 0
        in world), contacts (N, 2) left/right foot contact flags, state from the previous frame
        (or ``initial_state(N)``); ``active`` (N,) bool, default all: an inactive character's
        feet are neither pinned nor pushed (a held lock is released smoothly). Returns the new
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
        fp = self.footprints
        out, locked, lock, offset, release, drifted = apply_frame(
            np.ascontiguousarray(pelvis), np.ascontiguousarray(rots), np.ascontiguousarray(contacts, dtype=bool),
            np.ascontiguousarray(act), state.locked, state.lock, state.offset, state.release, state.drifted,
            self.max_reach * (THIGH_LENGTH + SHIN_LENGTH), THIGH_LENGTH, SHIN_LENGTH, self.max_drift,
            self.release_frames, fp.centers, fp.rights, fp.facings, fp.halves, self.passes)
        return out, FootState(locked=locked, lock=lock, offset=offset, release=release, drifted=drifted)

    def apply_numpy(self, pelvis: NDArray[np.float64], rots: NDArray[np.float64], contacts: NDArray[np.float64], state: FootState,
                    active: NDArray[np.float64] | None = None) -> tuple[NDArray[np.float64], FootState]:
        """``apply`` as array steps (the reference of the compiled ``sim.body.foot_kernel.apply_frame``;
        same results to rounding). Inputs are not checked here."""
        pelvis = np.asarray(pelvis, dtype=np.float64)
        rots = np.asarray(rots, dtype=np.float64)
        contacts = np.asarray(contacts)
        n = len(pelvis)
        act = np.ones(n, dtype=bool) if active is None else np.asarray(active, dtype=bool).reshape(n)
        contact = contacts.astype(bool) & act[:, None]

        chain = LegChain(pelvis, rots)
        toe = chain.toe  # (N, 2, 3)
        foot = toe - chain.ankle  # the foot keeps its animated world orientation

        # pinning: release, blend, lock
        full = self.max_reach * (THIGH_LENGTH + SHIN_LENGTH)  # (2,) left, right
        drift = np.linalg.norm(state.lock - toe, axis=-1)
        overreach = np.linalg.norm(state.lock - foot - chain.hip, axis=-1) > full
        lost = state.locked & ~contact
        drifted_now = state.locked & contact & ((drift > self.max_drift) | overreach)
        released = lost | drifted_now
        offset = np.where(released[..., None], state.lock - toe, state.offset)
        release = np.where(released, self.release_frames,
                           np.where(state.locked, 0, np.maximum(state.release - 1, 0)))
        locked = state.locked & ~released
        drifted = (state.drifted | drifted_now) & contact & (release > 0)
        weight = _smoothstep(release / self.release_frames) if self.release_frames > 0 else np.zeros(release.shape)
        offset = np.where((release > 0)[..., None], offset, 0.0)
        target = np.where(locked[..., None], state.lock, toe + offset * weight[..., None])
        # a pinned or blending foot stays within max_reach of the leg (or the animation's own
        # reach, if longer), pulled towards the hip: the IK then seldom straightens the knee
        ankle_to = target - foot - chain.hip
        dist = np.linalg.norm(ankle_to, axis=-1)
        limit = np.maximum(full, np.linalg.norm(chain.ankle - chain.hip, axis=-1))
        far = dist > limit
        if far.any():
            scale = np.where(far, limit / np.maximum(dist, 1e-12), 1.0)[..., None]
            target = np.where(far[..., None], chain.hip + ankle_to * scale + foot, target)

        # clearance: the rigid foot (ankle, toe) out of every footprint, horizontally
        shift = np.zeros((n, 2, 2))
        if len(self.footprints) and act.any():
            pts = np.stack([target - foot, target], axis=2)[act][..., :2]  # (A, 2 feet, 2 points, 2)
            shift[act] = push_out(pts.reshape(-1, 2, 2), self.footprints, self.passes).reshape(-1, 2, 2)
        target = target.copy()
        target[..., :2] += shift

        # (a target clamped to the reach sits on it up to rounding: a tolerance keeps that a start)
        start = contact & ~locked & ~drifted & (np.linalg.norm(target - foot - chain.hip, axis=-1) <= full + _REACH_EPS)
        lock = np.where(start[..., None], target, state.lock)
        locked = locked | start
        release = np.where(start, 0, release)
        offset = np.where(start[..., None], 0.0, offset)
        new_state = FootState(locked=locked, lock=np.where(locked[..., None], lock, 0.0),
                              offset=offset, release=release, drifted=drifted)

        # every leg of an active character goes through the IK (a leg whose target is its own
        # ankle comes back as it was, up to rounding, unless its knee bent backwards), so a
        # lock or a push never switches the knee rule on in the middle of a stride
        solve = (np.linalg.norm(target - toe, axis=-1) > 0.0) | act[:, None]
        return solve_chain(chain, rots, target - foot, solve), new_state

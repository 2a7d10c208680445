"""The raw query vector of a motion-matching search, for a batch of characters.

The pose part comes from each character's last output pose (joints and joint velocities in
its character frame, one batched forward-kinematics call), the control part from its query
(future root points and headings, target, seat height). Two paths give the same vectors:
``query_features_many`` (numpy, any state, also a state with no output pose yet) and
``compiled_query_features`` (``storyteller.sim.motion.kernels.query_features``, every state posed).

It reads states and queries through the protocols below (``storyteller.sim.motion.matching.MatchState``
and ``MotionQuery`` satisfy them) and imports nothing from ``storyteller.sim.motion.matching``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from storyteller.sim.body.skeleton import NUM_JOINTS, forward_kinematics
from storyteller.sim.motion.database import MotionDatabase
from storyteller.sim.motion.features import (
    Control,
    assemble,
    relative_target,
    to_character_frame,
    vectors_to_character_frame,
)
from storyteller.sim.motion.frames import DatabaseFrames
from storyteller.sim.motion.kernels import OFFSETS, PARENT_INDEX, query_features


class PoseHistory(Protocol):
    """What a query reads of a character's matcher state: its database frame, heading (rad)
    and its last two output poses (``pose_*`` None before the first step), ``pose_dt`` (s)
    apart."""

    @property
    def key(self) -> str: ...
    @property
    def frame(self) -> int: ...
    @property
    def heading(self) -> float: ...
    @property
    def pose_local(self) -> NDArray[np.float64] | None: ...
    @property
    def pose_pelvis(self) -> NDArray[np.float64] | None: ...
    @property
    def prev_local(self) -> NDArray[np.float64] | None: ...
    @property
    def prev_pelvis(self) -> NDArray[np.float64] | None: ...
    @property
    def pose_dt(self) -> float: ...


class Steering(Protocol):
    """What a query reads of a motion query: planned future root points (3, 2) / headings (3,),
    target ground point and facing (rad), seat height (m); None where not given."""

    @property
    def future_xy(self) -> NDArray[np.float64] | None: ...
    @property
    def future_heading(self) -> NDArray[np.float64] | None: ...
    @property
    def target_xy(self) -> NDArray[np.float64] | None: ...
    @property
    def target_facing(self) -> float | None: ...
    @property
    def seat_height(self) -> float | None: ...


def pose_joints(states: Sequence[PoseHistory]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """World joints (M,22,3) of the states' last poses and their character-frame velocities
    (M,22,3), with one batched forward-kinematics call. Every state must have a pose."""
    m = len(states)
    locs: list[NDArray[np.float64]] = []
    pels: list[NDArray[np.float64]] = []
    prev_locs: list[NDArray[np.float64]] = []
    prev_pels: list[NDArray[np.float64]] = []
    has_prev: list[bool] = []
    for s in states:
        if s.pose_local is None or s.pose_pelvis is None:
            raise ValueError("every state needs a pose (a first matching step) before its joints are read")
        locs.append(s.pose_local)
        pels.append(s.pose_pelvis)
        has = s.prev_local is not None and s.prev_pelvis is not None and s.pose_dt > 0
        if s.prev_local is not None and s.prev_pelvis is not None and has:
            prev_locs.append(s.prev_local)
            prev_pels.append(s.prev_pelvis)
        has_prev.append(has)
    joints = forward_kinematics(np.stack(locs + prev_locs), np.stack(pels + prev_pels))[0]
    vel = np.zeros((m, NUM_JOINTS, 3))
    k = m
    for i, (s, h) in enumerate(zip(states, has_prev, strict=True)):
        if h:
            vel[i] = vectors_to_character_frame((joints[i] - joints[k]) / s.pose_dt, np.asarray(s.heading))
            k += 1
    return joints[:m], vel


def control(query: Steering, root_xy: NDArray[np.float64], heading: float) -> Control:
    """The control part of a query at ``root_xy`` / ``heading`` (no future: stay here)."""
    if query.future_xy is not None:
        fut_xy = np.asarray(query.future_xy, dtype=np.float64).reshape(3, 2)
        fut_h = (np.full(3, heading) if query.future_heading is None
                 else np.asarray(query.future_heading, dtype=np.float64).reshape(3))
    else:
        fut_xy, fut_h = np.broadcast_to(root_xy, (3, 2)), np.full(3, heading)
    fut_pos, fut_dir = relative_target(np.broadcast_to(root_xy, (3, 2)), np.full(3, heading), fut_xy, fut_h)
    if query.target_xy is not None:
        facing = heading if query.target_facing is None else float(query.target_facing)
        t_pos, t_dir = relative_target(root_xy, np.asarray(heading), np.asarray(query.target_xy, float), np.asarray(facing))
    else:
        t_pos, t_dir = np.zeros(2), np.array([-1.0, 0.0])
    height = np.asarray(query.seat_height if query.seat_height is not None else 0.0)
    return Control(fut_pos, fut_dir, t_pos, t_dir, height)


def query_features_many(frames_of: Callable[[str], DatabaseFrames], db: MotionDatabase, states: Sequence[PoseHistory],
                        queries: Sequence[Steering], roots: Sequence[NDArray[np.float64]],
                        headings: Sequence[float]) -> NDArray[np.float64]:
    """Raw query vectors (M,D) for characters searching ``db`` (one FK call for all); a state
    with no output pose yet stands at its database frame (``frames_of(key)``), at rest."""
    m = len(states)
    pos = np.empty((m, NUM_JOINTS, 3))
    vel = np.zeros((m, NUM_JOINTS, 3))
    posed = [i for i, s in enumerate(states) if s.pose_local is not None and s.pose_pelvis is not None]
    fresh = [i for i, s in enumerate(states) if s.pose_local is None or s.pose_pelvis is None]
    if posed:
        joints, v = pose_joints([states[i] for i in posed])
        idx = np.array(posed)
        pos[idx] = to_character_frame(joints, np.stack([roots[i] for i in posed]),
                                      np.array([headings[i] for i in posed], dtype=np.float64))
        vel[idx] = v
    if fresh:  # no output pose yet: the current database frame, at rest
        rots = np.stack([frames_of(states[i].key).rot[states[i].frame] for i in fresh])
        pels = np.stack([frames_of(states[i].key).pelvis[states[i].frame] for i in fresh])
        pos[np.array(fresh)] = forward_kinematics(rots, pels)[0]
    ctrl = [control(q, r, h) for q, r, h in zip(queries, roots, headings, strict=True)]
    stacked = Control(*(np.stack([getattr(c, f) for c in ctrl]) for f in
                         ("future_pos", "future_dir", "target_pos", "target_dir", "target_height")))
    return assemble(db.layout_name, pos, vel, stacked)


def compiled_query_features(members: Sequence[int], states: Sequence[PoseHistory], queries: Sequence[Steering],
                            roots: Sequence[NDArray[np.float64]], headings: Sequence[float],
                            sources: np.ndarray) -> NDArray[np.float64]:
    """Raw query vectors (M,D) of characters ``members`` (indices into the other sequences)
    through the compiled kernel; ``sources``: the database layout's feature sources
    (``StepDatabase.sources``). Every member must have an output pose."""
    # every member has a pose here (the caller checks); numpy turns the lists into arrays
    cur_l: list[NDArray[np.float64] | None] = []
    cur_p: list[NDArray[np.float64] | None] = []
    prev_l: list[NDArray[np.float64] | None] = []
    prev_p: list[NDArray[np.float64] | None] = []
    fut_xy: list[ArrayLike] = []
    fut_h: list[ArrayLike] = []
    scalars: list[tuple[float, ...]] = []
    for i in members:
        s, q, h, root = states[i], queries[i], headings[i], roots[i]
        cur_l.append(s.pose_local)
        cur_p.append(s.pose_pelvis)
        if s.prev_local is not None and s.pose_dt > 0:
            has_prev, pose_dt = 1.0, s.pose_dt
            prev_l.append(s.prev_local)
            prev_p.append(s.prev_pelvis)
        else:  # placeholders, unused
            has_prev, pose_dt = 0.0, 1.0
            prev_l.append(s.pose_local)
            prev_p.append(s.pose_pelvis)
        fx = q.future_xy
        if fx is None:
            fut_xy.append((root, root, root))
            fut_h.append((h, h, h))
        else:
            fut_xy.append(fx if type(fx) is np.ndarray and fx.shape == (3, 2)
                          else np.asarray(fx, dtype=np.float64).reshape(3, 2))
            fh = q.future_heading
            fut_h.append((h, h, h) if fh is None else fh if type(fh) is np.ndarray and fh.shape == (3,)
                         else np.asarray(fh, dtype=np.float64).reshape(3))
        if q.target_xy is None:
            has_t, tx, ty, facing = 0.0, 0.0, 0.0, 0.0
        else:
            t = np.asarray(q.target_xy, dtype=np.float64)
            has_t, tx, ty = 1.0, t[0], t[1]
            facing = h if q.target_facing is None else float(q.target_facing)
        height = 0.0 if q.seat_height is None else q.seat_height
        scalars.append((has_prev, pose_dt, s.heading, root[0], root[1], h, has_t, tx, ty, facing, height))
    return query_features(np.array(cur_l, dtype=np.float64), np.array(cur_p, dtype=np.float64),
                          np.array(prev_l, dtype=np.float64), np.array(prev_p, dtype=np.float64),
                          np.array(fut_xy, dtype=np.float64), np.array(fut_h, dtype=np.float64),
                          np.array(scalars, dtype=np.float64), sources, PARENT_INDEX, OFFSETS)

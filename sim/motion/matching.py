"""Motion-matching controller: a pure per-character update over the motion databases.

``MotionMatcher.step(state, query, dt) -> (state, pose)`` plays the current database frame,
searches for a better frame every ``search_interval`` frames, when the action label changes,
when a clip runs out or when the caller forces it, and hides every switch with
inertialization (offsets that decay with a critically damped spring of half-life
``blend_halflife`` seconds).

The root (ground point and heading) belongs to the caller: when the query carries the
simulated ``root_xy`` / ``heading`` the pose is placed there (the root stays on the planned
path); without them the database's own root motion is integrated (sitting down, stepping).
The database supplies the body: pelvis offset from the root and joint rotations.

Frames: world z up; the character frame has x forward, y left, origin at the root.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim.body.skeleton import NUM_JOINTS, forward_kinematics
from sim.motion.action_labels import database_key
from sim.motion.clips import FOOT_JOINTS, FPS
from sim.motion.database import MotionDatabase
from sim.motion.features import (
    FUTURE_FRAMES,
    Control,
    assemble,
    relative_target,
    to_character_frame,
    vectors_to_character_frame,
)
from sim.motion.frames import (
    DatabaseFrames,
    FrameTable,
    StepDatabase,
    feature_sources,
    shared_frames,
    shared_store,
    shared_table,
)
from sim.motion.inertialization import LN2
from sim.motion.kernels import OFFSETS, PARENT_INDEX, advance_clips, query_features, step_poses


class MotionMatchingError(ValueError):
    """A query the matcher cannot serve (e.g. no database for its label)."""


@dataclass(frozen=True)
class MotionQuery:
    """What the character should do now.

    label: action label; seated: do it seated (selects the seated database).
    root_xy (2,), heading (rad): the simulated root this frame (None: use root motion).
    future_xy (3,2), future_heading (3,): planned root positions / headings (world) at
    +10, +20, +30 frames; None means "stay here". target_xy (2,), target_facing (rad):
    seat, partner or object ground point and facing; seat_height (m) for sitting.
    force_search: search now (e.g. on a character-state change).
    """

    label: str
    seated: bool = False
    root_xy: NDArray[np.float64] | None = None
    heading: float | None = None
    future_xy: NDArray[np.float64] | None = None
    future_heading: NDArray[np.float64] | None = None
    target_xy: NDArray[np.float64] | None = None
    target_facing: float | None = None
    seat_height: float | None = None
    force_search: bool = False


@dataclass(frozen=True)
class Pose:
    """Output pose: pelvis (3,) world; local_rotations (22,3,3) with joint 0 the world pelvis
    rotation; root_xy (2,) / heading (rad) of the character; contacts (2,) left/right foot."""

    pelvis: NDArray[np.float64]
    local_rotations: NDArray[np.float64]
    root_xy: NDArray[np.float64]
    heading: float
    contacts: NDArray[np.float64]

    def joints(self) -> NDArray[np.float64]:
        """World joint positions (22,3)."""
        return forward_kinematics(self.local_rotations, self.pelvis)[0]


@dataclass(frozen=True)
class MatchState:
    """Per-character matcher state (immutable; ``step`` returns a new one).

    The last output pose is kept as rotations + pelvis (``pose_local``, ``pose_pelvis``; None
    before the first step) together with the one before it (``prev_local``, ``prev_pelvis``)
    and the step length ``pose_dt`` (s) between them: joint positions and velocities are only
    needed when a search runs, so forward kinematics runs then (``joints_world``,
    ``joint_vel_char``), not every frame.
    """

    key: str
    frame: int
    root_xy: NDArray[np.float64]
    heading: float
    frame_clock: float = 0.0
    since_search: int = 0
    offset_rot: NDArray[np.float64] | None = None
    offset_ang_vel: NDArray[np.float64] | None = None
    offset_pos: NDArray[np.float64] | None = None
    offset_vel: NDArray[np.float64] | None = None
    pose_local: NDArray[np.float64] | None = None
    pose_pelvis: NDArray[np.float64] | None = None
    prev_local: NDArray[np.float64] | None = None
    prev_pelvis: NDArray[np.float64] | None = None
    pose_dt: float = 0.0
    elapsed: float = 0.0
    done: bool = False
    switches: int = 0
    searches: int = 0

    @property
    def joints_world(self) -> NDArray[np.float64] | None:
        """World joint positions (22,3) of the last output pose (None before the first step)."""
        if self.pose_local is None or self.pose_pelvis is None:
            return None
        return forward_kinematics(self.pose_local, self.pose_pelvis)[0]

    @property
    def joint_vel_char(self) -> NDArray[np.float64] | None:
        """Joint velocities (22,3) m/s of the last output pose in its character frame (zeros
        after the first step; None before it)."""
        if self.pose_local is None or self.pose_pelvis is None:
            return None
        velocities: NDArray[np.float64] = _pose_joints([self])[1][0]
        return velocities


def _pose_joints(states: Sequence[MatchState]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
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


_NO_SWITCH = (np.empty((0, 2), dtype=np.int64), np.empty((2, 0, NUM_JOINTS, 3)), np.empty((2, 0, 3)))


@dataclass(frozen=True)
class PoseBatch:
    """The output poses of a batched step as arrays, row i for character i: pelvis (N,3),
    local_rotations (N,22,3,3) (joint 0 the world pelvis rotation), root_xy / heading per
    character, contacts (N,2) bool. ``poses()`` gives them as ``Pose`` objects."""

    pelvis: NDArray[np.float64]
    local_rotations: NDArray[np.float64]
    root_xy: Sequence[NDArray[np.float64]]
    heading: Sequence[float]
    contacts: NDArray[np.bool_]

    def poses(self) -> list[Pose]:
        new = object.__new__
        out = []
        for pel, loc, root, head, con in zip(list(self.pelvis), list(self.local_rotations), self.root_xy, self.heading,
                                             list(self.contacts), strict=True):
            pose = new(Pose)  # a frozen dataclass, filled as its __init__ would
            pose.__dict__.update(pelvis=pel, local_rotations=loc, root_xy=root, heading=head, contacts=con)
            out.append(pose)
        return out


_ClipTables = tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_],
                    NDArray[np.bool_]]
"""``advance_clips``'s tables: per database base, per global frame next frame, non-loop end and
looping clip, per database completes and entry index (``MotionMatcher._clip_tables``)."""


@dataclass(frozen=True)
class _Batch:
    """The states a batched step returned, with their fields as arrays (row i: state i), so
    that the next step, handed those very states back, reads arrays instead of N objects:
    database index (``StepDatabase.index``), frame, frame clock, frames since the last
    search, done, elapsed, switches, searches, the offset arrays (rotation, angular velocity,
    pelvis, pelvis velocity) and the output poses (rows)."""

    states: tuple[MatchState, ...]
    key: NDArray[np.int64]
    frame: NDArray[np.int64]
    clock: NDArray[np.float64]
    since: NDArray[np.int64]
    done: NDArray[np.bool_]
    elapsed: NDArray[np.float64]
    switches: NDArray[np.int64]
    searches: NDArray[np.int64]
    offsets: tuple[NDArray[np.float64], ...] = ()
    pose_local: Sequence[NDArray[np.float64] | None] = ()
    pose_pelvis: Sequence[NDArray[np.float64] | None] = ()

    @classmethod
    def of(cls, states: Sequence[MatchState], keys: Sequence[int]) -> _Batch:
        """The array fields of any states (``keys``: their database indices); no offsets or poses."""
        n = len(states)
        return cls(
            states=tuple(states), key=np.array(keys, dtype=np.int64).reshape(n),
            frame=np.fromiter((s.frame for s in states), dtype=np.int64, count=n),
            clock=np.fromiter((s.frame_clock for s in states), dtype=np.float64, count=n),
            since=np.fromiter((s.since_search for s in states), dtype=np.int64, count=n),
            done=np.fromiter((s.done for s in states), dtype=np.bool_, count=n),
            elapsed=np.fromiter((s.elapsed for s in states), dtype=np.float64, count=n),
            switches=np.fromiter((s.switches for s in states), dtype=np.int64, count=n),
            searches=np.fromiter((s.searches for s in states), dtype=np.int64, count=n),
        )


class MotionMatcher:
    """Motion matching over ``databases`` (database key -> MotionDatabase)."""

    def __init__(
        self,
        databases: Mapping[str, MotionDatabase],
        search_interval: int = 10,
        blend_halflife: float = 0.1,
        continuation_window: int = 3,
    ) -> None:
        self.databases = dict(databases)
        self.search_interval = int(search_interval)
        self.blend_halflife = float(blend_halflife)
        self.continuation_window = int(continuation_window)
        self._frames: dict[str, DatabaseFrames] = {}
        self._tables: dict[str, FrameTable] = {}
        self._keys: dict[str, StepDatabase] = {}
        self._store = shared_store(self.databases)
        self._by_label: dict[tuple[str, bool], StepDatabase] = {}
        self._step_dbs: list[StepDatabase] = []  # by StepDatabase.index
        self._clip_arrays_for = 0  # databases in _clip_arrays
        self._clip_arrays: _ClipTables | None = None  # see _clip_tables
        # the states returned by the last step and their fields as arrays: lets the next call
        # skip reading N objects when it gets those very states back
        self._last_batch: _Batch | None = None

    def database(self, label: str, seated: bool = False) -> MotionDatabase:
        key = database_key(label, seated)
        db = self.databases.get(key)
        if db is None:
            raise MotionMatchingError(f"no motion database for {key!r}; loaded: {sorted(self.databases)}")
        return db

    def frames(self, key: str) -> DatabaseFrames:
        """Cached per-database arrays (character-frame rotations, pelvis, velocities)."""
        out = self._frames.get(key)
        if out is None:
            out = self._frames[key] = shared_frames(self.databases[key])
        return out

    def _table(self, key: str) -> FrameTable:
        """Per-database frame tables as Python lists (cheap per-character lookups)."""
        out = self._tables.get(key)
        if out is None:
            out = self._tables[key] = shared_table(self.databases[key], key)
        return out

    def initial_state(self, label: str, root_xy: Sequence[float] | NDArray[np.float64], heading: float, seated: bool = False) -> MatchState:
        db = self.database(label, seated)
        frame = int(np.flatnonzero(db.searchable)[0])
        z = np.zeros((NUM_JOINTS, 3))
        return MatchState(db.key, frame, np.asarray(root_xy, dtype=np.float64).reshape(2), float(heading),
                          offset_rot=z, offset_ang_vel=z, offset_pos=np.zeros(3), offset_vel=np.zeros(3))

    def _control(self, state: MatchState, query: MotionQuery, root_xy: NDArray[np.float64], heading: float) -> Control:
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

    def _query_features_many(self, db: MotionDatabase, states: Sequence[MatchState], queries: Sequence[MotionQuery],
                             roots: Sequence[NDArray[np.float64]], headings: Sequence[float]) -> NDArray[np.float64]:
        """Raw query vectors (M,D) for characters searching ``db`` (one FK call for all)."""
        m = len(states)
        pos = np.empty((m, NUM_JOINTS, 3))
        vel = np.zeros((m, NUM_JOINTS, 3))
        posed = [i for i, s in enumerate(states) if s.pose_local is not None and s.pose_pelvis is not None]
        fresh = [i for i, s in enumerate(states) if s.pose_local is None or s.pose_pelvis is None]
        if posed:
            joints, v = _pose_joints([states[i] for i in posed])
            idx = np.array(posed)
            pos[idx] = to_character_frame(joints, np.stack([roots[i] for i in posed]),
                                          np.array([headings[i] for i in posed], dtype=np.float64))
            vel[idx] = v
        if fresh:  # no output pose yet: the current database frame, at rest
            rots = np.stack([self.frames(states[i].key).rot[states[i].frame] for i in fresh])
            pels = np.stack([self.frames(states[i].key).pelvis[states[i].frame] for i in fresh])
            pos[np.array(fresh)] = forward_kinematics(rots, pels)[0]
        ctrl = [self._control(s, q, r, h) for s, q, r, h in zip(states, queries, roots, headings, strict=True)]
        control = Control(*(np.stack([getattr(c, f) for c in ctrl]) for f in
                             ("future_pos", "future_dir", "target_pos", "target_dir", "target_height")))
        return assemble(db.layout_name, pos, vel, control)

    def query_features(self, db: MotionDatabase, state: MatchState, query: MotionQuery,
                       root_xy: NDArray[np.float64], heading: float) -> NDArray[np.float64]:
        """Raw query vector: the pose part from the last output pose, the control part from the query."""
        raw: NDArray[np.float64] = self._query_features_many(
            db, [state], [query], [np.asarray(root_xy, dtype=np.float64)], [float(heading)])[0]
        return raw

    def step(self, state: MatchState, query: MotionQuery, dt: float) -> tuple[MatchState, Pose]:
        """Advance one character by ``dt`` seconds. Pure: returns the new state and pose."""
        states, poses = self.step_many([state], [query], dt)
        return states[0], poses[0]

    def _key(self, key: str) -> StepDatabase:
        """Per-database facts the step needs, looked up once per key."""
        out = self._keys.get(key)
        if out is None:
            db = self.databases[key]
            frames, tab = self.frames(key), self._table(key)
            out = self._keys[key] = StepDatabase(
                key=key, db=db, tab=tab, frames=frames, seat=db.layout_name in ("sitting", "seated"),
                sources=feature_sources(db.layout_name), base=self._store.base(key, frames, db.contacts),
                index=len(self._step_dbs))
            self._step_dbs.append(out)
        return out

    def _query_key(self, query: MotionQuery) -> StepDatabase:
        """The database of a query's label (cached per label / seated)."""
        out = self._by_label.get((query.label, query.seated))
        if out is None:
            db = self.database(query.label, query.seated)  # raises for labels without a database
            out = self._by_label[(query.label, query.seated)] = self._key(db.key)
        return out

    def _raw_queries(self, members: Sequence[int], states: Sequence[MatchState], queries: Sequence[MotionQuery],
                     roots: Sequence[NDArray[np.float64]], headings: Sequence[float], info: StepDatabase) -> NDArray[np.float64]:
        """Raw query vectors (M,D) of characters searching ``info``'s database: the compiled
        path (``query_features``) when every one has an output pose, else ``_query_features_many``."""
        if any(states[i].pose_local is None or states[i].pose_pelvis is None for i in members):
            return self._query_features_many(info.db, [states[i] for i in members], [queries[i] for i in members],
                                             [roots[i] for i in members], [headings[i] for i in members])
        # every member has a pose here (checked above); numpy turns the lists into arrays
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
                              np.array(scalars, dtype=np.float64), info.sources, PARENT_INDEX, OFFSETS)

    def step_many(self, states: Sequence[MatchState], queries: Sequence[MotionQuery],
                  dt: float) -> tuple[list[MatchState], list[Pose]]:
        """Advance several independent characters by ``dt`` seconds, batched: searches are
        grouped per database; the clip bookkeeping, inertialization, the output poses and the
        query features run in compiled kernels over all characters (``sim.motion.kernels``).
        Same result as ``step`` on each character, and as the numpy version
        (``benchmark.support.motion_reference``)."""
        out_states, batch = self.step_batch(states, queries, dt)
        return out_states, batch.poses()

    def _clip_tables(self) -> _ClipTables:
        """The frame tables of the databases used so far, for ``advance_clips``: per database
        index (``StepDatabase.index``) its base and whether it completes / has an entry index;
        per global frame (base + frame) the next frame, non-loop end, looping clip."""
        n_keys = len(self._step_dbs)
        if self._clip_arrays is None or self._clip_arrays_for != n_keys:
            size = max((k.base + len(k.tab.nxt) for k in self._step_dbs), default=0)
            nxt = np.zeros(size, dtype=np.int64)
            end = np.zeros(size, dtype=np.bool_)
            loops = np.zeros(size, dtype=np.bool_)
            for k in self._step_dbs:
                f = len(k.tab.nxt)
                nxt[k.base: k.base + f] = k.tab.nxt
                end[k.base: k.base + f] = k.tab.end
                loops[k.base: k.base + f] = k.tab.loops
            self._clip_arrays = (np.array([k.base for k in self._step_dbs], dtype=np.int64), nxt, end, loops,
                            np.array([k.tab.completes for k in self._step_dbs], dtype=np.bool_),
                            np.array([k.tab.entry for k in self._step_dbs], dtype=np.bool_))
            self._clip_arrays_for = n_keys
        return self._clip_arrays

    def step_batch(self, states: Sequence[MatchState], queries: Sequence[MotionQuery],
                   dt: float) -> tuple[list[MatchState], PoseBatch]:
        """``step_many`` with the poses as arrays (``PoseBatch``), for callers that use them
        as arrays (the world's frame assembly): no per-character ``Pose`` objects."""
        if len(states) != len(queries):
            raise ValueError(f"{len(states)} states but {len(queries)} queries")
        n = len(states)
        if n == 0:
            return [], PoseBatch(np.empty((0, 3)), np.empty((0, NUM_JOINTS, 3, 3)), [], [], np.empty((0, 2), dtype=bool))
        step_frames = dt * FPS
        by_label = self._by_label
        infos = [by_label.get((q.label, q.seated)) or self._query_key(q) for q in queries]
        keys = self._keys
        last = self._last_batch
        if last is not None and len(last.states) == n and all(a is b for a, b in zip(last.states, states, strict=True)):
            prior = last  # the very states returned last time: their fields are rows of these arrays
        else:
            prior = _Batch.of(states, [(keys.get(s.key) or self._key(s.key)).index for s in states])
        step_dbs = self._step_dbs
        base, nxt, end, loops, completes, entry_key = self._clip_tables()
        info_idx = np.array([k.index for k in infos], dtype=np.int64)
        force = np.array([q.force_search for q in queries], dtype=np.bool_)
        frames_a, clocks_a, since_a, need_a, changed_a, entry_a, done_a = advance_clips(
            prior.frame, prior.clock, prior.since, prior.done, prior.key, info_idx, force, float(step_frames),
            self.search_interval, base, nxt, end, loops, completes, entry_key)
        roots: list[NDArray[np.float64]] = []
        headings: list[float] = []
        f64 = np.float64
        for i, query in enumerate(queries):
            q_root, q_head = query.root_xy, query.heading
            if q_root is not None and q_head is not None:  # root given: no root motion
                if type(q_root) is np.ndarray and q_root.dtype == f64 and q_root.shape == (2,):
                    roots.append(q_root)
                else:
                    roots.append(np.asarray(q_root, dtype=np.float64).reshape(2))
                headings.append(float(q_head))
            else:  # the database's root motion over the frames the clock passed
                root_xy, heading = self._root_motion(states[i], step_dbs[int(prior.key[i])].db, step_frames)
                if q_root is not None:
                    root_xy = np.asarray(q_root, dtype=np.float64).reshape(2)
                if q_head is not None:
                    heading = float(q_head)
                roots.append(root_xy)
                headings.append(float(heading))
        frames = frames_a.tolist()
        changed = changed_a.tolist()
        entry = entry_a.tolist()
        curs = [step_dbs[k] for k in prior.key.tolist()]

        # searches, grouped per (database, entry index)
        new_frames = list(frames)
        switched: list[int] = []
        groups: dict[tuple[str, bool], list[int]] = {}
        for i in np.flatnonzero(need_a).tolist():
            groups.setdefault((infos[i].key, entry[i]), []).append(i)
        for (_key, ent), members in groups.items():
            info = infos[members[0]]
            db = info.db
            raw = self._raw_queries(members, states, queries, roots, headings, info)
            if len(members) == 1:
                found: Sequence[int] | NDArray[np.int64] = [db.search(raw[0], entry=ent)[0]]
            else:
                index = db.entry_index if ent else db.index
                found = index.query_many(db.normalize(raw))[0]
            clip_of, succ, last_frame = info.tab.clip, info.tab.nxt, info.tab.end
            for i, b in zip(members, found, strict=True):
                # the query is the pose shown last frame, so the frame found stands for that
                # pose: its successor is the one to show now (playing the found frame itself
                # would repeat a frame's pose at every search, and slow a walk's steps)
                b, frame = int(b), frames[i]
                b = b if last_frame[b] else int(succ[b])
                if changed[i] or clip_of[b] != clip_of[frame] or not 0 <= b - frame <= self.continuation_window:
                    switched.append(i)
                    new_frames[i] = b
        switched.sort()

        if prior is last:
            off_rot, off_av, off_pos, off_vel = last.offsets
        else:
            off_rot, off_av, off_pos, off_vel = (
                np.ascontiguousarray(np.stack([getattr(s, f) for s in states]), dtype=np.float64)
                for f in ("offset_rot", "offset_ang_vel", "offset_pos", "offset_vel"))
        out_key = prior.key.copy()
        slot = np.full(n, -1, dtype=np.int64)
        done_a = done_a.copy()
        if switched:
            m = len(switched)
            sw_idx = np.empty((m, 2), dtype=np.int64)
            sw_av, sw_lin = np.empty((2, m, NUM_JOINTS, 3)), np.empty((2, m, 3))
            for r, i in enumerate(switched):
                slot[i] = r
                src, dst = curs[i], infos[i]
                sf, df = frames[i], new_frames[i]
                sw_idx[r] = src.base + sf, dst.base + df
                (sw_av[0, r], sw_lin[0, r]), (sw_av[1, r], sw_lin[1, r]) = src.frames.motion(sf), dst.frames.motion(df)
                done_a[i] = False
                out_key[i] = dst.index
        else:
            sw_idx, sw_av, sw_lin = _NO_SWITCH
        new_frames_a = np.array(new_frames, dtype=np.int64)
        chars = np.empty((n, 2), dtype=np.int64)
        chars[:, 0] = base[out_key] + new_frames_a
        chars[:, 1] = slot
        reals = np.empty((n, 4))
        reals[:, 0] = headings
        reals[:, 1:3] = roots
        reals[:, 3] = 0.0
        if any(k.seat for k in step_dbs):  # seat heights correct a seated pelvis
            seats = np.array([k.seat for k in step_dbs], dtype=np.bool_)
            for i in np.flatnonzero(seats[out_key]).tolist():
                q = queries[i]
                if q.seat_height is not None:
                    info = step_dbs[int(out_key[i])]
                    reals[i, 3] = self._seat_correction_cached(info.db, info.frames, new_frames[i], q)
        y = 2.0 * LN2 / max(self.blend_halflife, 1e-5) / 2.0
        eydt = float(np.exp(-y * dt))
        new_rot, new_av = np.empty((n, NUM_JOINTS, 3)), np.empty((n, NUM_JOINTS, 3))
        new_pos, new_vel = np.empty((n, 3)), np.empty((n, 3))
        local, pelvis, contacts = np.empty((n, NUM_JOINTS, 3, 3)), np.empty((n, 3)), np.empty((n, 2), dtype=bool)
        store = self._store
        step_poses(off_rot, off_av, off_pos, off_vel, chars, reals, sw_idx, sw_av, sw_lin, store.rot, store.aux,
                   y, float(dt), eydt, new_rot, new_av, new_pos, new_vel, local, pelvis, contacts)

        elapsed_a = np.where(changed_a, 0.0, prior.elapsed + dt)
        switches_a = prior.switches + (slot >= 0)
        searches_a = prior.searches + need_a
        out_states = []
        pose_dt = float(dt)
        new = object.__new__
        rots, avs, poss, vels = list(new_rot), list(new_av), list(new_pos), list(new_vel)
        locs, pels = list(local), list(pelvis)
        prev_l, prev_p = (last.pose_local, last.pose_pelvis) if prior is last else (
            [s.pose_local for s in states], [s.pose_pelvis for s in states])
        key_names = [k.key for k in step_dbs]
        for i, (key, frame, clock, since_i, el, dn, sw, se) in enumerate(zip(
                out_key.tolist(), new_frames, clocks_a.tolist(), since_a.tolist(), elapsed_a.tolist(), done_a.tolist(),
                switches_a.tolist(), searches_a.tolist(), strict=True)):
            st = new(MatchState)
            st.__dict__.update(
                key=key_names[key], frame=frame, root_xy=roots[i], heading=headings[i],
                frame_clock=clock, since_search=since_i, offset_rot=rots[i], offset_ang_vel=avs[i],
                offset_pos=poss[i], offset_vel=vels[i], pose_local=locs[i], pose_pelvis=pels[i],
                prev_local=prev_l[i], prev_pelvis=prev_p[i], pose_dt=pose_dt, elapsed=el, done=dn,
                switches=sw, searches=se,
            )
            out_states.append(st)
        self._last_batch = _Batch(
            states=tuple(out_states), offsets=(new_rot, new_av, new_pos, new_vel), key=out_key, frame=new_frames_a,
            clock=clocks_a, since=since_a, done=done_a, elapsed=elapsed_a, switches=switches_a, searches=searches_a,
            pose_local=locs, pose_pelvis=pels)
        return out_states, PoseBatch(pelvis, local, roots, headings, contacts)

    @staticmethod
    def _root_motion(state: MatchState, db: MotionDatabase, step_frames: float) -> tuple[NDArray[np.float64], float]:
        """Root xy and heading after the database's own root motion over the frames the clock
        passes this step (a character whose query gives no root)."""
        n_adv = math.floor(state.frame_clock + step_frames + 1e-9)
        frame = state.frame
        root_xy, heading = state.root_xy.copy(), state.heading
        for _ in range(n_adv):
            nxt, end = db.next_frame(frame)
            if end:
                break
            if nxt == frame + 1:  # root motion of the database (not across a loop seam)
                d = db.root_xy[nxt] - db.root_xy[frame]
                c, s = np.cos(heading - db.heading[frame]), np.sin(heading - db.heading[frame])
                root_xy = root_xy + np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]])
                heading += float(db.heading[nxt] - db.heading[frame])
            frame = nxt
        return root_xy, heading

    @staticmethod
    def _seat_correction_cached(db: MotionDatabase, frames: DatabaseFrames, frame: int, query: MotionQuery) -> float:
        """Raise/lower a seated pelvis by the difference between the query's seat height and
        the clip's, weighted by how far the clip has sat down (0 standing .. 1 seated)."""
        if query.seat_height is None or db.layout_name not in ("sitting", "seated"):
            return 0.0
        clip = int(db.clip_of_frame[frame])
        clip_h = float(db.targets[clip, 3])
        if not np.isfinite(clip_h):
            return 0.0
        top, bottom = (float(v) for v in frames.clip_z[clip])
        w = 1.0 if top - bottom < 0.05 else (top - float(db.pelvis[frame, 2])) / (top - bottom)
        return (float(query.seat_height) - clip_h) * w


def future_from_path(path_xy: NDArray[np.float64], frame_speed: float, heading: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Planned future root points (3,2) and headings (3,) from a polyline path (K,2) starting
    at the character, walked at ``frame_speed`` metres per frame (e.g. 1.0 / 30)."""
    path = np.asarray(path_xy, dtype=np.float64).reshape(-1, 2)
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    pts, hds = [], []
    for k in FUTURE_FRAMES:
        s = min(k * frame_speed, float(cum[-1]))
        x, y = np.interp(s, cum, path[:, 0]), np.interp(s, cum, path[:, 1])
        i = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, max(len(seg) - 1, 0)))
        if len(seg) and seg[i] > 1e-9 and s < cum[-1] - 1e-9:
            d = path[i + 1] - path[i]
            hds.append(float(np.arctan2(d[1], d[0])))
        else:
            hds.append(hds[-1] if hds else float(heading))
        pts.append((x, y))
    return np.array(pts), np.array(hds)


def foot_sliding(joint_positions: NDArray[np.float64], contacts: NDArray[np.float64], fps: float = FPS) -> float:
    """Mean horizontal speed (m/s) of the toe joints over frames where that foot is in
    contact in both the frame and the next; 0.0 when there is no such frame."""
    toes = np.asarray(joint_positions)[:, FOOT_JOINTS, :2]
    speed = np.linalg.norm(np.diff(toes, axis=0), axis=-1) * fps
    c = np.asarray(contacts, dtype=bool)
    both = c[1:] & c[:-1]
    return float(speed[both].mean()) if both.any() else 0.0

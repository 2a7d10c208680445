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

The batched step's parts live beside it: the query vectors (``storyteller.sim.motion.query_vectors``),
the grouped searches (``storyteller.sim.motion.frame_search``), the clip tables, root motion and seat
correction (``storyteller.sim.motion.clip_playback``) and the compiled kernels (``storyteller.sim.motion.kernels``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import NUM_JOINTS, forward_kinematics
from storyteller.sim.motion.action_labels import database_key
from storyteller.sim.motion.clip_playback import ClipTables, clip_tables, root_motion, seat_correction
from storyteller.sim.motion.clips import FPS
from storyteller.sim.motion.database import MotionDatabase
from storyteller.sim.motion.frame_search import search_frames
from storyteller.sim.motion.frames import (
    DatabaseFrames,
    FrameTable,
    StepDatabase,
    feature_sources,
    shared_frames,
    shared_store,
    shared_table,
)
from storyteller.sim.motion.inertialization import LN2
from storyteller.sim.motion.kernels import advance_clips, step_poses
from storyteller.sim.motion.query_vectors import pose_joints, query_features_many


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
        velocities: NDArray[np.float64] = pose_joints([self])[1][0]
        return velocities


_SwitchRows = tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]
"""``step_poses``'s switch rows: (source, destination) global frames (M,2), their angular (2,M,22,3)
and linear (2,M,3) motion."""
_NO_SWITCH: _SwitchRows = (np.empty((0, 2), dtype=np.int64), np.empty((2, 0, NUM_JOINTS, 3)), np.empty((2, 0, 3)))


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
        self._clip_arrays: ClipTables | None = None  # see _clip_tables
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

    def _query_features_many(self, db: MotionDatabase, states: Sequence[MatchState], queries: Sequence[MotionQuery],
                             roots: Sequence[NDArray[np.float64]], headings: Sequence[float]) -> NDArray[np.float64]:
        """Raw query vectors (M,D) for characters searching ``db`` (``query_features_many``)."""
        return query_features_many(self.frames, db, states, queries, roots, headings)

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

    def step_many(self, states: Sequence[MatchState], queries: Sequence[MotionQuery],
                  dt: float) -> tuple[list[MatchState], list[Pose]]:
        """Advance several independent characters by ``dt`` seconds, batched: searches are
        grouped per database; the clip bookkeeping, inertialization, the output poses and the
        query features run in compiled kernels over all characters (``storyteller.sim.motion.kernels``).
        Same result as ``step`` on each character, and as the numpy version
        (``storyteller.benchmark.support.motion_reference``)."""
        out_states, batch = self.step_batch(states, queries, dt)
        return out_states, batch.poses()

    def _clip_tables(self) -> ClipTables:
        """``clip_tables`` of the databases used so far, rebuilt when one is added."""
        n_keys = len(self._step_dbs)
        if self._clip_arrays is None or self._clip_arrays_for != n_keys:
            self._clip_arrays = clip_tables(self._step_dbs)
            self._clip_arrays_for = n_keys
        return self._clip_arrays

    def step_batch(self, states: Sequence[MatchState], queries: Sequence[MotionQuery],
                   dt: float) -> tuple[list[MatchState], PoseBatch]:
        """``step_many`` with the poses as arrays (``PoseBatch``), for callers that use them
        as arrays (the world's frame assembly): no per-character ``Pose`` objects.

        Phases: advance every clip (``advance_clips``), place the roots, search (grouped per
        database), blend the switches and pose everyone (``step_poses``), then the new states."""
        if len(states) != len(queries):
            raise ValueError(f"{len(states)} states but {len(queries)} queries")
        n = len(states)
        if n == 0:
            return [], PoseBatch(np.empty((0, 3)), np.empty((0, NUM_JOINTS, 3, 3)), [], [], np.empty((0, 2), dtype=bool))
        step_frames = dt * FPS
        by_label = self._by_label
        infos = [by_label.get((q.label, q.seated)) or self._query_key(q) for q in queries]
        prior = self._prior(states)
        base, nxt, end, loops, completes, entry_key = self._clip_tables()
        info_idx = np.array([k.index for k in infos], dtype=np.int64)
        force = np.array([q.force_search for q in queries], dtype=np.bool_)
        frames_a, clocks_a, since_a, need_a, changed_a, entry_a, done_a = advance_clips(
            prior.frame, prior.clock, prior.since, prior.done, prior.key, info_idx, force, float(step_frames),
            self.search_interval, base, nxt, end, loops, completes, entry_key)
        roots, headings = self._roots(states, queries, prior.key, step_frames)
        frames = frames_a.tolist()
        new_frames, switched = search_frames(self.frames, states, queries, roots, headings, infos, need_a, frames,
                                             changed_a.tolist(), entry_a.tolist(), self.continuation_window)
        out_key, slot, done_a, switch_rows = self._switches(prior, infos, frames, new_frames, switched, done_a)
        chars = np.empty((n, 2), dtype=np.int64)
        chars[:, 0] = base[out_key] + np.array(new_frames, dtype=np.int64)
        chars[:, 1] = slot
        reals = self._reals(queries, roots, headings, out_key, new_frames)
        new_offsets, local, pelvis, contacts = self._poses(prior, states, chars, reals, switch_rows, dt)
        clips = _Batch(states=(), key=out_key, frame=np.array(new_frames, dtype=np.int64), clock=clocks_a,
                       since=since_a, done=done_a, elapsed=np.where(changed_a, 0.0, prior.elapsed + dt),
                       switches=prior.switches + (slot >= 0), searches=prior.searches + need_a)
        out_states = self._new_states(prior, states, clips, roots, headings, new_offsets, local, pelvis, dt)
        return out_states, PoseBatch(pelvis, local, roots, headings, contacts)

    def _prior(self, states: Sequence[MatchState]) -> _Batch:
        """The array fields of ``states``: the last step's own arrays when handed its very states back."""
        last = self._last_batch
        if last is not None and len(last.states) == len(states) and all(
                a is b for a, b in zip(last.states, states, strict=True)):
            return last  # the very states returned last time: their fields are rows of these arrays
        keys = self._keys
        return _Batch.of(states, [(keys.get(s.key) or self._key(s.key)).index for s in states])

    def _roots(self, states: Sequence[MatchState], queries: Sequence[MotionQuery], prior_key: NDArray[np.int64],
               step_frames: float) -> tuple[list[NDArray[np.float64]], list[float]]:
        """Each character's root xy and heading this step: the query's, else the database's root motion."""
        step_dbs = self._step_dbs
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
                s = states[i]
                root_xy, heading = root_motion(step_dbs[int(prior_key[i])].db, s.frame, s.frame_clock, s.root_xy,
                                               s.heading, step_frames)
                if q_root is not None:
                    root_xy = np.asarray(q_root, dtype=np.float64).reshape(2)
                if q_head is not None:
                    heading = float(q_head)
                roots.append(root_xy)
                headings.append(float(heading))
        return roots, headings

    def _switches(self, prior: _Batch, infos: Sequence[StepDatabase], frames: list[int], new_frames: list[int],
                  switched: list[int], done: NDArray[np.bool_]) -> tuple[
                      NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_], _SwitchRows]:
        """Each character's database after the searches, its row among the switches (-1: none),
        its done flag (a switch clears it) and the switches' source / destination frames and motion."""
        step_dbs = self._step_dbs
        curs = [step_dbs[k] for k in prior.key.tolist()]
        out_key = prior.key.copy()
        slot = np.full(len(frames), -1, dtype=np.int64)
        done = done.copy()
        if not switched:
            return out_key, slot, done, _NO_SWITCH
        m = len(switched)
        sw_idx = np.empty((m, 2), dtype=np.int64)
        sw_av, sw_lin = np.empty((2, m, NUM_JOINTS, 3)), np.empty((2, m, 3))
        for r, i in enumerate(switched):
            slot[i] = r
            src, dst = curs[i], infos[i]
            sf, df = frames[i], new_frames[i]
            sw_idx[r] = src.base + sf, dst.base + df
            (sw_av[0, r], sw_lin[0, r]), (sw_av[1, r], sw_lin[1, r]) = src.frames.motion(sf), dst.frames.motion(df)
            done[i] = False
            out_key[i] = dst.index
        return out_key, slot, done, (sw_idx, sw_av, sw_lin)

    def _reals(self, queries: Sequence[MotionQuery], roots: Sequence[NDArray[np.float64]], headings: list[float],
               out_key: NDArray[np.int64], new_frames: list[int]) -> NDArray[np.float64]:
        """``step_poses``'s per-character reals: heading, root xy and the seated pelvis correction."""
        step_dbs = self._step_dbs
        reals = np.empty((len(queries), 4))
        reals[:, 0] = headings
        reals[:, 1:3] = roots
        reals[:, 3] = 0.0
        if any(k.seat for k in step_dbs):  # seat heights correct a seated pelvis
            seats = np.array([k.seat for k in step_dbs], dtype=np.bool_)
            for i in np.flatnonzero(seats[out_key]).tolist():
                q = queries[i]
                if q.seat_height is not None:
                    info = step_dbs[int(out_key[i])]
                    reals[i, 3] = seat_correction(info.db, info.frames, new_frames[i], q.seat_height)
        return reals

    def _poses(self, prior: _Batch, states: Sequence[MatchState], chars: NDArray[np.int64], reals: NDArray[np.float64],
               switch_rows: _SwitchRows, dt: float) -> tuple[
                   tuple[NDArray[np.float64], ...], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """The inertialization offsets after this step and the output poses (``step_poses``):
        offsets (rotation, angular velocity, pelvis, pelvis velocity), local rotations, pelvis, contacts."""
        if prior is self._last_batch:
            off_rot, off_av, off_pos, off_vel = prior.offsets
        else:
            off_rot, off_av, off_pos, off_vel = (
                np.ascontiguousarray(np.stack([getattr(s, f) for s in states]), dtype=np.float64)
                for f in ("offset_rot", "offset_ang_vel", "offset_pos", "offset_vel"))
        n = len(states)
        sw_idx, sw_av, sw_lin = switch_rows
        y = 2.0 * LN2 / max(self.blend_halflife, 1e-5) / 2.0
        eydt = float(np.exp(-y * dt))
        new_rot, new_av = np.empty((n, NUM_JOINTS, 3)), np.empty((n, NUM_JOINTS, 3))
        new_pos, new_vel = np.empty((n, 3)), np.empty((n, 3))
        local, pelvis, contacts = np.empty((n, NUM_JOINTS, 3, 3)), np.empty((n, 3)), np.empty((n, 2), dtype=bool)
        store = self._store
        step_poses(off_rot, off_av, off_pos, off_vel, chars, reals, sw_idx, sw_av, sw_lin, store.rot, store.aux,
                   y, float(dt), eydt, new_rot, new_av, new_pos, new_vel, local, pelvis, contacts)
        return (new_rot, new_av, new_pos, new_vel), local, pelvis, contacts

    def _new_states(self, prior: _Batch, states: Sequence[MatchState], clips: _Batch,
                    roots: Sequence[NDArray[np.float64]], headings: Sequence[float],
                    offsets: tuple[NDArray[np.float64], ...], local: NDArray[np.float64], pelvis: NDArray[np.float64],
                    dt: float) -> list[MatchState]:
        """The states after this step (``clips``: their array fields), kept as the next step's prior."""
        out_states = []
        pose_dt = float(dt)
        new = object.__new__
        new_rot, new_av, new_pos, new_vel = offsets
        rots, avs, poss, vels = list(new_rot), list(new_av), list(new_pos), list(new_vel)
        locs, pels = list(local), list(pelvis)
        prev_l, prev_p = (prior.pose_local, prior.pose_pelvis) if prior is self._last_batch else (
            [s.pose_local for s in states], [s.pose_pelvis for s in states])
        key_names = [k.key for k in self._step_dbs]
        for i, (key, frame, clock, since_i, el, dn, sw, se) in enumerate(zip(
                clips.key.tolist(), clips.frame.tolist(), clips.clock.tolist(), clips.since.tolist(),
                clips.elapsed.tolist(), clips.done.tolist(), clips.switches.tolist(), clips.searches.tolist(),
                strict=True)):
            st = new(MatchState)
            st.__dict__.update(
                key=key_names[key], frame=frame, root_xy=roots[i], heading=headings[i],
                frame_clock=clock, since_search=since_i, offset_rot=rots[i], offset_ang_vel=avs[i],
                offset_pos=poss[i], offset_vel=vels[i], pose_local=locs[i], pose_pelvis=pels[i],
                prev_local=prev_l[i], prev_pelvis=prev_p[i], pose_dt=pose_dt, elapsed=el, done=dn,
                switches=sw, searches=se,
            )
            out_states.append(st)
        self._last_batch = replace(clips, states=tuple(out_states), offsets=offsets, pose_local=locs, pose_pelvis=pels)
        return out_states

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
import weakref
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from sim.action_labels import database_key, family_of
from sim.inertialization import (
    angular_velocity,
    apply_rotation_offsets,
    decay_spring,
    transition_offsets,
    transition_offsets_linear,
)
from sim.motion_clips import FOOT_JOINTS, FPS
from sim.motion_database import MotionDatabase
from sim.motion_features import (
    FUTURE_FRAMES,
    Control,
    assemble,
    relative_target,
    to_character_frame,
    vectors_to_character_frame,
)
from sim.procedural_rig import rot_z
from sim.skeleton import NUM_JOINTS, forward_kinematics


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
    root_xy: np.ndarray | None = None
    heading: float | None = None
    future_xy: np.ndarray | None = None
    future_heading: np.ndarray | None = None
    target_xy: np.ndarray | None = None
    target_facing: float | None = None
    seat_height: float | None = None
    force_search: bool = False


@dataclass(frozen=True)
class Pose:
    """Output pose: pelvis (3,) world; local_rotations (22,3,3) with joint 0 the world pelvis
    rotation; root_xy (2,) / heading (rad) of the character; contacts (2,) left/right foot."""

    pelvis: np.ndarray
    local_rotations: np.ndarray
    root_xy: np.ndarray
    heading: float
    contacts: np.ndarray

    def joints(self) -> np.ndarray:
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
    root_xy: np.ndarray
    heading: float
    frame_clock: float = 0.0
    since_search: int = 0
    offset_rot: np.ndarray | None = None
    offset_ang_vel: np.ndarray | None = None
    offset_pos: np.ndarray | None = None
    offset_vel: np.ndarray | None = None
    pose_local: np.ndarray | None = None
    pose_pelvis: np.ndarray | None = None
    prev_local: np.ndarray | None = None
    prev_pelvis: np.ndarray | None = None
    pose_dt: float = 0.0
    elapsed: float = 0.0
    done: bool = False
    switches: int = 0
    searches: int = 0

    @property
    def joints_world(self) -> np.ndarray | None:
        """World joint positions (22,3) of the last output pose (None before the first step)."""
        if self.pose_local is None or self.pose_pelvis is None:
            return None
        return forward_kinematics(self.pose_local, self.pose_pelvis)[0]

    @property
    def joint_vel_char(self) -> np.ndarray | None:
        """Joint velocities (22,3) m/s of the last output pose in its character frame (zeros
        after the first step; None before it)."""
        if self.pose_local is None or self.pose_pelvis is None:
            return None
        return _pose_joints([self])[1][0]


def _rot_z(theta: np.ndarray) -> np.ndarray:
    return rot_z(theta)


def _pose_joints(states: Sequence[MatchState]) -> tuple[np.ndarray, np.ndarray]:
    """World joints (M,22,3) of the states' last poses and their character-frame velocities
    (M,22,3), with one batched forward-kinematics call. Every state must have a pose."""
    m = len(states)
    has_prev = [s.prev_local is not None and s.pose_dt > 0 for s in states]
    locs = [s.pose_local for s in states] + [s.prev_local for s, h in zip(states, has_prev, strict=True) if h]
    pels = [s.pose_pelvis for s in states] + [s.prev_pelvis for s, h in zip(states, has_prev, strict=True) if h]
    joints = forward_kinematics(np.stack(locs), np.stack(pels))[0]  # type: ignore[arg-type]
    vel = np.zeros((m, NUM_JOINTS, 3))
    k = m
    for i, (s, h) in enumerate(zip(states, has_prev, strict=True)):
        if h:
            vel[i] = vectors_to_character_frame((joints[i] - joints[k]) / s.pose_dt, np.asarray(s.heading))
            k += 1
    return joints[:m], vel


@dataclass(frozen=True)
class _Frames:
    """Per-database arrays, computed once per database: F frames, C clips.

    rot (F,22,3,3) local rotations with joint 0 in the frame's character frame; pelvis (F,3)
    character frame; pair_a, pair_b (F,) the finite-difference frame pair of each frame (equal
    when the frame has no neighbour in its clip); clip_z (C,2) highest / lowest pelvis height
    per clip. ``motion(frame)`` gives the inertialization velocities, memoised per frame.
    """

    rot: np.ndarray
    pelvis: np.ndarray
    pair_a: np.ndarray
    pair_b: np.ndarray
    clip_z: np.ndarray
    _motion: dict[str, np.ndarray] = field(default_factory=dict, repr=False, compare=False)

    def motion(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """Angular velocities (22,3) rad/s and pelvis velocity (3,) m/s at ``frame``."""
        mo = self._motion
        if not mo:  # every frame at once, on first use
            a, b = self.pair_a, self.pair_b
            ang = angular_velocity(self.rot[a], self.rot[b], 1.0 / FPS)
            lin = (self.pelvis[b] - self.pelvis[a]) * FPS
            still = a == b
            ang[still] = 0.0
            lin[still] = 0.0
            mo["ang"], mo["lin"] = ang, lin
        return mo["ang"][frame], mo["lin"][frame]


@dataclass(frozen=True)
class _Table:
    """Per-database frame facts as Python lists: next frame and non-loop end (``next_frame``),
    whether the frame's clip loops, its clip id; ``completes``: the family plays non-looping
    clips through (in-place, partner, sitting); ``entry``: a switch into it searches the entry
    index."""

    nxt: list[int]
    end: list[bool]
    loops: list[bool]
    clip: list[int]
    completes: bool
    entry: bool


def _frames_of(db: MotionDatabase) -> _Frames:
    rot = np.array(db.local_rotations, dtype=float)
    rot[:, 0] = _rot_z(-np.asarray(db.heading, dtype=float)) @ rot[:, 0]
    pelvis = to_character_frame(np.asarray(db.pelvis, dtype=float)[:, None], db.root_xy, db.heading)[:, 0]
    f = np.arange(db.num_frames)
    clip = np.asarray(db.clip_of_frame, dtype=np.int64)
    ranges = np.asarray(db.clip_ranges, dtype=np.int64)
    start, end = ranges[clip, 0], ranges[clip, 1]
    loops = np.asarray(db.clip_loops, dtype=bool)[clip]
    inside = f + 1 < end
    nxt = np.where(inside, f + 1, np.where(loops, start, f))  # next_frame, vectorised
    at_end = ~inside & ~loops
    a = np.where(at_end, np.maximum(f - 1, 0), f)
    b = np.where(at_end, f, nxt)
    a = np.where((clip[a] != clip[b]) | (a == b), b, a)
    z = np.asarray(db.pelvis, dtype=float)[:, 2]
    clip_z = np.array([[z[s:e].max(), z[s:e].min()] for s, e in ranges])
    return _Frames(rot, pelvis, a, b, clip_z.reshape(-1, 2))


_FRAMES_CACHE: dict[int, tuple[weakref.ref[np.ndarray], _Frames]] = {}


def _shared_frames(db: MotionDatabase) -> _Frames:
    """``_frames_of`` memoised per database content object (the frame-rotation array, which
    wrappers of the same database share), so matchers built over the same databases reuse it."""
    arr = db.local_rotations
    hit = _FRAMES_CACHE.get(id(arr))
    if hit is not None and hit[0]() is arr:
        return hit[1]
    for k in [k for k, (ref, _f) in _FRAMES_CACHE.items() if ref() is None]:
        del _FRAMES_CACHE[k]  # databases that are gone
    out = _frames_of(db)
    _FRAMES_CACHE[id(arr)] = (weakref.ref(arr), out)
    return out


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
        self._frames: dict[str, _Frames] = {}
        self._tables: dict[str, _Table] = {}
        # (states returned by the last step_many, their offset arrays): lets the next call skip
        # re-stacking per-character offsets when it gets those very states back
        self._last_batch: tuple[tuple[MatchState, ...], tuple[np.ndarray, ...]] | None = None

    def database(self, label: str, seated: bool = False) -> MotionDatabase:
        key = database_key(label, seated)
        db = self.databases.get(key)
        if db is None:
            raise MotionMatchingError(f"no motion database for {key!r}; loaded: {sorted(self.databases)}")
        return db

    def frames(self, key: str) -> _Frames:
        """Cached per-database arrays (character-frame rotations, pelvis, velocities)."""
        out = self._frames.get(key)
        if out is None:
            out = self._frames[key] = _shared_frames(self.databases[key])
        return out

    def _table(self, key: str) -> _Table:
        """Per-database frame tables as Python lists (cheap per-character lookups)."""
        out = self._tables.get(key)
        if out is None:
            db = self.databases[key]
            clip = [int(c) for c in db.clip_of_frame]
            steps = [db.next_frame(f) for f in range(db.num_frames)]
            loops = [bool(db.clip_loops[c]) for c in clip]
            fam = family_of(key)
            out = self._tables[key] = _Table(
                nxt=[f for f, _ in steps], end=[e for _, e in steps], loops=loops, clip=clip,
                completes=fam in ("in_place", "partner", "sitting"),
                entry=fam in ("in_place", "partner") and not bool(np.asarray(db.clip_loops).all()),
            )
        return out

    def initial_state(self, label: str, root_xy: Sequence[float], heading: float, seated: bool = False) -> MatchState:
        db = self.database(label, seated)
        frame = int(np.flatnonzero(db.searchable)[0])
        z = np.zeros((NUM_JOINTS, 3))
        return MatchState(db.key, frame, np.asarray(root_xy, dtype=float).reshape(2), float(heading),
                          offset_rot=z, offset_ang_vel=z, offset_pos=np.zeros(3), offset_vel=np.zeros(3))

    def _control(self, state: MatchState, query: MotionQuery, root_xy: np.ndarray, heading: float) -> Control:
        if query.future_xy is not None:
            fut_xy = np.asarray(query.future_xy, dtype=float).reshape(3, 2)
            fut_h = (np.full(3, heading) if query.future_heading is None
                     else np.asarray(query.future_heading, dtype=float).reshape(3))
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
                             roots: Sequence[np.ndarray], headings: Sequence[float]) -> np.ndarray:
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
                                          np.array([headings[i] for i in posed], dtype=float))
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
                       root_xy: np.ndarray, heading: float) -> np.ndarray:
        """Raw query vector: the pose part from the last output pose, the control part from the query."""
        return self._query_features_many(db, [state], [query], [np.asarray(root_xy, dtype=float)], [float(heading)])[0]

    def step(self, state: MatchState, query: MotionQuery, dt: float) -> tuple[MatchState, Pose]:
        """Advance one character by ``dt`` seconds. Pure: returns the new state and pose."""
        states, poses = self.step_many([state], [query], dt)
        return states[0], poses[0]

    def step_many(self, states: Sequence[MatchState], queries: Sequence[MotionQuery],
                  dt: float) -> tuple[list[MatchState], list[Pose]]:
        """Advance several independent characters by ``dt`` seconds, batched: searches are
        grouped per database, forward kinematics, inertialization and pose assembly run once
        over all characters. Same result as ``step`` on each character."""
        if len(states) != len(queries):
            raise ValueError(f"{len(states)} states but {len(queries)} queries")
        n = len(states)
        if n == 0:
            return [], []
        dbs = [self.database(q.label, q.seated) for q in queries]
        clocks, roots, headings, frames, since = [], [], [], [], []
        changed, completing, entry, done, need, n_advs = [], [], [], [], [], []
        step_frames = dt * FPS
        for state, query, db in zip(states, queries, dbs, strict=True):
            cur = self.databases[state.key]
            tab = self._table(state.key)
            clock = state.frame_clock + step_frames
            n_adv = math.floor(clock + 1e-9)
            clock -= n_adv
            frame, ended = state.frame, False
            if query.root_xy is not None and query.heading is not None:  # root given: no root motion
                nxt_of, end_of = tab.nxt, tab.end
                for _ in range(n_adv):
                    if end_of[frame]:
                        ended = True
                        break
                    frame = nxt_of[frame]
                root_xy = np.asarray(query.root_xy, dtype=float).reshape(2)
                heading = float(query.heading)
            else:
                root_xy, heading = state.root_xy.copy(), state.heading
                for _ in range(n_adv):
                    nxt, end = cur.next_frame(frame)
                    if end:
                        ended = True
                        break
                    if nxt == frame + 1:  # root motion of the database (not across a loop seam)
                        d = cur.root_xy[nxt] - cur.root_xy[frame]
                        c, s = np.cos(heading - cur.heading[frame]), np.sin(heading - cur.heading[frame])
                        root_xy = root_xy + np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]])
                        heading += float(cur.heading[nxt] - cur.heading[frame])
                    frame = nxt
                if query.root_xy is not None:
                    root_xy = np.asarray(query.root_xy, dtype=float).reshape(2)
                if query.heading is not None:
                    heading = float(query.heading)
            ch = db.key != state.key
            new_tab = self._table(db.key)
            comp = False
            if not ch:
                comp = new_tab.completes and not new_tab.loops[frame]
            dn = state.done and not ch
            sn = state.since_search + n_adv
            periodic = sn >= self.search_interval and not comp  # completing actions play through
            nd = ch or query.force_search or periodic or (ended and not comp)
            if ended and comp:
                dn = True
                nd = ch or query.force_search
            clocks.append(clock)
            roots.append(root_xy)
            headings.append(float(heading))
            frames.append(frame)
            since.append(0 if nd else sn)
            changed.append(ch)
            completing.append(comp)
            entry.append(ch and new_tab.entry)
            done.append(dn)
            need.append(nd)
            n_advs.append(n_adv)

        # searches, grouped per (database, entry index)
        best = np.full(n, -1, dtype=np.int64)
        groups: dict[tuple[str, bool], list[int]] = {}
        for i in range(n):
            if need[i]:
                groups.setdefault((dbs[i].key, entry[i]), []).append(i)
        for (_key, ent), members in groups.items():
            db = dbs[members[0]]
            raw = self._query_features_many(db, [states[i] for i in members], [queries[i] for i in members],
                                            [roots[i] for i in members], [headings[i] for i in members])
            if len(members) == 1:
                best[members[0]] = db.search(raw[0], entry=ent)[0]
            else:
                index = db.entry_index if ent else db.index
                best[np.array(members)] = index.query_many(db.normalize(raw))[0]

        last = self._last_batch
        if last is not None and len(last[0]) == n and all(a is b for a, b in zip(last[0], states, strict=True)):
            # the very states returned by the previous call: their offsets are rows of these arrays
            off_rot, off_av, off_pos, off_vel = (x.copy() for x in last[1])
        else:
            off_rot = np.stack([s.offset_rot for s in states])  # type: ignore[arg-type]
            off_av = np.stack([s.offset_ang_vel for s in states])  # type: ignore[arg-type]
            off_pos = np.stack([s.offset_pos for s in states])  # type: ignore[arg-type]
            off_vel = np.stack([s.offset_vel for s in states])  # type: ignore[arg-type]
        new_keys = [s.key for s in states]
        new_frames = list(frames)
        switched: list[int] = []
        for i in range(n):
            if not need[i]:
                continue
            b, db, frame = int(best[i]), dbs[i], frames[i]
            clip_of = self._table(db.key).clip
            same_clip = not changed[i] and clip_of[b] == clip_of[frame]
            if not (same_clip and 0 <= b - frame <= self.continuation_window):
                switched.append(i)
        if switched:
            sw = np.array(switched)
            src = [self.frames(states[i].key) for i in switched]
            dst = [self.frames(dbs[i].key) for i in switched]
            sf = [frames[i] for i in switched]
            df = [int(best[i]) for i in switched]
            src_mo = [f.motion(k) for f, k in zip(src, sf, strict=True)]
            dst_mo = [f.motion(k) for f, k in zip(dst, df, strict=True)]
            src_rot = np.stack([f.rot[k] for f, k in zip(src, sf, strict=True)])
            dst_rot = np.stack([f.rot[k] for f, k in zip(dst, df, strict=True)])
            off_rot[sw], off_av[sw] = transition_offsets(off_rot[sw], off_av[sw], src_rot,
                                                         np.stack([m[0] for m in src_mo]), dst_rot,
                                                         np.stack([m[0] for m in dst_mo]))
            off_pos[sw], off_vel[sw] = transition_offsets_linear(
                off_pos[sw], off_vel[sw], np.stack([f.pelvis[k] for f, k in zip(src, sf, strict=True)]),
                np.stack([m[1] for m in src_mo]), np.stack([f.pelvis[k] for f, k in zip(dst, df, strict=True)]),
                np.stack([m[1] for m in dst_mo]))
            for i, k in zip(switched, df, strict=True):
                new_keys[i], new_frames[i] = dbs[i].key, k
                done[i] = False
        off_rot, off_av = decay_spring(off_rot, off_av, self.blend_halflife, dt)
        off_pos, off_vel = decay_spring(off_pos, off_vel, self.blend_halflife, dt)

        out_frames = [self.frames(k) for k in new_keys]
        rot_c = apply_rotation_offsets(off_rot, np.stack([f.rot[k] for f, k in zip(out_frames, new_frames, strict=True)]))
        pelvis_c = np.stack([f.pelvis[k] for f, k in zip(out_frames, new_frames, strict=True)]) + off_pos
        pelvis_c[:, 2] += [self._seat_correction_cached(self.databases[k], out_frames[i], new_frames[i], queries[i])
                           for i, k in enumerate(new_keys)]
        head = np.array(headings)
        root = np.stack(roots)
        rz = _rot_z(head)
        local = rot_c
        local[:, 0] = rz @ rot_c[:, 0]
        c, s = rz[:, 0, 0], rz[:, 1, 0]
        pelvis = np.stack([root[:, 0] + (c * pelvis_c[:, 0] - s * pelvis_c[:, 1]),
                           root[:, 1] + (s * pelvis_c[:, 0] + c * pelvis_c[:, 1]), pelvis_c[:, 2]], axis=-1)
        switched_set = set(switched)
        out_states, poses = [], []
        for i, state in enumerate(states):
            out_db = self.databases[new_keys[i]]
            pose = Pose(pelvis[i], local[i], roots[i], headings[i], out_db.contacts[new_frames[i]].copy())
            poses.append(pose)
            out_states.append(MatchState(
                key=new_keys[i], frame=new_frames[i], root_xy=roots[i], heading=headings[i],
                frame_clock=clocks[i], since_search=since[i], offset_rot=off_rot[i], offset_ang_vel=off_av[i],
                offset_pos=off_pos[i], offset_vel=off_vel[i], pose_local=local[i], pose_pelvis=pelvis[i],
                prev_local=state.pose_local, prev_pelvis=state.pose_pelvis, pose_dt=float(dt),
                elapsed=0.0 if changed[i] else state.elapsed + dt, done=done[i],
                switches=state.switches + (1 if i in switched_set else 0), searches=state.searches + int(need[i]),
            ))
        self._last_batch = (tuple(out_states), (off_rot, off_av, off_pos, off_vel))
        return out_states, poses

    @staticmethod
    def _seat_correction_cached(db: MotionDatabase, frames: _Frames, frame: int, query: MotionQuery) -> float:
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


def future_from_path(path_xy: np.ndarray, frame_speed: float, heading: float) -> tuple[np.ndarray, np.ndarray]:
    """Planned future root points (3,2) and headings (3,) from a polyline path (K,2) starting
    at the character, walked at ``frame_speed`` metres per frame (e.g. 1.0 / 30)."""
    path = np.asarray(path_xy, dtype=float).reshape(-1, 2)
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


def foot_sliding(joint_positions: np.ndarray, contacts: np.ndarray, fps: float = FPS) -> float:
    """Mean horizontal speed (m/s) of the toe joints over frames where that foot is in
    contact in both the frame and the next; 0.0 when there is no such frame."""
    toes = np.asarray(joint_positions)[:, FOOT_JOINTS, :2]
    speed = np.linalg.norm(np.diff(toes, axis=0), axis=-1) * fps
    c = np.asarray(contacts, dtype=bool)
    both = c[1:] & c[:-1]
    return float(speed[both].mean()) if both.any() else 0.0

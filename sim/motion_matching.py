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

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

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
    """Per-character matcher state (immutable; ``step`` returns a new one)."""

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
    joints_world: np.ndarray | None = None
    joint_vel_char: np.ndarray | None = None
    elapsed: float = 0.0
    done: bool = False
    switches: int = 0
    searches: int = 0


def _char_rotations(db: MotionDatabase, frame: int) -> np.ndarray:
    """Local rotations of a frame with joint 0 expressed in the frame's character frame."""
    rot = db.local_rotations[frame].copy()
    rot[0] = rot_z(-db.heading[frame]) @ rot[0]
    return rot


def _char_pelvis(db: MotionDatabase, frame: int) -> np.ndarray:
    p = db.pelvis[frame]
    return to_character_frame(p[None], db.root_xy[frame], np.asarray(db.heading[frame]))[0]


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

    def database(self, label: str, seated: bool = False) -> MotionDatabase:
        key = database_key(label, seated)
        db = self.databases.get(key)
        if db is None:
            raise MotionMatchingError(f"no motion database for {key!r}; loaded: {sorted(self.databases)}")
        return db

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

    def query_features(self, db: MotionDatabase, state: MatchState, query: MotionQuery,
                       root_xy: np.ndarray, heading: float) -> np.ndarray:
        """Raw query vector: the pose part from the last output pose, the control part from the query."""
        if state.joints_world is None or state.joint_vel_char is None:
            cur = self.databases[state.key]
            pos = forward_kinematics(_char_rotations(cur, state.frame), _char_pelvis(cur, state.frame))[0]
            vel = np.zeros((NUM_JOINTS, 3))
        else:
            pos = to_character_frame(state.joints_world, root_xy, np.asarray(heading))
            vel = state.joint_vel_char
        return assemble(db.layout_name, pos, vel, self._control(state, query, root_xy, heading))

    def step(self, state: MatchState, query: MotionQuery, dt: float) -> tuple[MatchState, Pose]:
        """Advance one character by ``dt`` seconds. Pure: returns the new state and pose."""
        db = self.database(query.label, query.seated)
        cur = self.databases[state.key]
        clock = state.frame_clock + dt * FPS
        n_adv = int(np.floor(clock + 1e-9))
        clock -= n_adv
        frame, ended = state.frame, False
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

        changed = db.key != state.key
        completing = False
        if not changed:
            completing = family_of(db.key) in ("in_place", "partner", "sitting") and not bool(
                db.clip_loops[int(db.clip_of_frame[frame])])
        enter_from_start = changed and family_of(db.key) in ("in_place", "partner") and not bool(db.clip_loops.all())
        done = state.done and not changed
        since = state.since_search + n_adv
        periodic = since >= self.search_interval and not completing  # completing actions play through
        need = changed or query.force_search or periodic or (ended and not completing)
        if ended and completing:
            done = True
            need = changed or query.force_search
        off_rot, off_av = state.offset_rot, state.offset_ang_vel
        off_pos, off_vel = state.offset_pos, state.offset_vel
        assert off_rot is not None and off_av is not None and off_pos is not None and off_vel is not None
        switches, searches = state.switches, state.searches
        new_key, new_frame = state.key, frame
        if need:
            searches += 1
            since = 0
            best, _ = db.search(self.query_features(db, state, query, root_xy, heading), entry=enter_from_start)
            same_clip = not changed and db.clip_of_frame[best] == db.clip_of_frame[frame]
            if not (same_clip and 0 <= best - frame <= self.continuation_window):
                src_rot, src_av, src_pos, src_vel = self._frame_motion(cur, frame)
                dst_rot, dst_av, dst_pos, dst_vel = self._frame_motion(db, best)
                off_rot, off_av = transition_offsets(off_rot, off_av, src_rot, src_av, dst_rot, dst_av)
                off_pos, off_vel = transition_offsets_linear(off_pos, off_vel, src_pos, src_vel, dst_pos, dst_vel)
                new_key, new_frame = db.key, int(best)
                switches += 1
                done = False
        off_rot, off_av = decay_spring(off_rot, off_av, self.blend_halflife, dt)
        off_pos, off_vel = decay_spring(off_pos, off_vel, self.blend_halflife, dt)
        out_db = self.databases[new_key]
        rot_c = apply_rotation_offsets(off_rot, _char_rotations(out_db, new_frame))
        pelvis_c = _char_pelvis(out_db, new_frame) + off_pos
        pelvis_c[2] += self._seat_correction(out_db, new_frame, query)
        rz = rot_z(heading)
        local = rot_c.copy()
        local[0] = rz @ rot_c[0]
        pelvis = np.array([*(root_xy + rz[:2, :2] @ pelvis_c[:2]), pelvis_c[2]])
        pose = Pose(pelvis, local, root_xy, heading, out_db.contacts[new_frame].copy())
        joints = pose.joints()
        if state.joints_world is not None and dt > 0:
            vel = vectors_to_character_frame((joints - state.joints_world) / dt, np.asarray(heading))
        else:
            vel = np.zeros((NUM_JOINTS, 3))
        elapsed = 0.0 if changed else state.elapsed + dt
        new_state = replace(
            state, key=new_key, frame=new_frame, root_xy=root_xy, heading=heading, frame_clock=clock,
            since_search=since, offset_rot=off_rot, offset_ang_vel=off_av, offset_pos=off_pos,
            offset_vel=off_vel, joints_world=joints, joint_vel_char=vel, elapsed=elapsed, done=done,
            switches=switches, searches=searches,
        )
        return new_state, pose

    def step_many(self, states: Sequence[MatchState], queries: Sequence[MotionQuery],
                  dt: float) -> tuple[list[MatchState], list[Pose]]:
        """Advance several characters (independent; same result as calling ``step`` on each)."""
        out = [self.step(s, q, dt) for s, q in zip(states, queries, strict=True)]
        return [s for s, _ in out], [p for _, p in out]

    @staticmethod
    def _frame_motion(db: MotionDatabase, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Character-frame rotations, angular velocities, pelvis offset and its velocity."""
        nxt, end = db.next_frame(frame)
        a, b = (frame, nxt) if not end else (max(frame - 1, 0), frame)
        if db.clip_of_frame[a] != db.clip_of_frame[b] or a == b:
            a = b
        rot_a, rot_b = _char_rotations(db, a), _char_rotations(db, b)
        av = angular_velocity(rot_a, rot_b, 1.0 / FPS) if a != b else np.zeros((NUM_JOINTS, 3))
        pa, pb = _char_pelvis(db, a), _char_pelvis(db, b)
        pv = (pb - pa) * FPS if a != b else np.zeros(3)
        return _char_rotations(db, frame), av, _char_pelvis(db, frame), pv

    @staticmethod
    def _seat_correction(db: MotionDatabase, frame: int, query: MotionQuery) -> float:
        """Raise/lower a seated pelvis by the difference between the query's seat height and
        the clip's, weighted by how far the clip has sat down (0 standing .. 1 seated)."""
        if query.seat_height is None or db.layout_name not in ("sitting", "seated"):
            return 0.0
        clip = int(db.clip_of_frame[frame])
        clip_h = float(db.targets[clip, 3])
        if not np.isfinite(clip_h):
            return 0.0
        start, end = (int(v) for v in db.clip_ranges[clip])
        z = db.pelvis[start:end, 2]
        top, bottom = float(z.max()), float(z.min())
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

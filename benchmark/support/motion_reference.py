"""A frozen copy of ``MotionMatcher.step_many`` as it was before the motion kernels.

``ReferenceMotionMatcher`` is the baseline that ``benchmark/bench_motion_step.py`` times the
matcher against and that ``tests/sim/motion/test_motion_step_equivalence.py`` checks it against: the same
decisions, states and poses, bit for bit. It uses the numpy versions of forward kinematics
(``storyteller.sim.body.skeleton``) and inertialization (``storyteller.sim.motion.inertialization``), which the kernels replace
in the simulation, and keeps its own copy of the old nearest-frame scan. Not used by the
simulation itself.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Sequence

import numpy as np

from storyteller.sim.body.skeleton import NUM_JOINTS, forward_kinematics
from storyteller.sim.motion.clips import FPS
from storyteller.sim.motion.database import MotionDatabase, NearestFrameIndex, squared_distances
from storyteller.sim.motion.features import (
    Control,
    assemble,
    relative_target,
    to_character_frame,
    vectors_to_character_frame,
)
from storyteller.sim.motion.frames import DatabaseFrames
from storyteller.sim.motion.inertialization import (
    apply_rotation_offsets,
    decay_spring,
    transition_offsets,
    transition_offsets_linear,
)
from storyteller.sim.motion.matching import MatchState, MotionMatcher, MotionQuery, Pose
from storyteller.sim.motion.sources.procedural_rig import rot_z

_SCAN_CACHE: weakref.WeakKeyDictionary[NearestFrameIndex, tuple[np.ndarray, np.ndarray, float]] = (
    weakref.WeakKeyDictionary())


def _ref_scan_many(index: NearestFrameIndex, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``NearestFrameIndex.scan_many`` as it was: distances by one matrix product on centred
    rows, rows within a rounding bound of the best re-ranked exactly."""
    ix = getattr(index, "_ix", index)  # benchmark wrappers keep the index as ``_ix``
    hit = _SCAN_CACHE.get(ix)
    if hit is None:
        centered = np.ascontiguousarray(ix.rows - ix.center)
        norms = np.einsum("nd,nd->n", centered, centered)
        hit = _SCAN_CACHE[ix] = (centered, norms, float(norms.max()))
    centered, norms, max_norm = hit
    q = np.asarray(queries, dtype=float).reshape(-1, ix.rows.shape[1])
    qc = q - ix.center
    qn = np.einsum("md,md->m", qc, qc)
    approx = norms[None, :] - 2.0 * (qc @ centered.T)
    lo = approx.min(axis=1)
    slack = 1e-10 * (max_norm + qn) * max(1, ix.rows.shape[1]) + 1e-300
    out_i = np.empty(len(q), dtype=np.int64)
    out_d = np.empty(len(q))
    for m in range(len(q)):
        close = np.flatnonzero(approx[m] <= lo[m] + slack[m])
        exact = squared_distances(ix.rows[close], q[m])
        j = int(close[int(np.argmin(exact))])
        out_i[m] = ix.candidates[j]
        out_d[m] = squared_distances(ix.rows[j : j + 1], q[m])[0]
    return out_i, out_d


def _ref_search(db: MotionDatabase, raw: np.ndarray, entry: bool) -> int:
    """Best frame of ``db.search`` as it was (the scan path frozen)."""
    index = db.entry_index if entry else db.index
    if index.use_scan:
        return int(_ref_scan_many(index, db.normalize(raw)[None])[0][0])
    return db.search(raw, entry=entry)[0]


def _ref_query_many(index: NearestFrameIndex, q: np.ndarray) -> np.ndarray:
    return _ref_scan_many(index, q)[0] if index.use_scan else index.query_many(q)[0]


def _stack_all(arrays: Sequence[np.ndarray | None], what: str) -> np.ndarray:
    """``np.stack`` of arrays every state has (a missing one is a bug in the caller)."""
    present = [a for a in arrays if a is not None]
    if len(present) != len(arrays):
        raise ValueError(f"a state has no {what}")
    return np.stack(present)


def _ref_pose_joints(states: Sequence[MatchState]) -> tuple[np.ndarray, np.ndarray]:
    """World joints (M,22,3) of the states' last poses and their character-frame velocities
    (M,22,3), with one batched forward-kinematics call. Every state must have a pose."""
    m = len(states)
    has_prev = [s.prev_local is not None and s.pose_dt > 0 for s in states]
    locs = [s.pose_local for s in states] + [s.prev_local for s, h in zip(states, has_prev, strict=True) if h]
    pels = [s.pose_pelvis for s in states] + [s.prev_pelvis for s, h in zip(states, has_prev, strict=True) if h]
    joints = forward_kinematics(_stack_all(locs, "pose"), _stack_all(pels, "pose"))[0]
    vel = np.zeros((m, NUM_JOINTS, 3))
    k = m
    for i, (s, h) in enumerate(zip(states, has_prev, strict=True)):
        if h:
            vel[i] = vectors_to_character_frame((joints[i] - joints[k]) / s.pose_dt, np.asarray(s.heading))
            k += 1
    return joints[:m], vel




class ReferenceMotionMatcher(MotionMatcher):
    """``MotionMatcher`` with the step as it was before the motion kernels (the baseline)."""

    # (states returned by the last step_many, their offset arrays)
    _ref_last: tuple[tuple[MatchState, ...], tuple[np.ndarray, ...]] | None = None

    def _query_features_many(self, db: MotionDatabase, states: Sequence[MatchState], queries: Sequence[MotionQuery],
                             roots: Sequence[np.ndarray], headings: Sequence[float]) -> np.ndarray:
        """Raw query vectors (M,D) for characters searching ``db`` (one FK call for all)."""
        m = len(states)
        pos = np.empty((m, NUM_JOINTS, 3))
        vel = np.zeros((m, NUM_JOINTS, 3))
        posed = [i for i, s in enumerate(states) if s.pose_local is not None and s.pose_pelvis is not None]
        fresh = [i for i, s in enumerate(states) if s.pose_local is None or s.pose_pelvis is None]
        if posed:
            joints, v = _ref_pose_joints([states[i] for i in posed])
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
                best[members[0]] = _ref_search(db, raw[0], ent)
            else:
                index = db.entry_index if ent else db.index
                best[np.array(members)] = _ref_query_many(index, db.normalize(raw))
        for i in np.flatnonzero(best >= 0).tolist():  # the found frame stands for the last pose: play its successor
            tab = self._table(dbs[i].key)
            if not tab.end[int(best[i])]:
                best[i] = tab.nxt[int(best[i])]

        last = self._ref_last
        if last is not None and len(last[0]) == n and all(a is b for a, b in zip(last[0], states, strict=True)):
            # the very states returned by the previous call: their offsets are rows of these arrays
            off_rot, off_av, off_pos, off_vel = (x.copy() for x in last[1])
        else:
            off_rot = _stack_all([s.offset_rot for s in states], "offset_rot")
            off_av = _stack_all([s.offset_ang_vel for s in states], "offset_ang_vel")
            off_pos = _stack_all([s.offset_pos for s in states], "offset_pos")
            off_vel = _stack_all([s.offset_vel for s in states], "offset_vel")
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
        rz = rot_z(head)
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
        self._ref_last = (tuple(out_states), (off_rot, off_av, off_pos, off_vel))
        return out_states, poses

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

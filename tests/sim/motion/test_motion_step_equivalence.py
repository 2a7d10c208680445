"""The compiled motion step equals the numpy one it replaced (storyteller.benchmark.support.motion_reference).

A scripted multi-character scenario (walkers in one group and alone, idle with a target, a
completing action entered from its clip start, sitting down on root motion with a seat height,
seated idle, a partner action, label changes, forced searches, fresh states, states handed back
as copies) and a short bench_world-like crowd run are stepped through both matchers; every
decision (database key, frame, counters, flags) must be equal and every array within 1e-12
(bit-identical on this machine's BLAS; the kernels' fused multiply-adds follow its dgemm).
The kernels are also checked one by one against scipy / numpy on random inputs.
"""

from __future__ import annotations

import copy
import math
from dataclasses import fields

import numpy as np
import pytest

from storyteller.benchmark.support.motion_reference import ReferenceMotionMatcher
from storyteller.orchestrator.cache_paths import motion_cache_dir
from storyteller.sim.body.skeleton import forward_kinematics
from storyteller.sim.motion.database import MotionDatabase, NearestFrameIndex, load_databases, squared_distances
from storyteller.sim.motion.features import future_from_path
from storyteller.sim.motion.inertialization import rotation_exp, rotation_log
from storyteller.sim.motion.kernels import (
    fk_positions,
    matmul3,
    matrix_to_rotvec,
    nearest_rows,
    rotvec_to_matrix,
)
from storyteller.sim.motion.matching import MatchState, MotionMatcher, MotionQuery, Pose

DT = 1.0 / 30.0
KEYS = ["walk", "idle", "chat", "turn_on_tv", "sit_down", "sit_idle", "drink@seated"]


@pytest.fixture(scope="module")
def dbs() -> dict[str, MotionDatabase]:
    return load_databases(KEYS, cache_dir=motion_cache_dir())


def _walk_query(x: float, y: float, heading: float, speed: float, turn: float = 0.0,
                with_heading: bool = True) -> MotionQuery:
    pts = [(x, y)]
    h = heading
    for _ in range(40):  # a gently curving path ahead
        h += turn * DT * 5
        pts.append((pts[-1][0] + math.cos(h) * speed * DT * 5, pts[-1][1] + math.sin(h) * speed * DT * 5))
    fut, hd = future_from_path(np.array(pts), speed * DT, heading)
    return MotionQuery("walk", root_xy=np.array([x, y]), heading=heading, future_xy=fut,
                       future_heading=hd if with_heading else None)


def _scenario(frames: int) -> list[list[MotionQuery]]:
    """Per-frame queries of six characters (deterministic)."""
    out = []
    for f in range(frames):
        t = f * DT
        qs = []
        # 0: walks along x, stops to idle facing a target, walks on
        if 50 <= f < 90:
            qs.append(MotionQuery("idle", root_xy=np.array([1.0 * 50 * DT, 0.0]), heading=0.0,
                                  target_xy=np.array([2.0, 1.0]), target_facing=0.5, force_search=f == 50))
        else:
            x = min(t, 50 * DT) + max(0.0, t - 90 * DT)
            qs.append(_walk_query(x, 0.0, 0.0, 1.0))
        # 1: walks a circle (no future headings every other second)
        a = 0.6 * t
        qs.append(_walk_query(3 + 2 * math.cos(a), 2 * math.sin(a), a + math.pi / 2, 1.2, 0.6,
                              with_heading=int(t) % 2 == 0))
        # 2: a completing action with a target (entered from the clip start), then idle
        if f < 110:
            qs.append(MotionQuery("turn_on_tv", root_xy=np.array([-2.0, 1.0]), heading=1.0,
                                  target_xy=np.array([-1.5, 1.5]), target_facing=1.2, force_search=f == 0))
        else:
            qs.append(MotionQuery("idle", root_xy=np.array([-2.0, 1.0]), heading=1.0))
        # 3: sits down on the database's root motion, then sits (seated idle, then a seated action)
        if f < 70:
            qs.append(MotionQuery("sit_down", target_xy=np.array([4.0, -3.0]), target_facing=math.pi,
                                  seat_height=0.47))
        elif f < 120:
            qs.append(MotionQuery("idle", seated=True, root_xy=np.array([4.0, -3.0]), heading=math.pi,
                                  target_xy=np.array([4.0, -3.0]), target_facing=math.pi, seat_height=0.47))
        else:
            qs.append(MotionQuery("drink", seated=True, root_xy=np.array([4.0, -3.0]), heading=math.pi,
                                  target_xy=np.array([4.0, -3.0]), target_facing=math.pi, seat_height=0.5))
        # 4: a partner action facing someone
        qs.append(MotionQuery("chat", root_xy=np.array([0.0, -2.0]), heading=-0.3,
                              target_xy=np.array([0.8, -2.2]), target_facing=2.8, force_search=f % 45 == 0))
        # 5: walks next to 0 (the walk database searched for two at once)
        x = 0.9 * t
        qs.append(_walk_query(x, 1.0, 0.05 * math.sin(t), 0.9))
        out.append(qs)
    return out


def _initial(m: MotionMatcher) -> list[MatchState]:
    return [m.initial_state("idle", (0.0, 0.0), 0.0), m.initial_state("idle", (5.0, 0.0), math.pi / 2),
            m.initial_state("turn_on_tv", (-2.0, 1.0), 1.0), m.initial_state("sit_down", (4.5, -3.0), math.pi),
            m.initial_state("idle", (0.0, -2.0), -0.3), m.initial_state("walk", (0.0, 1.0), 0.0)]


Frames = list[tuple[list[MatchState], list[Pose]]]
"""Per frame: every character's state and pose after the step."""


def _run(m: MotionMatcher, initial: list[MatchState], queries: list[list[MotionQuery]], copy_every: int = 0) -> Frames:
    states, out = list(initial), []
    for f, qs in enumerate(queries):
        if copy_every and f % copy_every == copy_every - 1:
            states = copy.deepcopy(states)  # not the objects returned last: offsets re-stacked
        states, poses = m.step_many(states, qs, DT)
        out.append((states, poses))
    return out


def _assert_same(ref: Frames, new: Frames) -> None:
    assert len(ref) == len(new)
    for f, ((rs, rp), (ns, np_)) in enumerate(zip(ref, new, strict=True)):
        for i, (a, b) in enumerate(zip(rs, ns, strict=True)):
            for fl in fields(MatchState):
                x, y = getattr(a, fl.name), getattr(b, fl.name)
                where = f"frame {f} character {i} state.{fl.name}"
                if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
                    assert x is not None and y is not None, where
                    np.testing.assert_allclose(y, x, rtol=0, atol=1e-12, err_msg=where)
                else:
                    assert x == y, (where, x, y)
        for i, (pa, pb) in enumerate(zip(rp, np_, strict=True)):
            for fl in fields(Pose):
                where = f"frame {f} character {i} pose.{fl.name}"
                np.testing.assert_allclose(np.asarray(getattr(pb, fl.name), dtype=float),
                                           np.asarray(getattr(pa, fl.name), dtype=float), rtol=0, atol=1e-12,
                                           err_msg=where)


def test_scripted_scenario_matches_the_reference_step(dbs: dict[str, MotionDatabase]) -> None:
    queries = _scenario(160)
    ref_m, new_m = ReferenceMotionMatcher(dbs), MotionMatcher(dbs)
    ref = _run(ref_m, _initial(ref_m), queries, copy_every=37)
    new = _run(new_m, _initial(new_m), queries, copy_every=37)
    _assert_same(ref, new)
    last = new[-1][0]
    # the scenario exercised what it claims: switches, several searches each, a finished action,
    # seated databases, root motion
    assert all(s.switches >= 2 and s.searches >= 5 for s in last)
    keys = {s.key for states, _ in new for s in states}
    assert {"walk", "idle", "turn_on_tv", "sit_down", "sit_idle", "drink@seated", "chat"} <= keys
    assert any(states[2].done for states, _ in new[:110])
    assert not np.allclose(new[69][0][3].root_xy, new[0][0][3].root_xy)  # sat down on root motion


def test_a_changed_step_is_caught(dbs: dict[str, MotionDatabase]) -> None:
    """The comparison can fail: a matcher with another blend half-life differs from the reference."""
    queries = _scenario(40)
    ref_m, other = ReferenceMotionMatcher(dbs), MotionMatcher(dbs, blend_halflife=0.11)
    ref = _run(ref_m, _initial(ref_m), queries)
    new = _run(other, _initial(other), queries)
    with pytest.raises(AssertionError):
        _assert_same(ref, new)


def test_crowd_run_matches_the_reference_step() -> None:
    from storyteller.benchmark.bench_motion_step import record, replay  # the bench_world-like crowd

    all_dbs = load_databases(cache_dir=motion_cache_dir())
    rec = record(all_dbs, 6, 75, seed=3)
    _, ref = replay(ReferenceMotionMatcher(all_dbs), rec)
    _, new = replay(MotionMatcher(all_dbs), rec)
    _assert_same(ref, new)
    assert sum(s.searches for s in new[-1][0]) > len(rec.initial)


def test_kernels_match_scipy_and_numpy() -> None:
    rng = np.random.default_rng(7)
    v = np.concatenate([rng.normal(size=(3000, 3)) * 2, rng.normal(size=(500, 3)) * 1e-4, np.zeros((2, 3))])
    np.testing.assert_allclose(rotvec_to_matrix(v), rotation_exp(v), rtol=0, atol=1e-14)
    m = rotation_exp(v) @ np.swapaxes(rotation_exp(rng.normal(size=v.shape) * 0.01), -1, -2)
    m = np.concatenate([m, rotation_exp(np.array([[math.pi, 0, 0], [0, 0, math.pi - 1e-9]]))])
    np.testing.assert_allclose(matrix_to_rotvec(np.ascontiguousarray(m)), rotation_log(m), rtol=0, atol=1e-12)
    a, b = rng.normal(size=(500, 3, 3)), rng.normal(size=(500, 3, 3))
    np.testing.assert_allclose(matmul3(a, b), a @ b, rtol=0, atol=1e-14)
    local, pelvis = rotation_exp(rng.normal(size=(40, 22, 3)) * 0.7), rng.normal(size=(40, 3))
    np.testing.assert_allclose(fk_positions(local, pelvis), forward_kinematics(local, pelvis)[0], rtol=0, atol=1e-14)
    rows = rng.normal(size=(700, 9))
    rows[5] = rows[300]  # an exact tie: the lower row wins
    q = np.concatenate([rows[[300, 2]], rng.normal(size=(3, 9))])
    idx, dist = nearest_rows(np.ascontiguousarray(rows.T), q)
    for k in range(len(q)):
        d = squared_distances(rows, q[k])
        assert idx[k] == int(np.argmin(d)) and dist[k] == d[idx[k]]
    assert idx[0] == 5


def test_scan_rejects_non_finite_queries() -> None:
    index = NearestFrameIndex(np.random.default_rng(0).normal(size=(50, 4)))
    with pytest.raises(ValueError, match="non-finite"):
        index.query(np.array([0.0, np.nan, 0.0, 0.0]))


def test_frame_tables_follow_next_frame(dbs: dict[str, MotionDatabase]) -> None:
    m = MotionMatcher(dbs)
    for key, db in dbs.items():
        tab = m._table(key)
        steps = [db.next_frame(f) for f in range(db.num_frames)]
        assert tab.nxt == [f for f, _ in steps] and tab.end == [e for _, e in steps], key
        assert tab.clip == [int(c) for c in db.clip_of_frame], key
        assert tab.loops == [bool(db.clip_loops[c]) for c in tab.clip], key
    assert any(m._table("sit_down").end) and not all(m._table("sit_down").end)  # clips end at their last frame


def test_matchers_over_the_same_databases_share_one_frame_store(dbs: dict[str, MotionDatabase]) -> None:
    a, b = MotionMatcher(dbs), MotionMatcher(dict(dbs))
    assert a._store is b._store
    assert MotionMatcher({"walk": dbs["walk"]})._store is not a._store

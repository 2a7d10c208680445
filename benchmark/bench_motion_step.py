"""Motion-step benchmark: ``MotionMatcher.step_many`` vs the frozen reference, same inputs.

Records the motion queries a bench_world-like run feeds the motion layer (10 characters
walking between random targets in the Office, ``--seconds`` simulated seconds), then replays
them through ``storyteller.benchmark.support.motion_reference.ReferenceMotionMatcher`` (the step as it was before the
motion kernels) and through ``storyteller.sim.motion.matching.MotionMatcher``, each starting from the
recorded initial states and feeding its own returned states back, as the world does. Prints
microseconds per frame (all characters) for both, best of ``--reps`` alternating replays,
their ratio, whether every search decision and state counter is the same, and whether the
poses and states are bit-identical (else the largest difference).

Usage: ``python -m storyteller.benchmark.bench_motion_step [--characters 10] [--seconds 10] [--reps 10] [--seed 0]``.
"""

from __future__ import annotations

import argparse
import copy
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from storyteller.benchmark.crowd_scenario import OFFICE, REFERENCE, IdleErrands
from storyteller.benchmark.support.motion_reference import ReferenceMotionMatcher
from storyteller.orchestrator.cache_paths import motion_cache_dir
from storyteller.sim.motion.database import MotionDatabase, load_databases
from storyteller.sim.motion.matching import MatchState, MotionMatcher, MotionQuery, Pose
from storyteller.sim.paths.nav_grid import build_nav_grid
from storyteller.sim.scene.files import load_scene
from storyteller.sim.world.step import World, WorldConfig, step


@dataclass
class Recording:
    """Initial motion states and the per-frame queries of a world run."""

    initial: list[MatchState]
    queries: list[list[MotionQuery]]
    dt: float


class RecordingMotion:
    """A motion layer that records what the world asks of a matcher."""

    def __init__(self, matcher: MotionMatcher) -> None:
        self._m = matcher
        self.initial: list[MatchState] | None = None
        self.queries: list[list[MotionQuery]] = []
        self.dt = 0.0

    def initial_state(self, label: str, root_xy: Any, heading: float, seated: bool = False) -> MatchState:
        return self._m.initial_state(label, root_xy, heading, seated)

    def step(self, state: MatchState, query: MotionQuery, dt: float) -> tuple[MatchState, Pose]:
        states, poses = self.step_many([state], [query], dt)
        return states[0], poses[0]

    def step_many(self, states: Sequence[MatchState], queries: Sequence[MotionQuery],
                  dt: float) -> tuple[list[MatchState], list[Pose]]:
        if self.initial is None:
            self.initial = list(states)
        self.queries.append(copy.deepcopy(list(queries)))
        self.dt = dt
        return self._m.step_many(states, queries, dt)


def record(dbs: dict[str, MotionDatabase], n: int, frames: int, seed: int) -> Recording:
    """The motion queries of ``n`` characters walking between random idle targets (as bench_world)."""
    scene = load_scene(OFFICE)
    grid = build_nav_grid(scene)
    layer = RecordingMotion(MotionMatcher(dbs))
    errands = IdleErrands(grid, n, seed)
    world = World(scene, errands.starts, layer, grid=grid, config=WorldConfig(seed=seed, initial_capacity=frames))
    for _ in range(frames):
        _, out = step(world, errands.commands(), world.dt)
        errands.observe(out)
    assert layer.initial is not None
    return Recording(layer.initial, layer.queries, layer.dt)


def replay(matcher: MotionMatcher, rec: Recording) -> tuple[float, list[tuple[list[MatchState], list[Pose]]]]:
    """(seconds, per-frame outputs) of feeding the recording through ``matcher``."""
    states: list[MatchState] = list(rec.initial)
    outs = []
    t0 = time.perf_counter()
    for qs in rec.queries:
        states, poses = matcher.step_many(states, qs, rec.dt)
        outs.append((states, poses))
    return time.perf_counter() - t0, outs


def compare(ref: list[tuple[list[MatchState], list[Pose]]],
            new: list[tuple[list[MatchState], list[Pose]]]) -> tuple[list[str], list[str], float]:
    """(decisions that differ, arrays that differ bit for bit, largest absolute array difference)
    between two replays, per frame, character and state / pose field."""
    decisions: list[str] = []
    arrays: list[str] = []
    worst = 0.0
    for f, ((rs, rp), (ns, np_)) in enumerate(zip(ref, new, strict=True)):
        pairs = [(f"frame {f} char {i} state.{fl.name}", getattr(a, fl.name), getattr(b, fl.name))
                 for i, (a, b) in enumerate(zip(rs, ns, strict=True)) for fl in fields(MatchState)]
        pairs += [(f"frame {f} char {i} pose.{fl.name}", getattr(a, fl.name), getattr(b, fl.name))
                  for i, (a, b) in enumerate(zip(rp, np_, strict=True)) for fl in fields(Pose)]
        for where, a, b in pairs:
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if a is None or b is None or np.shape(a) != np.shape(b):
                    decisions.append(where)
                elif not np.array_equal(a, b):
                    arrays.append(where)
                    worst = max(worst, float(np.max(np.abs(np.asarray(a, float) - np.asarray(b, float)))))
            elif a != b:
                decisions.append(where)
    return decisions, arrays, worst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--characters", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--reps", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if not REFERENCE.found:
        raise SystemExit(REFERENCE.reason)
    dbs = load_databases(cache_dir=motion_cache_dir())
    for db in dbs.values():
        db.index  # noqa: B018
        db.entry_index  # noqa: B018
    rec = record(dbs, args.characters, round(args.seconds * 30), args.seed)
    frames = len(rec.queries)
    ref_m, new_m = ReferenceMotionMatcher(dbs), MotionMatcher(dbs)
    replay(ref_m, rec)  # warm-up: per-database tables, compiled kernels
    replay(new_m, rec)
    best_ref = best_new = math.inf
    ratios = []
    ref_out = new_out = None
    for _ in range(args.reps):  # alternating, so that load on the machine hits both alike
        t_ref, ref_out = replay(ref_m, rec)
        t_new, new_out = replay(new_m, rec)
        best_ref, best_new = min(best_ref, t_ref), min(best_new, t_new)
        ratios.append(t_ref / t_new)
    assert ref_out is not None and new_out is not None
    decisions, arrays, worst = compare(ref_out, new_out)
    searches = sum(s.searches for s in ref_out[-1][0])
    print(f"{args.characters} characters, {frames} frames, {searches} searches, best of {args.reps} replays")
    print(f"reference step_many: {1e6 * best_ref / frames:8.1f} us/frame")
    print(f"current   step_many: {1e6 * best_new / frames:8.1f} us/frame")
    print(f"speed-up: {best_ref / best_new:.2f}x (best vs best; median of paired replays "
          f"{float(np.median(ratios)):.2f}x)")
    print(f"same decisions: {'yes' if not decisions else 'NO'}; bit-identical poses and states: "
          f"{'yes' if not arrays else 'no'} (largest difference {worst:.1e})")
    for line in (decisions + arrays)[:20]:
        print("  differs:", line)

if __name__ == "__main__":
    main()

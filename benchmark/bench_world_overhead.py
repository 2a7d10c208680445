"""World-step overhead: the time per frame outside path planning and the motion layer.

Runs ``bench_world``'s crowd (N characters walking between random targets in the Office, real
motion matcher, windowed cooperative A*) ``--repeats`` times and splits each frame's wall time
into planning (``PathPlanner.plan``), motion (``MotionMatcher.step_batch``) and the rest of the
world step ("world": phases, path following, futures, queries, buffers, command handling).
Prints per-frame milliseconds (best of the repeats), the world time as a ratio of the motion
time measured in the same run (the baseline), and a fingerprint of the run's output (final
positions, track buffers) so that two versions of the code can be checked to produce the same
frames. ``--clock cpu`` (default) times with this process's CPU time, which other processes on
a loaded machine disturb much less than the wall clock (``--clock wall``).

Usage: ``python -m storyteller.benchmark.bench_world_overhead [--characters 10] [--seconds 10] [--repeats 5] [--clock cpu]``.
"""

from __future__ import annotations

import argparse
import hashlib
import time
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from storyteller.benchmark.crowd_scenario import OFFICE, REFERENCE, IdleErrands
from storyteller.benchmark.world_timing import Counters, TimedMotion, TimedPlanner
from storyteller.orchestrator.cache_paths import motion_cache_dir
from storyteller.sim.motion.database import MotionDatabase, load_databases
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.paths.nav_grid import NavGrid, build_nav_grid
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.step import World, WorldConfig, step

CLOCK = time.process_time


@dataclass
class OverheadCounters(Counters):
    """``world_timing``'s counters (read with this script's clock, no planning problems kept),
    and the time inside ``step``."""

    record: bool = False
    step_s: float = 0.0  # inside ``step`` (the rest of the loop is this script making commands)


def run(scene: Scene, grid: NavGrid, dbs: Mapping[str, MotionDatabase], n: int, frames: int,
        seed: int) -> tuple[float, OverheadCounters, str]:
    """(seconds, counters, output fingerprint) of one crowd run (bench_world's scenario)."""
    counters = OverheadCounters(clock=CLOCK)
    planner = TimedPlanner(grid, counters, seed=seed)
    errands = IdleErrands(grid, n, seed)
    world = World(scene, errands.starts, TimedMotion(MotionMatcher(dbs), counters), grid=grid, planner=planner,
                  config=WorldConfig(seed=seed, initial_capacity=frames))
    t0 = CLOCK()
    for _ in range(frames):
        cmds = errands.commands()
        t1 = CLOCK()
        _, out = step(world, cmds, world.dt)
        counters.step_s += CLOCK() - t1
        errands.observe(out)
    wall = CLOCK() - t0
    h = hashlib.sha256()
    b = world.buffers
    for arr in (world.positions(), b.pelvis[: b.length], b.rotations[: b.length], b.labels[: b.length],
                b.contacts[: b.length], b.events[: b.length]):
        h.update(np.ascontiguousarray(arr).tobytes())
    h.update(repr([(c.phase, c.heading) for c in world.characters.values()]).encode())
    return wall, counters, h.hexdigest()[:16]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--characters", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--clock", choices=("cpu", "wall"), default="cpu")
    args = ap.parse_args()
    if not REFERENCE.found:
        raise SystemExit(REFERENCE.reason)
    global CLOCK
    CLOCK = time.process_time if args.clock == "cpu" else time.perf_counter
    scene = load_scene(OFFICE)
    grid = build_nav_grid(scene)
    dbs = load_databases(cache_dir=motion_cache_dir())
    for db in dbs.values():
        db.index  # noqa: B018
        db.entry_index  # noqa: B018
    frames = round(args.seconds * 30)
    run(scene, grid, dbs, 10, 60, args.seed + 1)  # warm-up: first-use costs out of the timed runs
    rows = []
    prints = set()
    for _ in range(args.repeats):
        wall, c, fp = run(scene, grid, dbs, args.characters, frames, args.seed)
        prints.add(fp)
        rows.append((wall, c.plan_s, c.motion_s, wall - c.plan_s - c.motion_s, c.step_s - c.plan_s - c.motion_s))
    best = min(rows, key=lambda r: r[3])
    wall, plan, motion, world, inside = (1e3 * v / frames for v in best)
    print(f"{args.characters} characters, {frames} frames, best of {args.repeats} (by world time), {args.clock} clock:")
    print(f"  per frame: total {wall:.3f} ms | planning {plan:.3f} ms | motion {motion:.3f} ms | world {world:.3f} ms "
          f"(in step: {inside:.3f} ms; making the commands: {world - inside:.3f} ms)")
    print(f"  world share {world / wall:.0%}; world / motion (same run) {world / motion:.2f}; "
          f"RTF {frames / 30 / (best[0]):.1f}x")
    print(f"  output fingerprint {', '.join(sorted(prints))}{'' if len(prints) == 1 else ' (NOT deterministic)'}")


if __name__ == "__main__":
    main()

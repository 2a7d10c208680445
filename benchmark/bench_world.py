"""World-step performance: 1, 10, 50, 200 and 1,000 characters walking between random targets.

For each crowd size the full world step runs (cooperative paths, character phases, motion
matching) and the script prints, each next to a baseline measured in the same run:

- character-frames per second and the real-time factor (simulated seconds per wall second),
  vs the same run with brute-force motion search;
- motion search latency (mean per query), KD-tree vs brute force (same queries: both runs are
  deterministic and take the same decisions, which the script checks);
- path planning time per replan, windowed cooperative A* (window 20 steps) vs a non-windowed
  planner (window long enough to reach any goal in the scene) solving the very same planning
  problems, recorded from the windowed run;
- where the time goes: motion layer, planning, the rest of the world step.

200 characters do not fit in the Office at 0.5 m spacing (about 45 m^2 of walkable floor, at
most ~125 bodies on the 0.3 m grid), so that size runs in "Office x4": four copies of the
Office side by side (2 x 2, the reference cell overrides dropped), stated in the output; up
to 500 characters run in "Office x4", more (the 1,000-character case) in "Office x16" (4 x 4).
Sizes above ``--brute-max`` (default 200) skip the brute-force runs and the non-windowed
replan baseline (a full-horizon window on "Office x16" needs hundreds of MB of search
scratch); their columns print "-".

Each size runs ``--repeats`` times per search method (all runs are deterministic and must
agree), interleaved, and the fastest run of each method is reported: the machines are
shared, and the least disturbed run is the closest to what the code costs (the target line
also gives the median).

Each scene first gets an untimed warm-up run (``--warmup`` simulated seconds, another seed), so
that one-off first-use costs of the process (per-database motion tables, the planner's move
masks for the grid) do not land in whichever run comes first.

Usage: ``python -m storyteller.benchmark.bench_world [--sizes 1 10 50 200 1000] [--seconds 10] [--seed 0] [--repeats 3] [--warmup 2]``,
or ``python -m storyteller.benchmark.bench_world --scaling [N ...] [--scaling-seconds 10] [--repeats 2]`` (below).
The 200-character case runs half of ``--seconds``, the 1,000-character case a fifth.
Targets: 10 characters >= 30x real time on one core (issue 8); 50 characters >= 20x, 200
characters >= 5x (30,000 character-frames per second), 1,000 characters measured (issue 14).

Scaling (``--scaling``; sizes default 125 250 500 1000): the crowds walk in ONE layout, "Office
x16" (14,832 walkable cells), so that a cost growing with the crowd is not mistaken for one
growing with the floor. Per size: CPU time of the first step (it runs the first planning pass:
a goal-distance field per new goal, counted and timed by the planner wrapper) and CPU per
character-frame over the frames after it, split into planning (fields included), motion and
the rest; search expansions per agent per planning call; the fastest of the interleaved runs
(all bit-identical). A last row runs a quarter of the largest crowd in "Office x4": a quarter
of the floor, the same walkers per cell. Then one field is timed on each layout.

Measured figures (dated, with the machine's load): ``benchmark/results/2026-12-03-world-step.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from storyteller.benchmark.crowd_scenario import OFFICE, REFERENCE, tiled
from storyteller.benchmark.world_timing import Counters, crowd_world
from storyteller.orchestrator.cache_paths import motion_cache_dir
from storyteller.sim.motion.database import MotionDatabase, load_databases
from storyteller.sim.paths.cooperative_astar import PathPlanner
from storyteller.sim.paths.heuristics import goal_distances
from storyteller.sim.paths.nav_grid import NavGrid, build_nav_grid
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.step import step


@dataclass
class RunResult:
    n: int
    frames: int
    wall_s: float
    cpu_s: float
    counters: Counters
    positions: np.ndarray


def run_crowd(scene: Scene, grid: NavGrid, n: int, frames: int, seed: int, dbs: dict[str, MotionDatabase],
              brute: bool) -> RunResult:
    counters = Counters()
    world, errands = crowd_world(scene, grid, n, frames, seed, dbs, brute, counters)
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(frames):
        _, out = step(world, errands.commands(), world.dt)
        errands.observe(out)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return RunResult(n, frames, wall, cpu, counters, world.positions())


def replan_baseline(grid: NavGrid, problems: list[tuple[Any, ...]], seed: int,
                    limit: int = 60, full: bool = True) -> tuple[float, float | None, float, bool]:
    """Seconds per replan on the same recorded problems: (windowed, non-windowed (None when
    ``full`` is off), windowed with the pure-Python backend), and whether both backends
    returned identical plans."""
    picks = problems[:: max(1, len(problems) // limit)][:limit]
    long_window = math.ceil((grid.shape[0] + grid.shape[1]) * 1.5)
    planners = {"windowed": PathPlanner(grid, seed=seed), "python": PathPlanner(grid, seed=seed, backend="python")}
    if full:
        planners["full"] = PathPlanner(grid, window=long_window, seed=seed, max_expansions=200_000)
    times, plans = {}, {}
    for name, planner in planners.items():
        t0 = time.perf_counter()
        plans[name] = [planner.plan(starts, goals, statics, t0=t, order=order or None, **kw)
                       for starts, goals, statics, t, order, kw in picks]
        times[name] = (time.perf_counter() - t0) / max(1, len(picks))
    return times["windowed"], times.get("full"), times["python"], plans["windowed"] == plans["python"]


@dataclass
class ScalingRun:
    """One crowd at the fixed layout, CPU time (``time.process_time``): the first step (which
    runs the first planning pass: a goal-distance field per new goal) apart from the frames after it."""

    n: int
    frames: int
    first_s: float  # the first step
    first: Counters  # its planning and fields
    steady_s: float  # the other frames
    steady: Counters  # theirs
    positions: np.ndarray


def scaling_run(scene: Scene, grid: NavGrid, n: int, frames: int, seed: int, dbs: dict[str, MotionDatabase]) -> ScalingRun:
    """``run_crowd`` (KD-tree search) with CPU-time counters, the first step timed on its own."""
    counters = Counters(clock=time.process_time, record=False)
    world, errands = crowd_world(scene, grid, n, frames, seed, dbs, False, counters)
    c0 = time.process_time()
    _, out = step(world, errands.commands(), world.dt)
    errands.observe(out)
    c1 = time.process_time()
    first = dataclasses.replace(counters)
    for _ in range(frames - 1):
        _, out = step(world, errands.commands(), world.dt)
        errands.observe(out)
    c2 = time.process_time()
    steady = counters.since(first)
    return ScalingRun(n, frames, c1 - c0, first, c2 - c1, steady, world.positions())


def scaling(office: Scene, dbs: dict[str, MotionDatabase], sizes: Sequence[int], seconds: float, seed: int,
            repeats: int, warmup: float) -> None:
    """The scaling section: crowds of ``sizes`` in one layout ("Office x16"), plus a quarter of
    the largest crowd in "Office x4" (about the same walkers per walkable cell: does a cost
    follow the crowd's size or its density?), then the cost of one goal-distance field per layout."""
    layouts = {}
    for nx in (4, 2):
        scene = tiled(office, nx, nx)
        grid = build_nav_grid(scene)
        layouts[nx] = (scene, grid, int(np.count_nonzero(grid.component == grid.main_component)))
        if warmup > 0:
            run_crowd(scene, grid, 10, max(1, round(warmup * 30)), seed + 1, dbs, brute=False)
    cases = [(4, n) for n in sizes] + ([(2, max(sizes) // 4)] if max(sizes) >= 4 else [])
    frames = max(2, round(seconds * 30))
    runs: dict[tuple[int, int], list[ScalingRun]] = {case: [] for case in cases}
    for _ in range(max(1, repeats)):  # interleaved: every size sees the same machine
        for nx, n in cases:
            scene, grid, _ = layouts[nx]
            runs[nx, n].append(scaling_run(scene, grid, n, frames, seed, dbs))
    scene, grid, free = layouts[4]
    print()
    print(f"Scaling at one layout: {scene.name}, {free} walkable cells of {grid.cell_size} m, {frames} frames per crowd "
          f"(the first step apart), CPU time, fastest of {max(1, repeats)} interleaved runs")
    hdr = (f"{'N':>5} {'scene':<10} {'per 100 cells':>13} | {'first step s':>12} {'fields':>6} {'field s':>7} "
           f"{'rest of plan s':>14} | {'us/char-frame':>13} {'plan':>6} {'fields':>6} {'motion':>6} {'rest':>6} {'x':>5} | "
           f"{'exp/agent':>9} {'detour/plan':>11} {'new fields':>10} | same")
    print(hdr)
    print("-" * len(hdr))
    base = None
    for nx, n in cases:
        scene, grid, free = layouts[nx]
        r = min(runs[nx, n], key=lambda x: x.first_s + x.steady_s)
        same = all(np.array_equal(x.positions, r.positions) for x in runs[nx, n])
        f, c = r.first, r.steady
        cf = n * (r.frames - 1)
        per = 1e6 * r.steady_s / cf
        base = per if base is None else base
        fields_us = 1e6 * (c.field_s + c.detour_s) / cf
        print(f"{n:>5} {scene.name:<10} {100 * n / free:>13.1f} | {r.first_s:>12.2f} {f.fields:>6} {f.field_s:>7.2f} "
              f"{f.plan_s - f.field_s - f.detour_s:>14.2f} | {per:>13.1f} {1e6 * c.plan_s / cf:>6.1f} {fields_us:>6.1f} "
              f"{1e6 * c.motion_s / cf:>6.1f} {1e6 * (r.steady_s - c.plan_s - c.motion_s) / cf:>6.1f} {per / base:>5.2f} | "
              f"{c.expansions / max(1, c.planned):>9.1f} {c.detoured / max(1, c.plans):>11.1f} "
              f"{c.fields + c.detour_fields:>10} | {'yes' if same else 'NO'}", flush=True)
    print("per 100 cells: walkers per 100 walkable cells (the last row: the largest crowd's density, a quarter of")
    print("     it in a quarter of the floor). first step: CPU of the step that runs the first planning pass;")
    print("     fields: goal-distance fields it computed (one per new goal) and their CPU; rest of plan: the rest of that call.")
    print("us/char-frame: CPU per character-frame over the frames after the first step; plan: planning calls (fields")
    print("     included); fields: goal and detour fields computed then; rest: world step, events, IK, garbage collector.")
    print("     x: relative to the first row. exp/agent: search expansions per agent and planning call;")
    print("     detour/plan: walkers planned around stationary bodies per call; new fields: fields computed after the first step.")
    print("same: the interleaved runs of a size agree bit for bit.")
    field_costs(office, seed, repeats)


def field_costs(office: Scene, seed: int, repeats: int, goals: int = 40) -> None:
    """CPU per goal-distance field (``heuristics.goal_distances``, the planner's static distance
    to one goal) on "Office", "Office x4" and "Office x16"."""
    print()
    print(f"One goal-distance field (heuristics.goal_distances), {goals} random goals per layout, CPU, best of "
          f"{max(1, repeats)}:")
    print(f"{'layout':<11} {'grid':>9} {'walkable':>8} {'padded':>7} | {'us/field':>8} {'ns/cell':>7}")
    rng = np.random.default_rng(seed)
    for nx in (1, 2, 4):
        scene = office if nx == 1 else tiled(office, nx, nx)
        grid = build_nav_grid(scene)
        planner = PathPlanner(grid, seed=seed)
        cells = np.argwhere(grid.component == grid.main_component)
        gids = [planner.cell_id((int(i), int(j))) for i, j in cells[rng.choice(len(cells), goals, replace=False)]]
        ring = np.zeros((3, planner.tables.nb_id.size + 1), dtype=np.int64)
        goal_distances(gids[0], planner.tables.nb_id, planner.tables.nb_cost, ring)  # compiled / loaded before timing
        best = math.inf
        for _ in range(max(1, repeats)):
            c0 = time.process_time()
            for g in gids:
                goal_distances(g, planner.tables.nb_id, planner.tables.nb_cost, ring)
            best = min(best, (time.process_time() - c0) / goals)
        print(f"{scene.name:<11} {f'{grid.shape[0]}x{grid.shape[1]}':>9} {len(cells):>8} {planner.tables.nb_id.shape[0]:>7} | "
              f"{1e6 * best:>8.0f} {1e9 * best / len(cells):>7.1f}")


def _arguments() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 10, 50, 200, 1000])
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per run (200: half)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=3,
                    help="identical runs per size and search method, interleaved; the fastest counts")
    ap.add_argument("--warmup", type=float, default=2.0,
                    help="simulated seconds of an untimed 10-character run per scene first (0: none)")
    ap.add_argument("--brute-max", type=int, default=200,
                    help="largest size that also runs brute-force search and the non-windowed baseline")
    ap.add_argument("--scaling", type=int, nargs="*", metavar="N",
                    help="instead of the table: crowds of these sizes (default 125 250 500 1000) in one layout "
                         "(Office x16), CPU per character-frame, and the cost of one goal-distance field per layout")
    ap.add_argument("--scaling-seconds", type=float, default=10.0, help="simulated seconds per --scaling crowd")
    return ap.parse_args()


def main() -> None:
    args = _arguments()
    if not REFERENCE.found:
        raise SystemExit(REFERENCE.reason)

    office = load_scene(OFFICE)
    t0 = time.perf_counter()
    dbs = load_databases(cache_dir=motion_cache_dir())
    for db in dbs.values():  # build the search indexes now, outside the timed runs
        db.index  # noqa: B018
        db.entry_index  # noqa: B018
    print(f"motion databases: {len(dbs)} keys, {sum(d.num_frames for d in dbs.values())} frames, "
          f"loaded in {time.perf_counter() - t0:.1f} s")
    if args.scaling is not None:
        scaling(office, dbs, args.scaling or [125, 250, 500, 1000], args.scaling_seconds, args.seed, args.repeats,
                args.warmup)
        return
    grids: dict[str, tuple[Scene, NavGrid]] = {}
    hdr = (f"{'N':>4} {'scene':<10} {'frames':>6} | {'char-fr/s':>9} {'brute':>8} {'ratio':>6} | {'RTF':>6} {'brute':>6} {'cpu':>6} | "
           f"{'search us':>9} {'brute':>8} {'ratio':>6} | {'replan ms':>9} {'full':>8} {'ratio':>6} {'python':>7} {'ratio':>6} | "
           f"{'motion':>6} {'plan':>5} {'world':>5} | same")
    print()
    print(hdr)
    print("-" * len(hdr), flush=True)
    rtfs: dict[int, tuple[float, float, float, float]] = {}  # n -> RTF wall, cpu, median; char-frames/s
    for n in args.sizes:
        scene = office if n <= 120 else tiled(office, 2, 2) if n <= 500 else tiled(office, 4, 4)
        if scene.name not in grids:
            grids[scene.name] = (scene, build_nav_grid(scene))
            if args.warmup > 0:  # first-use costs paid once per process: per-database motion
                # tables and velocities, the planner's move masks for this grid
                run_crowd(scene, grids[scene.name][1], 10, max(1, round(args.warmup * 30)), args.seed + 1, dbs, brute=False)
        scene, grid = grids[scene.name]
        seconds = args.seconds if n <= 120 else args.seconds / 2 if n <= 500 else args.seconds / 5
        row, rtfs[n] = _size_row(scene, grid, n, round(seconds * 30), n <= args.brute_max, args.seed, args.repeats, dbs)
        print(row, flush=True)
    _print_legend(args.repeats)
    _print_targets(rtfs)


def _size_row(
    scene: Scene, grid: NavGrid, n: int, frames: int, brute: bool, seed: int, repeats: int,
    dbs: dict[str, MotionDatabase],
) -> tuple[str, tuple[float, float, float, float]]:
    """One row of the table: ``n`` characters for ``frames`` frames, ``repeats`` times per search
    method (interleaved; the fastest counts), and the replan baseline on the problems they met;
    with the row, the size's RTF (wall, cpu, median of the runs) and character-frames per second."""
    kds, bfs = [], []
    for _ in range(max(1, repeats)):  # interleaved, so both methods see the same machine
        kds.append(run_crowd(scene, grid, n, frames, seed, dbs, brute=False))
        if brute:
            bfs.append(run_crowd(scene, grid, n, frames, seed, dbs, brute=True))
    kd = min(kds, key=lambda r: r.wall_s)
    bf = min(bfs, key=lambda r: r.wall_s) if bfs else None
    same = all(np.array_equal(r.positions, kd.positions) and r.counters.results == kd.counters.results
               for r in kds + bfs)
    w_s, nw_s, py_s, same_plans = replan_baseline(grid, kd.counters.problems, seed, limit=60 if brute else 8, full=brute)
    same = same and same_plans
    c = kd.counters
    ckd = n * frames / kd.wall_s
    sim_s = frames / 30.0
    s_kd = 1e6 * c.search_s / max(1, c.searches)
    motion, plan = c.motion_s / kd.wall_s, c.plan_s / kd.wall_s
    if bf is not None:
        cb = bf.counters
        cbf = n * frames / bf.wall_s
        s_bf = 1e6 * cb.search_s / max(1, cb.searches)
        bf_cols = (f"{cbf:>8.0f} {ckd / cbf:>6.2f}", f"{sim_s / bf.wall_s:>6.2f}",
                   f"{s_bf:>8.1f} {s_bf / max(s_kd, 1e-9):>6.2f}")
    else:
        bf_cols = (f"{'-':>8} {'-':>6}", f"{'-':>6}", f"{'-':>8} {'-':>6}")
    full_col = f"{1e3 * nw_s:>8.2f} {nw_s / max(w_s, 1e-12):>6.2f}" if nw_s is not None else f"{'-':>8} {'-':>6}"
    row = (f"{n:>4} {scene.name:<10} {frames:>6} | {ckd:>9.0f} {bf_cols[0]} | "
           f"{sim_s / kd.wall_s:>6.2f} {bf_cols[1]} {sim_s / kd.cpu_s:>6.2f} | "
           f"{s_kd:>9.1f} {bf_cols[2]} | "
           f"{1e3 * w_s:>9.2f} {full_col} "
           f"{1e3 * py_s:>7.2f} {py_s / max(w_s, 1e-12):>6.2f} | "
           f"{motion:>6.0%} {plan:>5.0%} {1 - motion - plan:>5.0%} | {'yes' if same else 'NO'}")
    return row, (sim_s / kd.wall_s, sim_s / kd.cpu_s, sim_s / float(np.median([r.wall_s for r in kds])), ckd)


def _print_legend(repeats: int) -> None:
    print()
    print(f"Each size runs {max(1, repeats)}x per search method (identical, interleaved); the fastest run of each")
    print("     is shown (the least disturbed on a shared machine).")
    print("char-fr/s: character-frames per wall second (KD-tree search); brute: same run, brute-force search.")
    print("RTF: simulated seconds per wall second (cpu: per second of this process's CPU time, which a")
    print("     loaded machine disturbs less). search us: mean motion search per query (single and batched).")
    print("replan ms: mean windowed WHCA* replan (window 20, compiled search); full: non-windowed planner on the")
    print("     same problems; python: the same windowed planner with the pure-Python backend (ratio: its speed-up).")
    print("motion / plan / world: share of the KD run's wall time. same: both runs took identical decisions")
    print("     (and both planner backends returned identical plans).")


def _print_targets(rtfs: dict[int, tuple[float, float, float, float]]) -> None:
    """Each issue's real-time target against the size it names, where that size was run."""
    for n, goal, what in ((10, 30.0, "issue 8"), (50, 20.0, "issue 14"), (200, 5.0, "issue 14"), (1000, 0.0, "issue 14")):
        if n not in rtfs:
            continue
        wall_rtf, cpu_rtf, median_rtf, cfs = rtfs[n]
        verdict = ("measured" if goal == 0 else "met" if wall_rtf >= goal else
                   "met by CPU time only" if cpu_rtf >= goal else "NOT met")
        ask = f">= {goal:.0f}x real time" if goal else "measured and reported"
        print(f"{what} target ({n} characters {ask}): {wall_rtf:.2f}x wall, {cpu_rtf:.2f}x cpu "
              f"(median of the runs {median_rtf:.2f}x), {cfs:.0f} character-frames/s -> {verdict}")

if __name__ == "__main__":
    main()

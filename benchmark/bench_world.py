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

Usage: ``python -m benchmark.bench_world [--sizes 1 10 50 200 1000] [--seconds 10] [--seed 0] [--repeats 3] [--warmup 2]``,
or ``python -m benchmark.bench_world --scaling [N ...] [--scaling-seconds 10] [--repeats 2]`` (below).
The 200-character case runs half of ``--seconds``, the 1,000-character case a fifth.
Targets: 10 characters >= 30x real time on one core (issue 8); 50 characters >= 20x, 200
characters >= 5x (30,000 character-frames per second), 1,000 characters measured (issue 14).

Issue 14 figures (2026-12-02, ``--sizes 50 200 1000``, under ``nice`` on a 2-core machine shared
with an LLM job, load average 3.5-4; two runs of the script, each interleaved with a run of the
code before this round of speed-ups (commit 67f9f56) in the same session): 50 characters
26.4-26.7x wall (before 20.2-22.3x); 200 ("Office x4") 7.2-7.3x wall / 7.3-7.7x CPU, about
43,000 character-frames per second (before 5.4-6.2x wall, 32,500-37,000); 1,000 ("Office x16",
2 s) 0.94-0.98x wall (before 0.70-0.74x); windowed replan at 200 11.1-11.5 ms (before 16.4-17.3).
CPU time of the timed loop, least of the interleaved runs (9 / 6 / 3 per version): 200
characters 0.81 -> 0.61 s per 150 frames (-24%), 50 characters 0.45 -> 0.37 s per 300 frames,
1,000 characters 2.53 -> 2.03 s per 60 frames; the same positions, motion searches, track
buffers and foot states bit for bit.
(The figures before, 23.0x / 4.07x CPU at 50 / 200, were taken at load average 9-10.)
Where the CPU time goes at 200: planning about 31% (the compiled space-time search about 20%;
a planning pass is one compiled call), motion matching about 26%, leg IK about 7%, the rest
per-frame bookkeeping and Python's garbage collector: a full collection walks the process's
~140,000 objects (about 50 ms each time it comes, roughly once per 150 frames here; an
application can skip them with ``gc.freeze()`` after loading). The short 1,000-character run is
dominated by its first replan, which computes a goal-distance field for each of the 1,000
new goals at once; the field is a compiled bucket-queue Dijkstra (``astar_kernel.goal_distances``)
over the whole grid. Whether anything else grows with the crowd: ``--scaling``.

Scaling (``--scaling``; sizes default 125 250 500 1000): the crowds walk in ONE layout, "Office
x16" (14,832 walkable cells), so that a cost growing with the crowd is not mistaken for one
growing with the floor. Per size: CPU time of the first step (it runs the first planning pass:
a goal-distance field per new goal, counted and timed by the planner wrapper) and CPU per
character-frame over the frames after it, split into planning (fields included), motion and
the rest; search expansions per agent per planning call; the fastest of the interleaved runs
(all bit-identical). A last row runs a quarter of the largest crowd in "Office x4": a quarter
of the floor, the same walkers per cell. Then one field is timed on each layout. Figures
(2026-12-03, ``--scaling --repeats 2``, 10 simulated s per crowd, 83 s in all, under ``nice``
on the 2-core machine shared with an LLM job, load average 5-6)::

       N  layout      per 100 cells  first step s (fields)  us/char-frame  plan  motion  rest  exp/agent
     125  Office x16            0.8          0.16 (0.06)             26.6   4.7     7.8  14.2         21
     250  Office x16            1.7          0.41 (0.15)             28.8   5.0     9.1  14.7         42
     500  Office x16            3.4          0.84 (0.29)             31.9   7.9     7.9  16.1         83
    1000  Office x16            6.7          1.31 (0.49)             41.1  17.8     7.8  15.5        459
     250  Office x4             6.8          0.14 (0.03)             37.8  15.2     9.4  13.1        498

    one goal-distance field: Office (521 walkable cells) 14 us, x4 (3,670) 83 us, x16 (14,832) 491 us

What is and is not superlinear. Motion (matching and IK) and the rest of the step cost the same
per character at every size (within the noise of the shared machine; a profile finds no
function of theirs whose cost per character grows), except Python's full garbage collections:
they come more often with more characters, 2.2-2.5 us per character-frame at 250, 3.6-4.4 at
1,000 (200-frame runs, timed with ``gc.callbacks``). Planning per character-frame
grows, 4.7 -> 17.8 us from 125 to 1,000 walkers on the same floor, and it follows the crowd's
density, not its size: each walker's windowed search expands about twice as many nodes when
the crowd doubles on the same floor (more reserved paths to go around), and at 6.7 walkers
per 100 cells the crowd starts to jam (failed searches, repair passes, walkers planned around
the stationary bodies). The same density on a quarter of the floor (last row) costs the same
per character (498 expansions per agent, 37.8 us). That growth is the cooperative search
doing more work, not overhead; this round leaves it. The goal-distance fields are O(floor)
each: one per new goal (the first step: linear in N on one floor, 0.5 ms per walker on
"Office x16") and, after it, one per arrival and one per detour walker and planning call
(when the stationary bodies changed, as they do every call in a large crowd). On one
floor they are linear in N; they become N x floor only when the floor grows with the crowd,
as it does in the main table (a field costs 35x more on "Office x16" than on the Office, for
28x the walkable cells). Removed in this round: each detour walker also paid an O(floor)
setup of its own (a digest of the stationary bodies' masks and the blocked-move costs: 1.4 ms
on "Office x16", three times its Dijkstra) and every planning pass re-stacked the detour fields; both are now done
once per planning call (``PathPlanner._detour_graph``, ``_extra_stack``). 1,000 walkers in
"Office x16" for 16 simulated s (the jam builds after about 5 s; by 20 s about 250 of them
are planned around stationary bodies per call): 38.3 and 40.7 s CPU before, 30.6 and 30.6 s
after (two interleaved pairs), positions bit for bit the same.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from orchestrator.cache_paths import motion_cache_dir
from orchestrator.reference_data import locate_reference
from sim.motion.database import MotionDatabase, load_databases
from sim.motion.matching import MotionMatcher, MotionQuery, Pose, PoseBatch
from sim.paths.astar_kernel import goal_distances
from sim.paths.cooperative_astar import Agent, Cell, PathPlanner, PlanResult
from sim.paths.heuristics import DetourGraph, GoalDistances
from sim.paths.move_tables import MoveTables
from sim.paths.nav_grid import NavGrid, build_nav_grid
from sim.scene.files import load_scene
from sim.scene.model import Scene
from sim.world.events import AssignEvent, Assignment
from sim.world.step import World, WorldConfig, step

REFERENCE = locate_reference()  # absent: main() exits with REFERENCE.reason
OFFICE = REFERENCE.path / "configs" / "scenes" / "Office"


# ----- instrumentation -------------------------------------------------------------------------
@dataclass
class Counters:
    search_s: float = 0.0
    searches: int = 0
    motion_s: float = 0.0
    plan_s: float = 0.0
    plans: int = 0
    problems: list[tuple[Any, ...]] = field(default_factory=list)
    results: list[int] = field(default_factory=list)
    clock: Callable[[], float] = time.perf_counter  # what the wrappers time with (process_time: CPU)
    record: bool = True  # keep every planning problem (for the replan baselines)
    fields: int = 0  # goal-distance fields computed (static distance per new goal)
    field_s: float = 0.0
    detour_fields: int = 0  # fields computed for detour walkers (around the stationary bodies)
    detour_s: float = 0.0
    planned: int = 0  # agents planned, summed over the planning calls
    expansions: int = 0  # search expansions, summed over the planning calls
    detoured: int = 0  # detour walkers, summed over the planning calls

    def since(self, before: Counters) -> Counters:
        """The counts and times added since ``before`` (a copy of these counters taken earlier)."""
        return Counters(**{f.name: getattr(self, f.name) - getattr(before, f.name) for f in dataclasses.fields(self)
                           if type(getattr(self, f.name)) in (int, float)})


class TimedIndex:
    """A search index whose batched ``query_many`` (the matcher's grouped searches) is timed,
    and answered row by row by brute force in the brute-force run."""

    def __init__(self, index: Any, counters: Counters, brute: bool) -> None:
        self._ix, self._c, self._brute = index, counters, brute

    def __getattr__(self, name: str) -> Any:
        value = getattr(self._ix, name)
        object.__setattr__(self, name, value)  # read-only index data: look it up once
        return value

    def query_many(self, queries: np.ndarray, k: int = 4, workers: int = 1) -> tuple[np.ndarray, np.ndarray]:
        t0 = self._c.clock()
        if self._brute:
            pairs = [self._ix.brute_force(q) for q in np.asarray(queries, dtype=float)]
            out = (np.array([p[0] for p in pairs], dtype=np.int64), np.array([p[1] for p in pairs]))
        else:
            out = self._ix.query_many(queries, k=k, workers=workers)
        self._c.search_s += self._c.clock() - t0
        self._c.searches += len(out[0])
        self._c.results.extend(int(i) for i in out[0])
        return out


class TimedDatabase:
    """A MotionDatabase whose searches (single ``search`` and the batched ``index.query_many``)
    are timed (and optionally brute force). Other attributes are the database's own, looked
    up once (the database is immutable), so the wrapper adds little to the motion time."""

    def __init__(self, db: MotionDatabase, counters: Counters, brute: bool) -> None:
        self._db, self._c, self._brute = db, counters, brute
        self.index = TimedIndex(db.index, counters, brute)
        self.entry_index = TimedIndex(db.entry_index, counters, brute)

    def __getattr__(self, name: str) -> Any:
        value = getattr(self._db, name)
        object.__setattr__(self, name, value)
        return value

    def search(self, raw_query: np.ndarray, entry: bool = False) -> tuple[int, float]:
        db = self._db
        t0 = self._c.clock()
        if self._brute:
            index = db.entry_index if entry else db.index
            out = index.brute_force(db.normalize(raw_query))
        else:
            out = db.search(raw_query, entry=entry)
        self._c.search_s += self._c.clock() - t0
        self._c.searches += 1
        self._c.results.append(out[0])
        return out


class TimedMotion:
    """The motion layer with its step time counted."""

    def __init__(self, matcher: MotionMatcher, counters: Counters) -> None:
        self._m, self._c = matcher, counters

    def initial_state(self, label: str, root_xy: Any, heading: float, seated: bool = False) -> Any:
        return self._m.initial_state(label, root_xy, heading, seated)

    def step(self, state: Any, query: MotionQuery, dt: float) -> tuple[Any, Pose]:
        t0 = self._c.clock()
        out = self._m.step(state, query, dt)
        self._c.motion_s += self._c.clock() - t0
        return out

    def step_many(self, states: Any, queries: Any, dt: float) -> tuple[list[Any], list[Pose]]:
        """The batched path (``MotionMatcher.step_many``), timed."""
        t0 = self._c.clock()
        out = self._m.step_many(states, queries, dt)
        self._c.motion_s += self._c.clock() - t0
        return out

    def step_batch(self, states: Any, queries: Any, dt: float) -> tuple[list[Any], PoseBatch]:
        """The batched path the world uses (``MotionMatcher.step_batch``: poses as arrays), timed."""
        t0 = self._c.clock()
        out = self._m.step_batch(states, queries, dt)
        self._c.motion_s += self._c.clock() - t0
        return out


class TimedPlanner(PathPlanner):
    """WHCA* that times and records every planning call (and its goal distances)."""

    def __init__(self, grid: NavGrid, counters: Counters, **kw: Any) -> None:
        self.counters = counters
        super().__init__(grid, **kw)

    def _goal_distances(self, tables: MoveTables) -> GoalDistances:
        return TimedGoalDistances(tables, self.counters)

    def plan(
        self,
        starts: Mapping[Agent, Cell],
        goals: Mapping[Agent, Cell | None],
        static_obstacles: Sequence[NDArray[np.float64] | tuple[float, float]] = (),
        t0: int = 0,
        order: Sequence[Agent] | None = None,
        static_segments: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]] = (),
        hints: Mapping[Agent, tuple[Sequence[Cell], Cell]] | None = None,
        detour: Collection[Agent] = (),
    ) -> PlanResult:
        c = self.counters
        t = c.clock()
        kw = {"static_segments": static_segments, "hints": hints}
        out = super().plan(starts, goals, static_obstacles, t0=t0, order=order, static_segments=static_segments,
                           hints=hints, detour=detour)
        c.plan_s += c.clock() - t
        c.plans += 1
        c.planned += len(starts)
        c.expansions += out.expansions
        c.detoured += len(out.detour)
        if c.record:
            c.problems.append((dict(starts), dict(goals), list(static_obstacles), t0, list(order or ()), kw))
        return out



class TimedGoalDistances(GoalDistances):
    """The planner's goal-distance cache, with the fields it computes counted and timed."""

    def __init__(self, tables: MoveTables, counters: Counters) -> None:
        super().__init__(tables)
        self.counters = counters

    def row(self, gid: int) -> int:
        if gid in self.rows:
            return super().row(gid)
        c = self.counters
        t = c.clock()
        row = super().row(gid)
        c.field_s += c.clock() - t
        c.fields += 1
        return row

    def detour_field(self, gid: int, graph: DetourGraph) -> NDArray[np.float64]:
        """The detour walkers' fields, counted and timed when computed (not memoised)."""
        if (gid, graph[0]) in self._detour_memo:
            return super().detour_field(gid, graph)
        c = self.counters
        t = c.clock()
        out = super().detour_field(gid, graph)
        c.detour_s += c.clock() - t
        c.detour_fields += 1
        return out


# ----- scenes and crowds ----------------------------------------------------------------------------
def tiled(scene: Scene, nx: int, ny: int) -> Scene:
    """``nx`` x ``ny`` copies of ``scene`` side by side (objects renamed, overrides dropped)."""
    (x0, y0), (x1, y1) = scene.bounds_min, scene.bounds_max
    w, h = x1 - x0, y1 - y0
    objs = []
    next_idx: dict[str, int] = {}
    for a in range(nx):
        for b in range(ny):
            for o in scene.objects:
                k = next_idx.get(o.label, 0)
                next_idx[o.label] = k + 1
                c = (o.center[0] + a * w, o.center[1] + b * h, o.center[2])
                objs.append(o.model_copy(update={"name": f"{o.label}_{k}", "idx": k, "center": c}))
    return Scene(name=f"{scene.name} x{nx * ny}", bounds_min=(x0, y0), bounds_max=(x0 + nx * w, y0 + ny * h),
                 objects=tuple(objs), nav=scene.nav.model_copy(update={"occupied": (), "unoccupied": ()}))


class Stamps:
    """How many taken cells lie within 1 cell (Chebyshev) of each grid cell: a cell is at least
    2 cells from every taken one when its count is 0. Adding or removing a taken cell is O(1)."""

    def __init__(self, cells: np.ndarray) -> None:
        self.count = np.zeros((int(cells[:, 0].max()) + 3, int(cells[:, 1].max()) + 3), dtype=np.int64)

    def add(self, c: np.ndarray, k: int = 1) -> None:
        i, j = int(c[0]), int(c[1])  # count[i + 1, j + 1] belongs to cell (i, j)
        if -1 <= i < self.count.shape[0] - 1 and -1 <= j < self.count.shape[1] - 1:  # else: blocks no cell
            self.count[max(0, i): i + 3, max(0, j): j + 3] += k

    def free(self, cells: np.ndarray) -> np.ndarray:
        return np.asarray(self.count[cells[:, 0] + 1, cells[:, 1] + 1] == 0)


def spread_cells(cells: np.ndarray, count: int, rng: np.random.Generator, taken: list[np.ndarray] | Stamps,
                 ) -> list[np.ndarray]:
    """``count`` cells of ``cells`` (rows (i, j)) in the order of one random permutation, each at
    least 2 cells (Chebyshev) from ``taken`` and from the ones picked before it (``taken``
    given as ``Stamps`` is left as it was). O(1) per candidate, not O(len(taken)); candidates
    are tested in chunks of the permutation, so one pick does not test every cell of a large
    layout (the permutation itself is drawn whole: the generator's draws stay the same)."""
    out: list[np.ndarray] = []
    perm = rng.permutation(len(cells))
    if count <= 0:
        return out
    stamps = taken if isinstance(taken, Stamps) else Stamps(cells)
    if not isinstance(taken, Stamps):
        for o in taken:
            stamps.add(o)
    chunk = 64  # candidates checked per vectorised test: usually the first chunk has a free one
    for lo in range(0, len(perm), chunk):
        part = perm[lo: lo + chunk]
        for k in part[stamps.free(cells[part])]:
            c = cells[k]
            if stamps.count[c[0] + 1, c[1] + 1] == 0:
                out.append(c)
                if len(out) == count:
                    break
                stamps.add(c)
        if len(out) == count:
            break
    if taken is stamps:
        for c in out[:-1]:
            stamps.add(c, -1)
    if len(out) == count:
        return out
    raise SystemExit(f"only {len(out)} of {count} characters fit 2 cells apart")


class IdleErrands:
    """The benchmark's crowd scenario: ``n`` walkers start on spread-out cells (2 cells
    apart); whenever a walker's event loops or fails it gets a new ``idle`` event at a random
    free cell 2 cells from everyone's target, facing a random direction. Deterministic for a
    seed (one generator draws the starts, then every target in order)."""

    def __init__(self, grid: NavGrid, n: int, seed: int) -> None:
        self.grid = grid
        self.cells = np.argwhere(grid.component == grid.main_component)
        self.rng = np.random.default_rng(seed)
        starts = spread_cells(self.cells, n, self.rng, [])
        self.names = [f"p{i:03d}" for i in range(n)]
        self.starts = {nm: (tuple(grid.center_of(*c)), 0.0) for nm, c in zip(self.names, starts, strict=True)}
        self.targets = dict(zip(self.names, starts, strict=True))
        self.stamps = Stamps(self.cells)  # every walker's current target
        for c in starts:
            self.stamps.add(c)
        self.count = dict.fromkeys(self.names, 0)
        self.todo = set(self.names)

    def commands(self) -> list[AssignEvent]:
        """New events for the walkers that need one (then none until ``observe`` says so)."""
        cmds = []
        for nm in sorted(self.todo):
            self.stamps.add(self.targets[nm], -1)  # 2 cells from every other walker's target
            cell = spread_cells(self.cells, 1, self.rng, self.stamps)[0]
            self.stamps.add(cell)
            self.targets[nm] = cell
            self.count[nm] += 1
            theta = float(self.rng.uniform(-math.pi, math.pi))
            cmds.append(AssignEvent(event_id=f"{nm}-{self.count[nm]}", assignments=(Assignment(
                character=nm, action="idle", target_xy=tuple(self.grid.center_of(*cell)),
                facing_xy=(math.cos(theta), math.sin(theta))),)))
        self.todo = set()
        return cmds

    def observe(self, out: Any) -> None:
        """Walkers whose event looped or failed in this step's output need a new one."""
        self.todo = {e.rsplit("-", 1)[0] for e in out.looping_events} | {f.character for f in out.failures}


@dataclass
class RunResult:
    n: int
    frames: int
    wall_s: float
    cpu_s: float
    counters: Counters
    positions: np.ndarray


def crowd_world(scene: Scene, grid: NavGrid, n: int, frames: int, seed: int, dbs: dict[str, MotionDatabase],
                brute: bool, counters: Counters) -> tuple[World, IdleErrands]:
    """A world of ``n`` walkers on random errands whose motion search and planner report to ``counters``."""
    matcher = MotionMatcher({k: TimedDatabase(db, counters, brute) for k, db in dbs.items()})  # type: ignore[misc]  # TimedDatabase stands in for a MotionDatabase by delegation (__getattr__), not by subclassing
    planner = TimedPlanner(grid, counters, seed=seed)
    errands = IdleErrands(grid, n, seed)
    world = World(scene, errands.starts, TimedMotion(matcher, counters), grid=grid, planner=planner,
                  config=WorldConfig(seed=seed, initial_capacity=frames))
    return world, errands


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
    """CPU per goal-distance field (``astar_kernel.goal_distances``, the planner's static distance
    to one goal) on "Office", "Office x4" and "Office x16"."""
    print()
    print(f"One goal-distance field (astar_kernel.goal_distances), {goals} random goals per layout, CPU, best of "
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


def main() -> None:
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
    args = ap.parse_args()
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
        brute = n <= args.brute_max
        frames = round(seconds * 30)
        kds, bfs = [], []
        for _ in range(max(1, args.repeats)):  # interleaved, so both methods see the same machine
            kds.append(run_crowd(scene, grid, n, frames, args.seed, dbs, brute=False))
            if brute:
                bfs.append(run_crowd(scene, grid, n, frames, args.seed, dbs, brute=True))
        kd = min(kds, key=lambda r: r.wall_s)
        bf = min(bfs, key=lambda r: r.wall_s) if bfs else None
        same = all(np.array_equal(r.positions, kd.positions) and r.counters.results == kd.counters.results
                   for r in kds + bfs)
        w_s, nw_s, py_s, same_plans = replan_baseline(grid, kd.counters.problems, args.seed, limit=60 if brute else 8, full=brute)
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
        print(f"{n:>4} {scene.name:<10} {frames:>6} | {ckd:>9.0f} {bf_cols[0]} | "
              f"{sim_s / kd.wall_s:>6.2f} {bf_cols[1]} {sim_s / kd.cpu_s:>6.2f} | "
              f"{s_kd:>9.1f} {bf_cols[2]} | "
              f"{1e3 * w_s:>9.2f} {full_col} "
              f"{1e3 * py_s:>7.2f} {py_s / max(w_s, 1e-12):>6.2f} | "
              f"{motion:>6.0%} {plan:>5.0%} {1 - motion - plan:>5.0%} | {'yes' if same else 'NO'}", flush=True)
        rtfs[n] = (sim_s / kd.wall_s, sim_s / kd.cpu_s, sim_s / float(np.median([r.wall_s for r in kds])), ckd)
    print()
    print(f"Each size runs {max(1, args.repeats)}x per search method (identical, interleaved); the fastest run of each")
    print("     is shown (the least disturbed on a shared machine).")
    print("char-fr/s: character-frames per wall second (KD-tree search); brute: same run, brute-force search.")
    print("RTF: simulated seconds per wall second (cpu: per second of this process's CPU time, which a")
    print("     loaded machine disturbs less). search us: mean motion search per query (single and batched).")
    print("replan ms: mean windowed WHCA* replan (window 20, compiled search); full: non-windowed planner on the")
    print("     same problems; python: the same windowed planner with the pure-Python backend (ratio: its speed-up).")
    print("motion / plan / world: share of the KD run's wall time. same: both runs took identical decisions")
    print("     (and both planner backends returned identical plans).")
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

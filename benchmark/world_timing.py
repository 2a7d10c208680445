"""The world benchmarks' instrumentation: a world whose motion search and path planner report to
``Counters`` (searches and their time, motion step time, planning calls, the planning problems,
goal-distance fields), with an option to answer every motion search by brute force (the KD-tree's
baseline). The wrappers delegate; the world takes the same decisions with and without them.

Used by ``benchmark/bench_world.py`` and ``benchmark/bench_world_overhead.py`` (which reads them with its own clock).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from storyteller.benchmark.crowd_scenario import IdleErrands
from storyteller.sim.motion.database import MotionDatabase
from storyteller.sim.motion.matching import MotionMatcher, MotionQuery, Pose, PoseBatch
from storyteller.sim.paths.cooperative_astar import Agent, Cell, PathPlanner, PlanResult
from storyteller.sim.paths.heuristics import DetourGraph, GoalDistances
from storyteller.sim.paths.move_tables import MoveTables
from storyteller.sim.paths.nav_grid import NavGrid
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.step import World, WorldConfig


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


def crowd_world(scene: Scene, grid: NavGrid, n: int, frames: int, seed: int, dbs: dict[str, MotionDatabase],
                brute: bool, counters: Counters) -> tuple[World, IdleErrands]:
    """A world of ``n`` walkers on random errands whose motion search and planner report to ``counters``."""
    matcher = MotionMatcher({k: TimedDatabase(db, counters, brute) for k, db in dbs.items()})  # type: ignore[misc]  # TimedDatabase stands in for a MotionDatabase by delegation (__getattr__), not by subclassing
    planner = TimedPlanner(grid, counters, seed=seed)
    errands = IdleErrands(grid, n, seed)
    world = World(scene, errands.starts, TimedMotion(matcher, counters), grid=grid, planner=planner,
                  config=WorldConfig(seed=seed, initial_capacity=frames))
    return world, errands

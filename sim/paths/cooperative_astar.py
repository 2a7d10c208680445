"""Windowed hierarchical cooperative A* (WHCA*) with a continuous clearance guarantee.

Time is discrete: one *step* lasts ``step_time`` seconds (default ``cell_size / walking_speed``
= 0.3 s = 9 frames at 30 fps). In one step every walking agent either waits or moves to one of
its 8 neighbour cells, moving in a straight line at constant speed (so straight moves run at
the walking speed and diagonals at sqrt(2) times it). All agents share the step clock, so two
agents' relative motion within a step is linear and its closest approach has a closed form.

Clearance rule (the guarantee): for every pair of agents and every step, the centre distance
over the whole step never drops below ``min(2 * body_radius, distance at the step start)``.
Hence agents that start apart (>= 2r) stay apart at every instant, including mid-move and
during diagonal moves, and agents that start too close (e.g. placed by hand) never get closer.
When both agents move in the step their legs keep apart too: a walking body is its disc and a
segment through its centre along its direction of travel, its feet reaching ``LEG_REACH_M``
ahead and ``LEG_TRAIL_M`` behind, of radius ``LEG_RADIUS_M`` (``storyteller.sim.paths.move_tables.
striding_safe``: legs apart, legs clear of the other's hips, at instants of the step; a pair
that starts closer gets no closer). With discs only, two walkers crossing at right angles 0.6 m
apart touched thigh to thigh (the body-body overlap of ``storyteller.benchmark.motion_metrics``); side by
side they still pass at ``2 * body_radius``.
The rule is tabulated once over relative start offsets and relative velocities (cell units;
the legs' over offsets and both moves), which covers vertex, swap and following conflicts; an
agent farther than ``2 + walking_distance / cell`` cells (Chebyshev) cannot conflict within
one step. Stationary characters are discs at arbitrary positions; a move is forbidden for them
by the disc rule.

Planning pass (prioritized): agents plan one after another in a space-time A* over
``window`` steps against a reservation table of the agents planned before them (plain WHCA*).
If some agent's search fails (it is cornered), the call is planned again with every agent's
"wait where it stands" for the first ``commit_steps`` steps reserved up front and the failed
agents first: then an agent whose search still fails can safely wait, so the committed prefix
of every returned plan is conflict-free. A repair pass (same order, hints and window) takes
the pass before's result for every agent whose search read only reservation entries that
cannot have changed (the compiled search reports the entries it read), so its cost grows with
the neighbourhood of the failed agents, not with the crowd; the plans are the same.
Costs: a move costs its length in cells, waiting costs 1 per step except at the goal (free).
The heuristic is the exact distance on the static grid (Dijkstra per goal, compiled, cached).
Agents named in ``plan(detour=...)`` (walkers that stopped making progress: a stationary body,
such as a member waiting at its target, closes the corridor the static distance leads into)
use instead the exact distance along the moves the stationary bodies leave (Dijkstra per goal
and set of stationary bodies), so their search walks around the blockage; when the bodies
cut the goal off entirely they keep the static distance (and wait for the way to open).
Plans are deterministic: fixed move order, tie-breaking on (f, h, cell), explicit orders.

This module is the planner itself (``PathPlanner``: the passes of one call and their order) and
the one import path for its public names. Its parts: the clearance rule's geometry and plan
checks (``storyteller.sim.paths.clearance``), the move tables and clearance masks (``storyteller.sim.paths.move_tables``),
the moves stationary bodies leave (``storyteller.sim.paths.static_bodies``), the goal and detour distances
(``storyteller.sim.paths.heuristics``), the goals a walker can use (``storyteller.sim.paths.usable_goals``), the
reservation table (``storyteller.sim.paths.reservations``), the compiled backend
(``storyteller.sim.paths.compiled_backend``, on the kernels of ``storyteller.sim.paths.astar_kernel``) and the
pure-Python one (``storyteller.sim.paths.python_backend``).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.paths.clearance import plan_conflicts, position_at, segment_distance
from storyteller.sim.paths.compiled_backend import CompiledPasses, PassRecord
from storyteller.sim.paths.fallback import failed_first
from storyteller.sim.paths.heuristics import GoalDistances
from storyteller.sim.paths.move_tables import LEG_RADIUS_M, LEG_REACH_M, Move, MoveTables
from storyteller.sim.paths.nav_grid import NavGrid
from storyteller.sim.paths.plan_types import BACKENDS, Agent, Backend, Cell, PlanningError
from storyteller.sim.paths.python_backend import PythonPasses
from storyteller.sim.paths.static_bodies import Segment, StaticBodies
from storyteller.sim.paths.usable_goals import UsableGoals

# the planner's public names, wherever they are defined (one import path for callers)
__all__ = [
    "BACKENDS",
    "Agent",
    "Backend",
    "Cell",
    "PathPlanner",
    "PlanResult",
    "PlanningError",
    "plan_conflicts",
    "position_at",
    "segment_distance",
]

_EPS = 1e-9


@dataclass(frozen=True)
class PlanResult:
    """One planning call. ``paths[a]`` lists ``window + 1`` cells: the start, then one per step
    (only ``commit_steps + 1`` cells, all the start, for agents whose search failed).

    ``failed``: agents for which the windowed search found nothing (they wait in place);
    ``reused``: agents whose ``hints`` path was kept (checked, extended) instead of searched;
    ``fallback``: agents planned again by the fallback pass; ``goals``: the goal actually used
    per agent (replaced by the nearest reachable cell when the requested one is unreachable).
    """

    paths: dict[Agent, list[Cell]]
    failed: frozenset[Agent]
    fallback: frozenset[Agent]
    goals: dict[Agent, Cell]
    expansions: int = 0
    reused: frozenset[Agent] = frozenset()
    detour: dict[Agent, float] = field(default_factory=dict)
    """For the ``detour`` agents planned around the stationary bodies: the distance (cells)
    from the start to the used goal along the moves those bodies leave."""


class PathPlanner:
    """WHCA* over a ``NavGrid``. Pure and deterministic (no clock, no randomness but ``seed``).

    ``window``: steps planned per search (reference: 20). ``commit_steps``: steps executed
    before the next replan (the prefix that is guaranteed conflict-free; default 1 step =
    9 frames, about the reference's 10-frame replan interval). ``step_time``: seconds per step.
    ``max_expansions``: search budget per agent and call; beyond it the agent waits.
    ``backend``: ``"numba"`` (default) runs the reservation folding and the space-time search
    compiled (``sim.paths.astar_kernel``); ``"python"`` runs the same algorithm in pure Python. Both
    return the same plans.
    """

    def __init__(
        self,
        grid: NavGrid,
        window: int = 20,
        commit_steps: int = 1,
        walking_speed: float = 1.0,
        step_time: float | None = None,
        max_expansions: int = 4000,
        fallback: bool = True,
        seed: int = 0,
        repair_passes: int = 3,
        backend: Backend = "numba",
    ) -> None:
        if backend not in BACKENDS:
            raise PlanningError(f"backend must be one of {BACKENDS}, got {backend!r}")
        if window < 1:
            raise PlanningError(f"window must be >= 1 step, got {window}")
        if not 1 <= commit_steps <= window:
            raise PlanningError(f"commit_steps must be in [1, window={window}], got {commit_steps}")
        if not walking_speed > 0:
            raise PlanningError(f"walking_speed must be > 0 m/s, got {walking_speed}")
        self.grid = grid
        self.window = int(window)
        self.commit_steps = int(commit_steps)
        self.step_time = float(step_time if step_time is not None else grid.cell_size / walking_speed)
        self.max_expansions = int(max_expansions)
        self.fallback = bool(fallback)
        self.repair_passes = int(repair_passes)
        self.seed = int(seed)
        self.backend = backend
        self.min_distance = 2.0 * grid.body_radius  # metres between centres
        # farthest centres whose bodies can touch: two discs, or two walkers' legs end to end
        self.walking_distance = max(self.min_distance, 2.0 * (LEG_REACH_M + LEG_RADIUS_M))
        d_cells = self.min_distance / grid.cell_size
        self.reach = int(math.ceil(self.walking_distance / grid.cell_size + 2.0 - _EPS))  # can conflict
        self.tables = MoveTables(grid, self.reach, d_cells)
        self.statics = StaticBodies(self.tables, self.min_distance)
        self.distances = self._goal_distances(self.tables)
        self._python = PythonPasses(self.tables, self.distances, self.window, self.commit_steps, self.max_expansions)
        self._compiled = CompiledPasses(self.tables, self.distances, self.window, self.commit_steps,
                                        self.max_expansions)
        self.goals = UsableGoals(grid, self.tables, self.distances)

    def _goal_distances(self, tables: MoveTables) -> GoalDistances:
        """The planner's goal-distance cache (a subclass may measure it: ``benchmark/bench_world.py``)."""
        return GoalDistances(tables)

    # ----- ids -----------------------------------------------------------------------------
    def cell_id(self, cell: Cell) -> int:
        return self.tables.cell_id(cell)

    def id_cell(self, cid: int) -> Cell:
        return self.tables.id_cell(cid)

    # ----- heuristic -----------------------------------------------------------------------------
    def heuristic(self, goal: Cell) -> list[float]:
        """Exact static distances (cells) to ``goal`` indexed by padded cell id (inf: unreachable)."""
        return self.distances.as_list(self.cell_id(goal))

    def heuristic_array(self, goal: Cell) -> NDArray[np.float64]:
        """``heuristic(goal)`` as a float array (the compiled search's view), a row of the
        goal-distance cache (``GoalDistances.array``): read it before asking for other goals'
        distances, or copy it."""
        return self.distances.array(self.cell_id(goal))

    def detour_distances(self, goal: Cell, static_allow: NDArray[np.int64]) -> NDArray[np.float64]:
        """Distances (cells) to ``goal`` per padded cell id along the moves ``static_allow``
        leaves (the moves stationary bodies do not block; inf: no such path). Memoised per goal
        and ``static_allow``."""
        return self.distances.detour_field(self.cell_id(goal), self.distances.detour_graph(static_allow))

    def distance(self, start: Cell, goal: Cell) -> float:
        """Shortest static path length from ``start`` to ``goal`` in metres (inf: unreachable)."""
        return float(self.heuristic_array(goal)[self.cell_id(start)]) * self.grid.cell_size

    # ----- planning ------------------------------------------------------------------------------------
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
        """Plan ``window`` steps for every agent in ``starts``.

        ``goals[a]`` None (or missing) means "stay": the agent keeps its cell unless it must
        make way. ``static_obstacles``: xy centres of stationary characters (metres).
        ``order``: priority order (first plans first); default is a permutation seeded by
        ``seed`` and ``t0``. ``static_segments``: (p, q) pairs in metres, bodies sweeping that
        segment (off-grid legs; see ``StaticBodies.static_overrides``). Every agent's wait is reserved for
        the committed steps, so no plan steps into a body that has not planned yet; the
        fallback pass re-plans with the failed agents first and a doubled window for them.

        ``hints[a] = (path, goal)``: the rest of ``a``'s previous plan (starting on its start
        cell) made for the same used goal. In the plain passes such a path is kept instead of
        searching when every step of it still passes this call's checks (reservations of the
        agents planned before, static obstacles); it is extended to the full window greedily
        along the static distance. A kept path is feasible, so the clearance guarantee is the
        same; it may be longer than a new search would find, which is why callers give hints
        only every other replan (``CrowdNavigator``).

        ``detour``: agents whose search is guided by the distance around the stationary bodies
        (``detour_distances``) instead of the static distance, when that distance is finite;
        they keep no hint. ``PlanResult.detour`` gives their remaining distance.
        """
        agents = list(starts)
        self.distances.next_epoch()  # goal distances read by an earlier call may be evicted (see GoalDistances)
        order = self._priority_order(agents, starts, order, t0)
        overrides, static_allow = self._static_moves(static_obstacles, static_segments)
        used_goals = self.goals.usable_goals(agents, starts, goals, static_allow)
        heuristics = self._detour_heuristics(detour, starts, used_goals, static_allow)
        # Pass 1: plain WHCA*. An agent whose search fails was cornered by the first steps of
        # agents planned before it; its wait is then reserved for the committed steps and the
        # call planned again (lazy wait reservation: only agents that need it hold their
        # place, the others may still be pushed), up to ``repair_passes`` times. A pass is safe
        # when every failed agent had its wait reserved. Last resort: everyone's wait reserved,
        # failed agents first with a doubled window (always safe).
        usable = self._usable_hints(hints or {}, starts, used_goals, heuristics)
        reserved: frozenset[Agent] = frozenset()
        result, record = self._run_pass(order, starts, used_goals, overrides, frozenset(), reserved, usable, static_allow,
                                        heuristics)
        fallback = set(result.failed)
        expansions = result.expansions
        for _ in range(self.repair_passes):
            if result.failed <= reserved:
                break
            # same order, hints and window as the pass before: agents whose search reads only
            # reservations that did not change take that pass's result (``_dense_pass``)
            before, reserved = reserved, reserved | result.failed
            result, record = self._run_pass(order, starts, used_goals, overrides, frozenset(), reserved, usable,
                                            static_allow, heuristics,
                                            previous=None if record is None else (record, before))
            fallback |= result.failed
            expansions += result.expansions
        if not result.failed <= reserved:
            order2 = failed_first(order, result.failed) if self.fallback else list(order)
            ext = result.failed if self.fallback else frozenset()
            result, record = self._run_pass(order2, starts, used_goals, overrides, ext, frozenset(order), {}, static_allow,
                                       heuristics)
            expansions += result.expansions
        self._compiled.end_call()
        return PlanResult(
            paths=result.paths if record is None else self._compiled.record_paths(record),
            failed=result.failed,
            fallback=frozenset(fallback),
            goals=used_goals,
            expansions=expansions,
            reused=result.reused,
            detour={a: float(h[self.cell_id(starts[a])]) for a, h in heuristics.items()},
        )

    def _priority_order(self, agents: list[Agent], starts: Mapping[Agent, Cell], order: Sequence[Agent] | None,
                        t0: int) -> list[Agent]:
        """The planning order (see ``plan``), after checking that every start is a free cell."""
        for a in agents:
            s = starts[a]
            if not self.grid.is_free(*s):
                raise PlanningError(f"agent {a!r} starts in cell {s}, which is blocked or outside the grid")
        if order is None:
            rng = np.random.default_rng([self.seed, int(t0)])
            return [agents[k] for k in rng.permutation(len(agents))]
        missing = set(agents) - set(order)
        return [a for a in order if a in starts] + [a for a in agents if a in missing]

    def _static_moves(
        self, static_obstacles: Sequence[NDArray[np.float64] | tuple[float, float]], static_segments: Sequence[Segment],
    ) -> tuple[dict[int, list[Move]], NDArray[np.int64]]:
        """The moves the stationary bodies leave: neighbour lists with moves taken out (the
        pure-Python backend; empty for the compiled one) and the bit mask per padded cell."""
        statics = [np.asarray(p, dtype=np.float64) for p in static_obstacles]
        overrides: dict[int, list[Move]] = {}
        if self.backend == "numba":  # the compiled passes read the moves left as one mask per cell
            return overrides, self.statics.static_allow_of(statics, static_segments)
        kept = self.statics.static_overrides(statics, static_segments)
        overrides = {cid: [(nb[0], nb[1], 1 << (nb[4] + 6)) for nb in lst] for cid, lst in kept.items()}
        return overrides, self.statics.static_allow(overrides)

    def _detour_heuristics(self, detour: Collection[Agent], starts: Mapping[Agent, Cell], used_goals: Mapping[Agent, Cell],
                           static_allow: NDArray[np.int64]) -> dict[Agent, NDArray[np.float64]]:
        """The detour agents' distances around the stationary bodies, for those it leaves a way."""
        heuristics: dict[Agent, NDArray[np.float64]] = {}
        graph = self.distances.detour_graph(static_allow) if any(a in starts for a in detour) else None
        for a in detour:
            if a in starts and graph is not None:
                h = self.distances.detour_field(self.cell_id(used_goals[a]), graph)
                if h[self.cell_id(starts[a])] < math.inf:
                    heuristics[a] = h
        return heuristics

    def _usable_hints(self, hints: Mapping[Agent, tuple[Sequence[Cell], Cell]], starts: Mapping[Agent, Cell],
                      used_goals: Mapping[Agent, Cell], heuristics: Mapping[Agent, NDArray[np.float64]],
                      ) -> dict[Agent, NDArray[np.int64]]:
        """The hints ``plan`` may keep (see there) as padded ids: planned agents without a
        detour, on their start cell, made for the goal used now."""
        return self._hint_ids({
            a: path for a, (path, goal) in hints.items()
            if (a in starts and a not in heuristics and path and tuple(path[0]) == tuple(starts[a])
                and tuple(goal) == tuple(used_goals[a]))
        })

    def _hint_ids(self, paths: Mapping[Agent, Sequence[Cell]]) -> dict[Agent, NDArray[np.int64]]:
        """The padded ids of each path's first window + 1 cells (all paths converted at once)."""
        if not paths:
            return {}
        w = self.window + 1
        lens = [min(len(p), w) for p in paths.values()]
        flat = np.array([c for p in paths.values() for c in p[:w]], dtype=np.int64).reshape(-1, 2)
        pad, nyp = self.tables.pad, self.tables.ny_p
        ids = (flat[:, 0] + pad) * nyp + flat[:, 1] + pad
        return dict(zip(paths, np.split(ids, np.cumsum(lens)[:-1]), strict=True))

    def _run_pass(
        self,
        order: Sequence[Agent],
        starts: Mapping[Agent, Cell],
        goals: Mapping[Agent, Cell],
        overrides: Mapping[int, list[Move]],
        extended: frozenset[Agent],
        reserve_waits: frozenset[Agent],
        hints: Mapping[Agent, NDArray[np.int64]],
        static_allow: NDArray[np.int64],
        heuristics: Mapping[Agent, NDArray[np.float64]],
        previous: tuple[PassRecord, frozenset[Agent]] | None = None,
    ) -> tuple[PlanResult, PassRecord | None]:
        """One planning pass on this planner's backend; the dense pass also returns what each
        agent's search read (for the next repair pass, see ``_dense_pass``). ``heuristics``:
        per agent, the distances that replace its goal's static distance (see ``plan``)."""
        if self.backend == "numba":  # the cells of the paths: only for the last pass (see plan)
            return self._dense_pass(order, starts, goals, extended, reserve_waits, hints, static_allow, previous,
                                    heuristics, cells=False)
        lists = {a: np.asarray(h).tolist() for a, h in hints.items()}
        paths, failed, reused, total = self._python.run_pass(order, starts, goals, overrides, extended, reserve_waits,
                                                             heuristics, lists)
        return PlanResult(paths=paths, failed=frozenset(failed), fallback=frozenset(), goals=dict(goals), expansions=total,
                          reused=frozenset(reused)), None

    def _dense_pass(
        self,
        order: Sequence[Agent],
        starts: Mapping[Agent, Cell],
        goals: Mapping[Agent, Cell],
        extended: frozenset[Agent],
        reserve_waits: frozenset[Agent],
        hints: Mapping[Agent, Sequence[int] | NDArray[np.int64]],
        static_allow: NDArray[np.int64],
        previous: tuple[PassRecord, frozenset[Agent]] | None = None,
        heuristics: Mapping[Agent, NDArray[np.float64]] | None = None,
        cells: bool = True,
    ) -> tuple[PlanResult, PassRecord]:
        """``CompiledPasses.run_pass`` as a ``PlanResult`` and its record. ``cells`` off:
        ``PlanResult.paths`` is left empty (the record has the paths)."""
        record = self._compiled.run_pass(order, starts, goals, extended, reserve_waits, hints, static_allow, previous,
                                         heuristics)
        result = PlanResult(
            paths=self._compiled.record_paths(record) if cells else {},
            failed=frozenset(order[k] for k in np.flatnonzero(record.failed).tolist()), fallback=frozenset(),
            goals=dict(goals), expansions=int(record.expansions.sum()),
            reused=frozenset(order[k] for k in np.flatnonzero(record.reused).tolist()),
        )
        return result, record

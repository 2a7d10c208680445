"""The compiled WHCA* backend takes exactly the pure-Python planner's decisions.

Both backends of ``PathPlanner`` run the same algorithm (``storyteller.sim.paths.astar_kernel`` is the numba
version of ``PathPlanner._search`` and the reservation folding); here they must return equal
``PlanResult``s on crowded problems in the reference Office scene, with stationary bodies,
off-grid segments, hints, tight budgets (failures, repair and fallback passes), and drive a
crowd of walkers along identical trajectories. The compiled heuristic (``goal_distances``)
gives the floats the scipy Dijkstra it replaced gave, for every goal.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import cast

import numpy as np
import pytest

from storyteller.benchmark.bench_paths import _spaced
from storyteller.sim.paths.cooperative_astar import PathPlanner, PlanningError, PlanResult
from storyteller.sim.paths.following import CrowdNavigator
from storyteller.sim.paths.nav_grid import NavGrid, build_nav_grid
from storyteller.sim.paths.plan_types import Agent, Backend, Cell
from storyteller.sim.paths.reservations import Reservations
from storyteller.sim.scene.files import load_scene
from tests.support.dense_reservations import DenseReservations
from tests.support.goal_distance_reference import scipy_goal_distances
from tests.support.reference import OFFICE, reference_or_skip


@pytest.fixture(scope="module")
def grid() -> NavGrid:
    reference_or_skip()
    return build_nav_grid(load_scene(OFFICE))


def _free_cells(grid: NavGrid) -> list[tuple[int, int]]:
    return [(int(i), int(j)) for i, j in np.argwhere(grid.component == grid.main_component)]


def _same(a: PlanResult, b: PlanResult) -> None:
    assert a.paths == b.paths
    assert (a.failed, a.fallback, a.reused, a.goals, a.expansions) == (b.failed, b.fallback, b.reused, b.goals, b.expansions)


@pytest.mark.parametrize("budget", [4000, 60])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compiled_plans_equal_python_plans(grid: NavGrid, seed: int, budget: int) -> None:
    rng = np.random.default_rng(seed)
    cells = _free_cells(grid)
    placed = _spaced(cells, 34, rng)
    agents, statics = placed[:30], placed[30:]
    starts: dict[Agent, Cell] = {f"a{k}": c for k, c in enumerate(agents)}
    goals: dict[Agent, Cell | None] = {
        a: cells[int(rng.integers(len(cells)))] if k % 5 else None for k, a in enumerate(starts)
    }
    static_xy = [grid.center_of(*c) + rng.uniform(-0.1, 0.1, 2) for c in statics]
    p, q = grid.center_of(*statics[-1]), grid.center_of(*statics[-1]) + np.array([0.3, 0.0])
    fast = PathPlanner(grid, window=20, seed=seed, max_expansions=budget, backend="numba")
    slow = PathPlanner(grid, window=20, seed=seed, max_expansions=budget, backend="python")
    first = fast.plan(starts, goals, static_obstacles=static_xy, t0=3, static_segments=[(p, q)])
    _same(first, slow.plan(starts, goals, static_obstacles=static_xy, t0=3, static_segments=[(p, q)]))
    assert first.expansions > 0
    if budget < 100:
        assert first.failed or first.fallback  # the tight budget really exercises the failure passes
    # the rest of each plan as hints for the next call (the kept-path check and extension)
    nxt: dict[Agent, Cell] = {a: path[1] for a, path in first.paths.items()}
    hints: dict[Agent, tuple[Sequence[Cell], Cell]] = {a: (first.paths[a][1:], first.goals[a]) for a in starts}
    _same(fast.plan(nxt, goals, t0=4, hints=hints), slow.plan(nxt, goals, t0=4, hints=hints))


def test_packed_crowd_with_cornered_agents_plans_the_same(grid: NavGrid) -> None:
    # As many bodies as fit 2 cells apart: many searches fail, so the repair passes reserve
    # and release waits (the compiled release of one agent's reservation is exercised).
    rng = np.random.default_rng(11)
    cells = _free_cells(grid)
    starts: dict[Agent, Cell] = dict(enumerate(_spaced(cells, 200, rng)))
    goals: dict[Agent, Cell | None] = dict(enumerate(_spaced(cells, len(starts), rng)))
    fast = PathPlanner(grid, seed=0).plan(starts, goals)
    assert len(fast.failed) > 5 and len(starts) > 100
    _same(fast, PathPlanner(grid, seed=0, backend="python").plan(starts, goals))


def test_released_reservation_equals_never_reserved(grid: NavGrid) -> None:
    planner = PathPlanner(grid, seed=0)
    cells = _free_cells(grid)
    rng = np.random.default_rng(3)
    agents = _spaced(cells, 12, rng)
    paths = {}
    for k, c in enumerate(agents):  # short random walks of 4 steps from each start
        ids = [planner.cell_id(c)]
        for _ in range(4):
            moves = [nb[0] for nb in planner.tables.nbrs[ids[-1]]]
            ids.append(moves[int(rng.integers(len(moves)))])
        paths[k] = ids
    dense, plain = DenseReservations(4, planner.tables), Reservations(4, planner.tables)
    grown = DenseReservations(4, planner.tables, agents=1)  # its agent columns grow as agents come
    for k, ids in paths.items():
        dense.add(k, ids, 4)
        plain.add(k, ids, 4)
        grown.add(k, ids, 4)
    for k in (3, 7, 0):
        dense.remove(k, paths[k], 4)
        plain.remove(k, paths[k], 4)
        grown.remove(k, paths[k], 4)
    assert np.array_equal(grown.near, dense.near)
    fresh = DenseReservations(4, planner.tables)
    for k, ids in paths.items():
        if k not in (3, 7, 0):
            fresh.add(k, ids, 4)
    assert np.array_equal(dense.near, fresh.near)
    for t in range(4):
        row = np.full(dense.near.shape[1], planner.tables.full_mask, dtype=np.int64)
        for cid, mask in plain.near[t].items():
            row[cid] = mask
        assert np.array_equal(dense.near[t], row)
    assert (dense.near != planner.tables.full_mask).any()


def test_compiled_crowd_walks_the_same_trajectories(grid: NavGrid) -> None:
    rng = np.random.default_rng(7)
    cells = _free_cells(grid)
    starts = _spaced(cells, 16, rng)
    goal_seq = [[cells[int(i)] for i in rng.integers(len(cells), size=4)] for _ in starts]
    traces = {}
    for backend in ("numba", "python"):
        nav = CrowdNavigator(grid, PathPlanner(grid, seed=0, backend=backend), seed=0)
        for k, s in enumerate(starts):
            nav.add_walker(f"w{k}", s, goal_seq[k][0])
        legs = dict.fromkeys(range(len(starts)), 0)
        out = []
        for _ in range(600):
            pos = nav.tick()
            out.append(np.array([pos[f"w{k}"] for k in range(len(starts))]))
            for _, agent in nav.arrivals:
                assert isinstance(agent, str)  # the walkers are named w0, w1, ...
                k = int(agent[1:])
                if legs[k] + 1 < len(goal_seq[k]):
                    legs[k] += 1
                    nav.set_goal(agent, goal_seq[k][legs[k]])
            nav.arrivals.clear()
        traces[backend] = np.array(out)
    assert np.array_equal(traces["numba"], traces["python"])
    assert np.ptp(traces["numba"], axis=0).max() > 1.0  # they really walked


def test_unknown_backend_is_a_typed_error(grid: NavGrid) -> None:
    with pytest.raises(PlanningError, match="backend"):
        PathPlanner(grid, backend=cast(Backend, "cuda"))  # not a Backend on purpose: the refusal is checked


def test_repair_pass_reuses_unchanged_searches_exactly(grid: NavGrid) -> None:
    # A repair pass given the pass before takes that pass's outcome for agents whose reads are
    # unchanged; its result equals a repair pass that searches every agent again.
    rng = np.random.default_rng(11)
    cells = _free_cells(grid)
    starts: dict[Agent, Cell] = dict(enumerate(_spaced(cells, 40, rng)))
    planner = PathPlanner(grid, seed=0, max_expansions=60)  # a tight budget: a few searches fail
    goals = planner.plan(starts, dict(enumerate(_spaced(cells, len(starts), rng)))).goals  # usable goals
    order = list(starts)
    allow = planner.tables.all_allowed
    first, record = planner._dense_pass(order, starts, goals, frozenset(), frozenset(), {}, allow)
    assert first.failed
    again, outcomes = planner._dense_pass(order, starts, goals, frozenset(), first.failed, {}, allow,
                                          previous=(record, frozenset()))
    fresh, _ = planner._dense_pass(order, starts, goals, frozenset(), first.failed, {}, allow)
    _same(again, fresh)
    assert 0 < outcomes.taken.sum() < len(order)  # some taken over, some searched again
    assert not record.taken.any()  # (a pass without a pass before searches every agent)


def test_goal_distances_equal_scipy_dijkstra_bit_for_bit(grid: NavGrid) -> None:
    """Every free cell of the Office as a goal (and a blocked one): the same floats, inf alike."""
    planner = PathPlanner(grid)
    blocked = np.argwhere(~grid.free)[0]
    goals = [(int(i), int(j)) for i, j in np.argwhere(grid.free)] + [(int(blocked[0]), int(blocked[1]))]
    for goal in goals:
        got = planner.heuristic_array(goal)
        want = scipy_goal_distances(planner, goal)
        assert np.array_equal(got, want), goal
    # some cells are unreachable from some goals (blocked goal: only itself is at 0)
    assert np.isinf(planner.heuristic_array(goals[-1])).sum() == got.size - 1


def test_a_small_goal_distance_cache_plans_the_same(grid: NavGrid) -> None:
    # More goals in one call than the cache holds: a pass never evicts a row it has read (the
    # table grows instead), later calls evict the oldest goals; plans stay those of a large cache.
    rng = np.random.default_rng(5)
    cells = _free_cells(grid)
    small, large = PathPlanner(grid, seed=0), PathPlanner(grid, seed=0)
    small.distances.capacity = 4
    for t0 in range(3):
        starts: dict[Agent, Cell] = dict(enumerate(_spaced(cells, 12, rng)))
        goals: dict[Agent, Cell | None] = {a: cells[int(rng.integers(len(cells)))] for a in starts}
        _same(small.plan(starts, goals, t0=t0), large.plan(starts, goals, t0=t0))
        assert len(small.distances.rows) >= 12 > small.distances.capacity
    assert small.distances.table is not None and len(small.distances.table) < 3 * 12  # evicted rows were reused

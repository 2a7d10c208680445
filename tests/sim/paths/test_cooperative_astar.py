"""WHCA*: shortest when alone, conflict-free together, corridor swap solved by the fallback."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from storyteller.sim.paths.cooperative_astar import PathPlanner, PlanningError, plan_conflicts, position_at
from storyteller.sim.paths.following import CrowdNavigator
from storyteller.sim.paths.move_tables import Neighbour
from storyteller.sim.paths.nav_grid import MOVES, NavGrid, body_clearance, build_nav_grid
from storyteller.sim.paths.plan_types import Agent, Cell
from storyteller.sim.scene.model import Scene, SceneObject


def _box(name: str, x: float, y: float, w: float, d: float) -> SceneObject:
    label, idx = name.rsplit("_", 1)
    return SceneObject(name=name, label=label, idx=int(idx), center=(x, y, 0.4), size=(w, d, 0.8))


def _cluttered() -> NavGrid:
    objs = (_box("table_1", 1.5, 1.5, 1.0, 0.6), _box("table_2", 3.6, 2.6, 0.6, 1.6), _box("shelf_1", 2.4, 3.6, 1.8, 0.3))
    return build_nav_grid(Scene(name="room", bounds_min=(0, 0), bounds_max=(5.4, 4.8), objects=objs))


GRID = _cluttered()
PLANNER = PathPlanner(GRID, window=40)
FREE: list[Cell] = [(int(i), int(j)) for i, j in np.argwhere(GRID.component == GRID.main_component)]


def _dijkstra_len(grid: NavGrid, a: tuple[int, int], b: tuple[int, int]) -> float:
    import heapq

    dist = {a: 0.0}
    heap = [(0.0, a)]
    while heap:
        d, c = heapq.heappop(heap)
        if c == b:
            return d
        if d > dist[c]:
            continue
        for k, (dx, dy) in enumerate(MOVES):
            if grid.moves[c[0], c[1], k]:
                n = (c[0] + dx, c[1] + dy)
                nd = d + math.hypot(dx, dy)
                if nd < dist.get(n, math.inf):
                    dist[n] = nd
                    heapq.heappush(heap, (nd, n))
    return math.inf


@settings(max_examples=25, deadline=None)
@given(st.integers(0, len(FREE) - 1), st.integers(0, len(FREE) - 1))
def test_single_agent_path_is_connected_clear_and_shortest(i: int, j: int) -> None:
    start, goal = FREE[i], FREE[j]
    path = PLANNER.plan({"a": start}, {"a": goal}).paths["a"]
    assert path[0] == start
    length = 0.0
    for p, q in itertools.pairwise(path):
        d = (q[0] - p[0], q[1] - p[1])
        if d != (0, 0):
            assert GRID.moves[p[0], p[1], MOVES.index(d)]  # 8-connected, clear, no corner cut
            length += math.hypot(*d)
    best = _dijkstra_len(GRID, start, goal)
    if best <= PLANNER.window:  # reachable inside the window: exactly as short as Dijkstra
        assert path[-1] == goal
        assert math.isclose(length, best, abs_tol=1e-9)


@settings(max_examples=15, deadline=None)
@given(st.integers(2, 12), st.integers(0, 10_000))
def test_group_plans_have_no_conflicts_inside_the_window(n: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    chosen: list[tuple[int, int]] = []
    for k in rng.permutation(len(FREE)):
        c = FREE[k]
        if all(max(abs(c[0] - o[0]), abs(c[1] - o[1])) >= 2 for o in chosen):
            chosen.append(c)
    if len(chosen) < 2 * n:
        n = len(chosen) // 2
    starts: dict[Agent, Cell] = {a: chosen[a] for a in range(n)}
    goals: dict[Agent, Cell | None] = {a: chosen[n + a] for a in range(n)}
    planner = PathPlanner(GRID, window=20, seed=seed)
    result = planner.plan(starts, goals)
    ok = {a: p for a, p in result.paths.items() if a not in result.failed}
    # Planned agents: no vertex, swap, following or clearance conflict over the whole window.
    if len(ok) > 1:
        assert plan_conflicts(ok, GRID.cell_size, GRID.body_radius) == []
    # Everyone, including agents that wait because their search failed: the committed steps.
    assert plan_conflicts(result.paths, GRID.cell_size, GRID.body_radius, steps=planner.commit_steps) == []
    for path in result.paths.values():
        for p, q in itertools.pairwise(path):
            assert max(abs(q[0] - p[0]), abs(q[1] - p[1])) <= 1
            assert GRID.free[q]


def test_adjacent_cells_are_a_conflict_but_a_knight_move_apart_is_not() -> None:
    assert plan_conflicts({"a": [(2, 2), (2, 2)], "b": [(4, 2), (3, 2)]}, 0.3, 0.25)
    assert not plan_conflicts({"a": [(2, 2), (2, 2)], "b": [(4, 3), (4, 4)]}, 0.3, 0.25)
    # Diagonal crossing: both ends 2 cells apart, but they pass 0.42 m apart mid-step.
    assert plan_conflicts({"a": [(2, 0), (1, 1)], "b": [(0, 0), (1, -1)]}, 0.3, 0.25)


def _corridor() -> NavGrid:
    # A corridor one body wide (row j = 2) with a side pocket (column i = 12, rows 3-6).
    objs = (
        _box("wall_1", 3.6, 0.15, 7.2, 0.3),
        _box("wall_2", 1.65, 1.35, 3.3, 0.3),
        _box("wall_3", 5.7, 1.35, 3.0, 0.3),
    )
    return build_nav_grid(Scene(name="corridor", bounds_min=(0, 0), bounds_max=(7.2, 2.4), objects=objs))


def test_corridor_swap_is_solved_with_fallback_and_stays_clear() -> None:
    # Solved because walkers keep a still-valid plan every other replan (reuse_plans, the
    # default); searching every replan, prioritized planning ping-pongs here (the pushed agent
    # must enter the pocket before the other arrives): see the test below.
    grid = _corridor()
    row = [(int(i), int(j)) for i, j in np.argwhere(grid.free) if j == 2]
    left, right = (int(min(row)[0]), 2), (int(max(row)[0]), 2)
    nav = CrowdNavigator(grid, PathPlanner(grid, window=8), seed=0)
    nav.add_walker("a", left, right)
    nav.add_walker("b", right, left)
    trace = []
    for _ in range(30 * 60):
        pos = nav.tick()
        trace.append(np.linalg.norm(pos["a"] - pos["b"]))
        if len(nav.arrivals) == 2:
            break
    assert sorted((a for _, a in nav.arrivals), key=str) == ["a", "b"]
    assert nav.fallbacks > 0  # plain WHCA* got cornered; the fallback pass planned it
    assert min(trace) >= 2 * grid.body_radius - 1e-9


@pytest.mark.xfail(
    strict=True,
    reason="known limitation of prioritized planning searching every replan (reuse_plans=False): ping-pong in "
    "a corridor swap (a swap needs the pushed agent to enter the pocket before the other arrives; CBS-level)",
)
def test_corridor_swap_without_plan_reuse_ping_pongs() -> None:
    grid = _corridor()
    row = [(int(i), int(j)) for i, j in np.argwhere(grid.free) if j == 2]
    left, right = (int(min(row)[0]), 2), (int(max(row)[0]), 2)
    nav = CrowdNavigator(grid, PathPlanner(grid, window=8), seed=0, reuse_plans=False)
    nav.add_walker("a", left, right)
    nav.add_walker("b", right, left)
    for _ in range(30 * 60):
        nav.tick()
        if len(nav.arrivals) == 2:
            break
    assert sorted((a for _, a in nav.arrivals), key=str) == ["a", "b"]


def test_position_at_interpolates_at_walking_speed() -> None:
    path = [(2, 2), (3, 2), (4, 3)]
    p = position_at(path, 0.15, GRID, 0.3)
    assert np.allclose(p, (GRID.center_of(2, 2) + GRID.center_of(3, 2)) / 2)
    assert np.allclose(position_at(path, 10.0, GRID, 0.3), GRID.center_of(4, 3))


def test_exact_off_grid_targets_are_reached_and_left_with_clearance() -> None:
    grid = GRID
    nav = CrowdNavigator(grid, PathPlanner(grid, window=20), seed=0)
    target = grid.center_of(*FREE[40]) + np.array([0.11, -0.07])
    goal = grid.entry_cell(target)
    assert goal is not None and nav.target_problem(goal, target) is None
    nav.add_walker("a", FREE[0], goal, final_xy=target)
    nav.add_walker("b", FREE[-1], FREE[5])
    trace = []
    for _ in range(30 * 40):
        pos = nav.tick()
        trace.append(pos)
        if any(a == "a" for _, a in nav.arrivals):
            break
    assert np.allclose(nav.position("a"), target)  # ends exactly on the point, not a cell centre
    assert math.isfinite(nav.heading("a"))
    nav.set_goal("a", FREE[0])  # leaves the point back onto the grid
    for _ in range(30 * 40):
        trace.append(nav.tick())
        if sum(a == "a" for _, a in nav.arrivals) == 2:
            break
    assert sum(a == "a" for _, a in nav.arrivals) == 2
    d = [np.linalg.norm(p["a"] - p["b"]) for p in trace]
    assert min(d) >= 2 * grid.body_radius - 1e-9
    xy = np.array([p["a"] for p in trace])
    assert (body_clearance(grid.obstacles, xy, xy) >= grid.body_radius - 1e-9).all()


def test_a_target_inside_furniture_is_reported_not_walked_into() -> None:
    nav = CrowdNavigator(GRID, seed=0)
    nav.add_walker("a", FREE[0])
    with pytest.raises(PlanningError, match="table_1"):
        nav.set_goal("a", GRID.nearest_free_cell((1.5, 0.9)), final_xy=(1.5, 1.5))


def _overrides_reference(planner: PathPlanner, segs: list[tuple[np.ndarray, np.ndarray]]) -> dict[int, list[Neighbour]]:
    """Direct per-cell computation of the moves kept next to static discs / segments."""
    from storyteller.sim.paths.cooperative_astar import segment_distance

    g, cs = planner.grid, planner.grid.cell_size
    ps = np.array([p for p, _ in segs])
    qs = np.array([q for _, q in segs])
    out = {}
    for cid, nbs in planner.tables.nbrs.items():
        a = g.center_of(*planner.id_cell(cid))
        aa = np.broadcast_to(a, ps.shape)
        limit = np.minimum(planner.min_distance, segment_distance(aa, aa, ps, qs)) - 1e-7
        kept = [nb for nb in nbs
                if np.all(segment_distance(aa, np.broadcast_to(a + np.array(nb[2:4], float) * cs, ps.shape), ps, qs) >= limit)]
        if len(kept) != len(nbs):
            out[cid] = kept
    return out


def test_memoised_static_overrides_match_a_direct_computation() -> None:
    planner = PathPlanner(GRID)
    rng = np.random.default_rng(5)
    cells = [FREE[k] for k in rng.choice(len(FREE), 4, replace=False)]
    discs = [GRID.center_of(*c) + rng.normal(scale=0.1, size=2) for c in cells[:3]]
    leg = (GRID.center_of(*cells[3]), GRID.center_of(*cells[3]) + np.array([0.12, 0.2]))
    want = _overrides_reference(planner, [leg] + [(p, p) for p in discs])
    for _ in range(2):  # second call: from the memo
        got = planner.statics.static_overrides(discs, [leg])
        assert got == want
    assert want  # the discs do remove moves


def test_kept_plans_alternate_with_searches_and_stay_conflict_free() -> None:
    nav = CrowdNavigator(GRID, PathPlanner(GRID, window=20), seed=0, reuse_plans=True)
    rng = np.random.default_rng(2)
    picks = rng.choice(len(FREE), 12, replace=False)
    starts, goals = [FREE[k] for k in picks[:6]], [FREE[k] for k in picks[6:]]
    for i, (s, g) in enumerate(zip(starts, goals, strict=True)):
        nav.add_walker(i, s, g)
    kept_before: frozenset[Agent] = frozenset()
    kept_total = 0
    for _ in range(30 * 12):
        nav.tick()
        res = nav.last_result
        if nav.frame % nav.step_frames == 1 and res is not None:  # just replanned
            assert not (res.reused & kept_before)  # never kept two replans in a row
            kept_before = res.reused
            kept_total += len(res.reused)
            planned = {a: p for a, p in res.paths.items() if len(p) > 1}
            assert plan_conflicts(planned, GRID.cell_size, GRID.body_radius, steps=1) == []
    assert kept_total > 0
    nav2 = CrowdNavigator(GRID, PathPlanner(GRID, window=20), seed=0, reuse_plans=False)  # always search
    for i, (s, g) in enumerate(zip(starts, goals, strict=True)):
        nav2.add_walker(i, s, g)
    for _ in range(30 * 3):
        nav2.tick()
        assert nav2.last_result is not None and not nav2.last_result.reused

"""Two walkers passing each other in a corridor with room to spare reach their goals.

The scene: a corridor four cells wide, and a passage two cells wide (0.6 m) leaving it downwards
at its west end. Walker ``a`` goes east along the corridor, walker ``b`` comes west past it and turns
down the passage. When every repaired failure (a search that failed and a repair pass planned)
raised the failed walker's priority, each replan cornered the other walker, so the order
flipped at every step and the pair stepped back and forth between two rows for good (6 of these
12 starts and seeds; the 50-walker Office crowd had such a pair side by side 0.6 m apart for
its whole 20 s). ``PriorityKeeper`` raises the boost of a repaired walker once.
"""

from __future__ import annotations

from collections.abc import Hashable

import pytest

from storyteller.sim.paths.cooperative_astar import PathPlanner
from storyteller.sim.paths.fallback import PriorityKeeper
from storyteller.sim.paths.following import CrowdNavigator
from storyteller.sim.paths.nav_grid import NavGrid, build_nav_grid
from storyteller.sim.scene.model import Scene, SceneObject


def _wall(name: str, x: float, y: float, w: float, d: float) -> SceneObject:
    label, idx = name.rsplit("_", 1)
    return SceneObject(name=name, label=label, idx=int(idx), center=(x, y, 0.4), size=(w, d, 0.8))


def _ell() -> NavGrid:
    objs = (_wall("wall_1", 0.35, 1.2, 0.7, 2.4), _wall("wall_2", 3.85, 1.2, 4.3, 2.4))
    return build_nav_grid(Scene(name="ell", bounds_min=(0, 0), bounds_max=(6.0, 4.0), objects=objs))


GRID = _ell()
PASSAGE = min(i for i in range(GRID.shape[0]) if GRID.is_free(i, 2))  # its western column
BOTTOM = min(j for j in range(GRID.shape[1]) if GRID.is_free(PASSAGE + 3, j))  # the corridor's lowest row


def test_the_scene_is_a_corridor_with_a_narrow_passage() -> None:
    assert [i for i in range(GRID.shape[0]) if GRID.is_free(i, 2)] == [PASSAGE, PASSAGE + 1]
    assert all(GRID.is_free(i, j) for i in range(PASSAGE, PASSAGE + 12) for j in range(BOTTOM, BOTTOM + 4))


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("upper", ["a", "b"])
def test_walkers_passing_in_a_corridor_do_not_step_back_and_forth(seed: int, upper: str) -> None:
    a_start = (PASSAGE + 2, BOTTOM + (upper == "a"))
    b_start = (PASSAGE + 4, BOTTOM + (upper == "b"))
    nav = CrowdNavigator(GRID, PathPlanner(GRID, seed=seed), seed=seed)
    nav.add_walker("a", a_start, (PASSAGE + 11, BOTTOM))
    nav.add_walker("b", b_start, (PASSAGE, 1))
    for _ in range(30 * 15):  # 15 s; alone, each needs about 3.5 s
        nav.tick()
        if len(nav.arrivals) == 2:
            break
    assert sorted(str(a) for _, a in nav.arrivals) == ["a", "b"]


def test_a_repaired_failure_boosts_once_and_the_latest_boost_plans_first() -> None:
    keeper = PriorityKeeper(seed=0)
    dist: dict[Hashable, float] = {"a": 5.0, "b": 5.0}
    keeper.observe(dist, failed=(), repaired=("b",))
    assert keeper.order(["a", "b"], [])[0] == "b"
    keeper.observe(dist, failed=(), repaired=("a",))  # b cornered a: a's boost, given last, ranks first
    assert keeper.order(["a", "b"], [])[0] == "a"
    keeper.observe(dist, failed=(), repaired=("b",))  # b was boosted already: the order stays
    assert keeper.order(["a", "b"], []) == ["a", "b"]
    assert keeper.boost == {"a": 1, "b": 1}
    keeper.observe(dist, failed=("b",))  # left waiting: raised every time
    keeper.observe(dist, failed=("b",))
    assert keeper.boost["b"] == 3 and keeper.order(["a", "b"], [])[0] == "b"

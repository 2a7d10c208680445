"""The position sampler returns only floor a character can walk to (home_tv_evening: a "free"
point in a pocket between armchair_1, table_2 and tv_stand_1 made the event fail in the world)."""

from __future__ import annotations

import numpy as np
import pytest

from storyteller.sim.scene.bundled import resolve_scene
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.areas import Area, close_to
from storyteller.tools.errors import UnsatisfiableAreaError
from storyteller.tools.position_sampling import Constraints, FloorMap, sample_position, scene_nav_grid


def test_the_pocket_point_of_home_tv_evening_is_free_but_not_reachable() -> None:
    floor = FloorMap(resolve_scene("home"))
    p = np.array([[3.20, 7.09]])
    assert floor.free(p).all() and not floor.reachable(p).any()


def test_reachable_is_the_planner_entry_cell_test_on_the_main_component() -> None:
    scene = resolve_scene("home")
    floor, grid = FloorMap(scene), scene_nav_grid(scene)
    rng = np.random.default_rng(3)
    pts = rng.uniform(scene.bounds_min, scene.bounds_max, size=(400, 2))
    pts = np.concatenate([pts[floor.free(pts)], [[3.20, 7.09]]])
    oracle = [grid.entry_cell(p, component=grid.main_component) is not None for p in pts]
    assert floor.reachable(pts).tolist() == oracle
    assert not oracle[-1] and any(oracle)


def test_samples_near_the_tv_furniture_are_all_reachable() -> None:
    scene = resolve_scene("home")
    floor = FloorMap(scene)
    for name in ("tv_stand_1", "table_2", "armchair_1"):
        area = close_to(scene.by_name[name])
        pts = np.array([sample_position(area, floor, Constraints(), np.random.default_rng(k)).position
                        for k in range(30)])
        assert floor.reachable(pts).all(), name


def _wall(name: str, x: float, y: float, w: float, d: float) -> SceneObject:
    label, idx = name.rsplit("_", 1)
    return SceneObject(name=name, label=label, idx=int(idx), center=(x, y, 0.5), size=(w, d, 1.0))


def test_an_area_whose_free_floor_is_enclosed_fails_at_sampling_time() -> None:
    # a 1.2 m pen of four shelves in the middle of a 6 m room: free floor inside, no way in
    scene = Scene(name="pen", bounds_min=(0.0, 0.0), bounds_max=(6.0, 6.0), objects=(
        _wall("shelf_1", 3.0, 2.2, 1.8, 0.2), _wall("shelf_2", 3.0, 3.8, 1.8, 0.2),
        _wall("shelf_3", 2.2, 3.0, 0.2, 1.8), _wall("shelf_4", 3.8, 3.0, 0.2, 1.8)))
    floor = FloorMap(scene)

    def inside(p: np.ndarray) -> np.ndarray:
        within: np.ndarray = np.all(np.abs(p - 3.0) <= 0.45, axis=1)
        return within

    pen = Area("inside the pen", inside, (2.55, 2.55, 3.45, 3.45))
    assert floor.free(np.array([[3.0, 3.0]])).all()
    with pytest.raises(UnsatisfiableAreaError, match="no reachable floor"):
        sample_position(pen, floor, Constraints(), np.random.default_rng(0))

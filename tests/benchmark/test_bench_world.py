"""benchmark/crowd_scenario.py's ``tiled``: the larger layouts ("Office x4", "Office x16") the world
benchmark's big crowds walk in are copies of one scene side by side, and the navigation grid builds on them."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from storyteller.benchmark.crowd_scenario import tiled
from storyteller.sim.paths.cooperative_astar import PathPlanner
from storyteller.sim.paths.nav_grid import build_nav_grid
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import NavHints, Scene, SceneObject
from tests.support.reference import OFFICE, requires_reference

# a 4.2 m x 3 m room (14 x 10 cells of 0.3 m) with a table and a chair well inside its walls, and
# one reference-style cell override (tiled drops overrides: they name cells of the one copy)
ROOM = Scene(
    name="room", bounds_min=(0.0, 0.0), bounds_max=(4.2, 3.0),
    objects=(
        SceneObject(name="table_1", label="table", idx=1, center=(1.5, 1.5, 0.4), size=(1.2, 0.6, 0.8)),
        SceneObject(name="chair_1", label="chair", idx=1, center=(3.3, 0.9, 0.45), size=(0.45, 0.45, 0.9),
                    facing=(0.0, 1.0), has_facing=True),
    ),
    nav=NavHints(occupied=((0, 0),)),
)


def _tile_of(scene: Scene, nx: int, ny: int, xy: np.ndarray) -> tuple[int, int]:
    w = (scene.bounds_max[0] - scene.bounds_min[0]) / nx
    h = (scene.bounds_max[1] - scene.bounds_min[1]) / ny
    return (math.floor((xy[0] - scene.bounds_min[0]) / w), math.floor((xy[1] - scene.bounds_min[1]) / h))


def test_tiled_has_a_copy_of_every_object_per_tile_each_inside_its_own_tile() -> None:
    nx, ny = 3, 2
    big = tiled(ROOM, nx, ny)
    assert big.name == "room x6"
    assert big.bounds_min == (0.0, 0.0) and big.bounds_max == pytest.approx((12.6, 6.0))
    assert big.nav.occupied == () and big.nav.unoccupied == ()
    assert len(big.objects) == nx * ny * len(ROOM.objects)
    assert len({o.name for o in big.objects}) == len(big.objects)  # renamed: no two copies share a name
    # per label, the copies are numbered 0.. in order and named after it
    for label, count in Counter(o.label for o in big.objects).items():
        assert count == nx * ny
        assert sorted(o.idx for o in big.objects if o.label == label) == list(range(count))
    assert all(o.name == f"{o.label}_{o.idx}" for o in big.objects)
    # each original's copies: the same box and facing, offset by whole tiles, one per tile
    for orig in ROOM.objects:
        copies = [o for o in big.objects if o.label == orig.label]
        offsets = {(round(o.center[0] - orig.center[0], 9), round(o.center[1] - orig.center[1], 9)) for o in copies}
        assert offsets == {(round(a * 4.2, 9), round(b * 3.0, 9)) for a in range(nx) for b in range(ny)}
        assert all(o.center[2] == orig.center[2] and o.size == orig.size and o.facing == orig.facing for o in copies)
    # disjoint: every object's footprint lies in a single tile, and each tile holds one copy of each
    per_tile: Counter[tuple[int, int]] = Counter()
    for o in big.objects:
        half = np.abs(o.right) * o.width / 2 + np.abs(np.asarray(o.facing)) * o.depth / 2  # axis-aligned extent
        lo, hi = _tile_of(big, nx, ny, o.center_xy - half), _tile_of(big, nx, ny, o.center_xy + half)
        assert lo == hi, o.name
        per_tile[lo] += 1
    assert per_tile == {(a, b): len(ROOM.objects) for a in range(nx) for b in range(ny)}


def test_a_nav_grid_builds_on_the_tiled_scene_and_walks_across_tiles() -> None:
    one, big = build_nav_grid(ROOM.model_copy(update={"nav": NavHints()})), build_nav_grid(tiled(ROOM, 3, 2))
    k, m = round(4.2 / one.cell_size), round(3.0 / one.cell_size)  # a copy spans k x m cells
    assert big.shape[0] >= 3 * k and big.shape[1] >= 2 * m
    # no walls between the copies: every free cell of the room is free in each copy
    for a in range(3):
        for b in range(2):
            assert np.all(big.free[a * k:(a + 1) * k, b * m:(b + 1) * m][one.free[:k, :m]]), (a, b)
    assert int(big.free.sum()) > 6 * int(one.free.sum())  # and the walls between them are floor
    # one walkable component from the first copy to the last
    cells = np.argwhere(big.free)
    start, goal = (int(cells[0][0]), int(cells[0][1])), (int(cells[-1][0]), int(cells[-1][1]))
    assert start[0] < k and goal[0] >= 2 * k and goal[1] >= m  # in the first copy and the last
    assert big.component[start] == big.component[goal] == big.main_component
    assert PathPlanner(big).distance(start, goal) < math.inf


@requires_reference
def test_office_x4_has_four_offices_of_objects_and_one_walkable_floor() -> None:
    office = load_scene(OFFICE)
    x4 = tiled(office, 2, 2)
    assert x4.name == f"{office.name} x4" and len(x4.objects) == 4 * len(office.objects)
    assert Counter(o.label for o in x4.objects) == Counter({k: 4 * v for k, v in Counter(o.label for o in office.objects).items()})
    grid = build_nav_grid(x4)
    walkable = grid.component == grid.main_component
    half = (grid.shape[0] // 2, grid.shape[1] // 2)  # the main component reaches into every copy
    assert all(walkable[a * half[0]:(a + 1) * half[0], b * half[1]:(b + 1) * half[1]].any() for a in (0, 1) for b in (0, 1))

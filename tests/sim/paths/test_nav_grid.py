"""Navigation grid: blocking, bounds, reference overrides, seats, exact move clearance."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from storyteller.sim.paths.nav_grid import (
    MOVES,
    NavGridError,
    body_clearance,
    build_nav_grid,
    with_reference_grid_origin,
)
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import NavHints, Scene, SceneObject
from tests.support.reference import SCENES, reference_or_skip, requires_reference


def _box(name: str, center: tuple[float, float, float], size: tuple[float, float, float], **kw: object) -> SceneObject:
    label, idx = name.rsplit("_", 1)
    return SceneObject(name=name, label=label, idx=int(idx), center=center, size=size, **kw)


def _room(*objects: SceneObject, nav: NavHints | None = None) -> Scene:
    return Scene(name="room", bounds_min=(0.0, 0.0), bounds_max=(6.0, 4.0), objects=objects, nav=nav or NavHints())


def _office() -> Scene:
    reference_or_skip()
    return with_reference_grid_origin(load_scene(SCENES / "Office"), SCENES / "Office")


def test_floor_objects_block_with_body_radius_and_high_objects_do_not() -> None:
    table = _box("table_1", (3.0, 2.0, 0.4), (1.0, 1.0, 0.8))
    lamp = _box("lamp_1", (1.0, 1.0, 2.2), (0.5, 0.5, 0.2))  # hangs above head height
    tv = _box("tv_1", (5.0, 3.0, 1.3), (1.0, 0.1, 0.8))  # wall TV at chest height
    grid = build_nav_grid(_room(table, lamp, tv), cell_size=0.2, body_radius=0.25)
    assert not grid.is_free_xy((3.0, 2.0))
    assert not grid.is_free_xy((3.0, 2.0 + 0.5 + 0.2))  # 0.2 m from the edge < radius
    assert grid.is_free_xy((3.0, 2.0 + 0.5 + 0.3))
    assert grid.is_free_xy((1.0, 1.0))
    assert not grid.is_free_xy((5.0, 3.0))
    centers = grid.centers(np.argwhere(grid.free))
    assert body_clearance(grid.obstacles, centers, centers).min() >= 0.25
    # bounds: a body never leaves the floor rectangle
    assert centers[:, 0].min() >= 0.25 and centers[:, 0].max() <= 6.0 - 0.25


def test_cell_indexing_round_trips() -> None:
    grid = build_nav_grid(_room(), cell_size=0.3)
    for i, j in [(0, 0), (3, 7), (grid.shape[0] - 1, grid.shape[1] - 1)]:
        assert grid.cell_of(grid.center_of(i, j)) == (i, j)
    assert grid.nearest_free_cell((-5.0, -5.0)) == (1, 1)


def test_thin_object_between_free_cells_blocks_the_move() -> None:
    # A thin pole exactly between two cell centres: both cells are free, the move is not.
    # Cells (5, 6) and (6, 6) have centres (1.65, 1.95) and (1.95, 1.95).
    pole = _box("pole_1", (1.8, 1.95 + 0.24, 0.5), (0.01, 0.01, 1.0))
    grid = build_nav_grid(_room(pole), cell_size=0.3, body_radius=0.25)
    a, b = (5, 6), (6, 6)
    assert grid.is_free(*a) and grid.is_free(*b)
    assert not grid.move_allowed(a, MOVES.index((1, 0)))


@settings(max_examples=30, deadline=None)
@given(
    x=st.floats(0.5, 5.5),
    y=st.floats(0.5, 3.5),
    w=st.floats(0.05, 2.0),
    d=st.floats(0.05, 2.0),
    angle=st.floats(0.0, 6.283),
)
def test_every_allowed_move_keeps_the_body_clear(x: float, y: float, w: float, d: float, angle: float) -> None:
    obj = _box("crate_1", (x, y, 0.3), (w, d, 0.6), facing=(float(np.cos(angle)), float(np.sin(angle))))
    grid = build_nav_grid(_room(obj), cell_size=0.3, body_radius=0.25)
    for k, (dx, dy) in enumerate(MOVES):
        src = np.argwhere(grid.moves[:, :, k])
        a = grid.centers(src)
        b = a + np.array([dx, dy]) * grid.cell_size
        s = np.linspace(0.0, 1.0, 11)[:, None, None]
        pts = (a[None] + s * (b - a)[None]).reshape(-1, 2)
        assert np.all(~obj.contains_xy(pts, margin=0.25 - 1e-6) | (body_clearance([obj], pts, pts) >= 0.25 - 1e-9))
        if dx and dy:  # no corner cutting
            assert np.all(grid.free[src[:, 0] + dx, src[:, 1]]) and np.all(grid.free[src[:, 0], src[:, 1] + dy])


def test_office_reference_overrides_draw_the_walls() -> None:
    scene = _office()
    grid = build_nav_grid(scene)
    # Every in-bounds cell the reference marks occupied (and not unoccupied) is blocked.
    unocc = set(scene.nav.unoccupied)
    for a, b in scene.nav.occupied:
        cell = grid.reference_cell(a, b)
        assert cell is not None
        if (a, b) not in unocc and grid.in_grid(*cell):
            assert not grid.free[cell]
    # The wall between the lounge and the desks (reference column 24-26 at row 10) is closed...
    assert not any(grid.free[grid.reference_cell(a, 10)] for a in (24, 25, 26))
    # ...and without overrides it is open floor.
    plain = build_nav_grid(scene, use_reference_overrides=False)
    wall = grid.reference_cell(25, 10)
    assert wall is not None and plain.is_free_xy(grid.center_of(*wall))


@pytest.mark.parametrize("name", ["House", "Office", "Restaurant"])
@requires_reference
def test_seats_have_reachable_approach_cells(name: str) -> None:
    scene = with_reference_grid_origin(load_scene(SCENES / name), SCENES / name)
    grid = build_nav_grid(scene)
    main = grid.main_component
    seats = [o for o in scene.objects if o.is_seat]
    near = 0
    for obj in seats:
        cell = grid.approach_cell(obj)
        assert grid.component[cell] == main
        near += bool(np.linalg.norm(grid.center_of(*cell) - obj.seat_point()) < 1.2)
    if name != "Office":  # Office chairs are tucked 0.37-0.46 m from their tables: no room for a body
        assert near >= 0.8 * len(seats)


def test_bad_parameters_are_typed_errors() -> None:
    with pytest.raises(NavGridError, match="cell_size"):
        build_nav_grid(_room(), cell_size=0.0)
    with pytest.raises(NavGridError, match="body_radius"):
        build_nav_grid(_room(), body_radius=float("nan"))


def test_office_approach_points_fit_a_body_and_are_reached_in_a_straight_line() -> None:
    scene = _office()
    grid = build_nav_grid(scene)
    for obj in [o for o in scene.objects if o.is_seat]:
        ap = grid.approach_point(obj)
        p = np.asarray(ap.xy)
        assert grid.is_free_xy(p)
        c = grid.center_of(*ap.cell)
        assert body_clearance(grid.obstacles, c[None], p[None])[0] >= grid.body_radius - 1e-9
        assert abs(ap.gap - float(np.linalg.norm(p - obj.seat_point()))) < 1e-9
        # never farther from the seat than the old approach cell's centre
        assert ap.gap <= np.linalg.norm(grid.center_of(*grid.approach_cell(obj)) - obj.seat_point()) + 1e-9 or (
            grid.component[ap.cell] != grid.main_component
        )


def test_body_clearance_cutoff_is_exact_below_the_cutoff_and_a_bound_above() -> None:
    scene = _office()
    grid = build_nav_grid(scene)
    rng = np.random.default_rng(3)
    lo, hi = np.asarray(scene.bounds_min), np.asarray(scene.bounds_max)
    a = lo + rng.random((400, 2)) * (hi - lo)
    b = a + rng.normal(scale=0.3, size=a.shape)
    b[:100] = a[:100]  # points too
    full = body_clearance(grid.obstacles, a, b)
    for cutoff in (0.0, 0.25, 0.6):
        cut = body_clearance(grid.obstacles, a, b, cutoff=cutoff)
        below = full < cutoff
        assert np.array_equal(cut[below], full[below])  # the very same floats
        assert np.all(cut[~below] >= cutoff)
        assert np.all(cut >= full)
    assert below.any() and (~below).any()


def test_a_seat_whose_front_is_closed_off_is_sat_on_from_a_near_side_not_from_far_in_front() -> None:
    """The bundled home's armchair faces a pocket between the couch and the TV stand that a body
    does not fit into: its approach point used to be 2 m away in front (a sit-down sliding past
    the couch); a point within ``MAX_SIT_SLIDE_M`` beside it comes first."""
    from storyteller.sim.paths.nav_grid import MAX_SIT_SLIDE_M
    from storyteller.sim.scene.bundled import load_bundled_scene

    scene = load_bundled_scene("home")
    grid = build_nav_grid(scene)
    armchair = scene.by_name["armchair_1"]
    ap = grid.approach_point(armchair, component=grid.main_component)
    assert ap.gap <= MAX_SIT_SLIDE_M
    assert grid.component[ap.cell] == grid.main_component
    # a seat with room in front is still approached from the front
    couch = scene.by_name["couch_1"]
    front = grid.approach_point(couch, component=grid.main_component)
    assert (np.asarray(front.xy) - couch.center_xy) @ np.asarray(couch.facing) > couch.depth / 2.0

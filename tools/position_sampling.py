"""Area-conditioned position sampling: an ``Area`` plus constraints -> one exact position.

Rules (all distances in metres):

- free floor: the body centre stays ``body_radius`` (0.25) inside the scene bounds and at least
  ``body_radius`` from the footprint of every floor-standing object;
- reachable: a character can walk there: some cell of the scene's main walkable component of
  the navigation grid (``storyteller.sim.paths.nav_grid``, the path planner's own clearance and cells)
  within two cells has a straight furniture-free walk to the point (``NavGrid.entry_cell``);
  free floor in a pocket enclosed by furniture is not admissible. The grid is built once per
  scene (cached);
- other characters: at least ``min_separation`` (0.5) from every point in ``avoid`` (other
  characters' positions and targets);
- group: when members of the same event were already placed, prefer points within
  ``group_radius`` (1.5) of all of them (a preference: if no such point exists, the area wins);
- seats: a seat slot is used as is (its position and the seat's facing); a slot is free when no
  avoided point is within ``min_separation`` of it and its object is not taken; an area with
  seat slots prefers them; when a companion of the same event already took every seat of the
  area, the nearest free seat of the same kind within ``NEIGHBOUR_SEAT_M`` stands in (the group
  sits together) — never a seat someone outside the event holds;
- margin: points that stay inside the area when moved 0.1 m in any axis direction are preferred
  (so that a tolerance-free check of the same relation still holds);
- the candidates are a lattice of step 0.05 with a seeded offset; one is drawn uniformly with a
  seeded ``numpy.random.Generator``: the same seed and inputs give the same position;
- relaxation: a single directional area (``storyteller.tools.areas.directional``) whose lattice has no
  free reachable point (whoever else is there) is replaced by its smallest relaxation that has
  an admissible point (``Area.relaxations``: the same side of the object, wider and further
  out), and within it the points nearest the strict area are drawn from (``RELAXED_BAND``).
  Only then: an area with room gives exactly the position it gives without relaxations, and
  combined areas, which have none, are never relaxed.

An area with no admissible point (nor, for a directional one, its widest relaxation) raises
``UnsatisfiableAreaError`` naming the reason; it never falls back to a random point.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.scene.model import FLOOR_STANDING_M, Scene
from storyteller.tools.areas import Area, SeatSlot, seat_slots
from storyteller.tools.errors import UnsatisfiableAreaError
from storyteller.tools.place_relations import table_of
from storyteller.tools.scene_graph import footprint_distance, point_footprint_distance

if TYPE_CHECKING:
    from storyteller.sim.paths.nav_grid import NavGrid

BODY_RADIUS = 0.25
MIN_SEPARATION = 0.5
GROUP_RADIUS = 1.5
LATTICE_STEP = 0.05
INTERIOR_MARGIN = 0.1
MAX_CANDIDATES = 250_000
FLOOR_SUPPORT = FLOOR_STANDING_M
RELAXED_BAND = 0.1
"""m: in a relaxed area, only points within this much of the smallest excess over the strict
area are drawn from (``storyteller.tools.areas.Relaxation.excess``)."""


class FloorMap:
    """Which xy points a standing character's centre may occupy."""

    def __init__(
        self, scene: Scene, body_radius: float = BODY_RADIUS, floor_support: float = FLOOR_SUPPORT
    ):
        self.scene = scene
        self.body_radius = body_radius
        self.obstacles = [o for o in scene.objects if abs(o.z_min - scene.floor_z) < floor_support]
        # built (or found in the cache) here, and the compiled reachability test loaded, before
        # any event program's time budget starts
        self.grid = scene_nav_grid(scene)
        self.reachable((np.asarray(scene.bounds_min) + np.asarray(scene.bounds_max)).reshape(1, 2) / 2.0)

    def free(self, xy: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Whether points (N, 2) are on free floor (inside the bounds, clear of furniture)."""
        p = np.asarray(xy, dtype=float).reshape(-1, 2)
        r = self.body_radius
        (x0, y0), (x1, y1) = self.scene.bounds_min, self.scene.bounds_max
        ok = (p[:, 0] >= x0 + r) & (p[:, 0] <= x1 - r) & (p[:, 1] >= y0 + r) & (p[:, 1] <= y1 - r)
        for obj in self.obstacles:
            if not ok.any():
                break
            idx = np.flatnonzero(ok)
            ok[idx] = point_footprint_distance(obj, p[idx]) >= r
        return ok

    def reachable(self, xy: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Whether points (N, 2) can be walked to (see the module docstring: an entry cell of
        the main walkable component with a straight clear walk to the point)."""
        p = np.asarray(xy, dtype=float).reshape(-1, 2)
        grid = self.grid
        from storyteller.sim.paths.nav_grid import body_clearance  # numba: only when sampling

        main = grid.main_component
        base = np.floor((p - np.asarray(grid.origin)) / grid.cell_size).astype(np.int64)
        nx, ny = grid.shape
        r = grid.body_radius
        ok = np.zeros(len(p), dtype=bool)
        # the point itself must be clear of everything the grid blocks (wall-mounted things too)
        ok |= body_clearance(grid.obstacles, p, p, cutoff=r) < r - 1e-9
        lo, hi = np.asarray(grid.bounds_min) + r, np.asarray(grid.bounds_max) - r
        ok |= np.any((p < lo) | (p > hi), axis=1)
        blocked = ok.copy()
        for di in range(-2, 3):
            for dj in range(-2, 3):
                todo = np.flatnonzero(~ok)
                if len(todo) == 0:
                    return ok & ~blocked
                i, j = base[todo, 0] + di, base[todo, 1] + dj
                inside = (i >= 0) & (i < nx) & (j >= 0) & (j < ny)
                todo, i, j = todo[inside], i[inside], j[inside]
                walk = grid.component[i, j] == main
                todo, i, j = todo[walk], i[walk], j[walk]
                if len(todo) == 0:
                    continue
                centres = grid.centers(np.stack([i, j], axis=1))
                clear = body_clearance(grid.obstacles, centres, p[todo], cutoff=r) >= r
                ok[todo[clear]] = True
        return ok & ~blocked

    def colliding_objects(self, xy: tuple[float, float]) -> list[str]:
        """Floor-standing objects whose footprint grown by the body radius contains ``xy``."""
        p = np.asarray(xy, dtype=float).reshape(1, 2)
        return [
            o.name
            for o in self.obstacles
            if float(point_footprint_distance(o, p)[0]) < self.body_radius
        ]


@lru_cache(maxsize=4)
def scene_nav_grid(scene: Scene) -> NavGrid:
    """The path planner's navigation grid of ``scene`` (built once per scene content)."""
    from storyteller.sim.paths.nav_grid import build_nav_grid  # numba: only when sampling

    return build_nav_grid(scene)


@dataclass(frozen=True)
class Constraints:
    """What else the sampler must respect. Points are (x, y) in metres."""

    avoid: tuple[tuple[float, float], ...] = ()
    group: tuple[tuple[float, float], ...] = ()
    taken_objects: frozenset[str] = frozenset()
    taken_by_group: frozenset[str] = frozenset()
    """Seats taken by members of the same event placed before this character."""
    min_separation: float = MIN_SEPARATION
    group_radius: float = GROUP_RADIUS


@dataclass(frozen=True)
class Placement:
    """A sampled position; ``seat`` / ``seat_facing`` are set when it is a seat slot."""

    position: tuple[float, float]
    seat: str | None = None
    seat_facing: tuple[float, float] | None = None


def _far_from(
    points: NDArray[np.float64], others: tuple[tuple[float, float], ...], distance: float
) -> NDArray[np.bool_]:
    if not others or len(points) == 0:
        return np.ones(len(points), dtype=bool)
    o = np.asarray(others, dtype=float)
    d: NDArray[np.float64] = np.linalg.norm(points[:, None, :] - o[None, :, :], axis=2)
    nearest: NDArray[np.float64] = d.min(axis=1)
    return nearest >= distance


def _near_all(
    points: NDArray[np.float64], others: tuple[tuple[float, float], ...], distance: float
) -> NDArray[np.bool_]:
    o = np.asarray(others, dtype=float)
    d: NDArray[np.float64] = np.linalg.norm(points[:, None, :] - o[None, :, :], axis=2)
    farthest: NDArray[np.float64] = d.max(axis=1)
    return farthest <= distance


def _free_seats(area: Area, c: Constraints) -> list[SeatSlot]:
    free = []
    for slot in area.seats:
        single = sum(1 for s in area.seats if s.seat == slot.seat) == 1
        if single and slot.seat in c.taken_objects:
            continue
        if bool(_far_from(np.array([slot.position]), c.avoid, c.min_separation)[0]):
            free.append(slot)
    return free


NEIGHBOUR_SEAT_M = 1.5
"""How far (m, between seat footprints) a seat of the same kind may be to stand in for one a
companion already took."""


def _companion_seats(area: Area, scene: Scene, c: Constraints) -> list[SeatSlot]:
    """When every seat ``area`` offers was taken by members of the same event ("Cy and Di sit on
    chair_5" for a one-place chair, or four on a three-place couch), the free seat nearest to
    it (within ``NEIGHBOUR_SEAT_M``), one of the same kind first, then one at the same table
    (:func:`storyteller.tools.place_relations.table_of`): the group sits together. Empty otherwise."""
    wanted = {s.seat for s in area.seats}
    if not wanted or not wanted <= c.taken_by_group:
        return []
    by_name = {o.name: o for o in scene.objects}
    chosen = [by_name[n] for n in sorted(wanted) if n in by_name]
    labels = {o.label for o in chosen}
    tables = {t.name for o in chosen if (t := table_of(scene, o)) is not None}
    best: list[tuple[bool, bool, float, str, SeatSlot]] = []
    for o in scene.objects:
        if not o.is_seat or o.name in wanted:
            continue
        gap = min(footprint_distance(o, w) for w in chosen)
        if gap > NEIGHBOUR_SEAT_M:
            continue
        slots = seat_slots(o)
        for slot in slots:
            if len(slots) == 1 and o.name in c.taken_objects:
                continue
            if bool(_far_from(np.array([slot.position]), c.avoid, c.min_separation)[0]):
                at = table_of(scene, o)
                best.append((o.label not in labels, bool(tables) and (at is None or at.name not in tables), gap, o.name, slot))
    best.sort(key=lambda t: (t[0], t[1], t[2], t[3]))
    return [best[0][4]] if best else []


SEAT_EDGE_MARGIN = 0.05
"""m: a seat point moved off other furniture stays this far inside the seat's own edges."""


def _clear_seat_point(slot: SeatSlot, floor: FloorMap) -> tuple[float, float]:
    """The slot's point, or, when it lies inside the footprint of other floor-standing furniture
    (a stool pushed into a plant's leaves), the point of the seat's own footprint nearest to it
    that is clear of all of them: nobody sits inside a plant. Kept when the whole seat is covered."""
    seat = floor.scene.by_name.get(slot.seat)
    p = np.array([slot.position], dtype=float)
    others = [o for o in floor.obstacles if o.name != slot.seat]
    if seat is None or all(float(point_footprint_distance(o, p)[0]) > 0.0 for o in others):
        return slot.position
    half_w, half_d = seat.width / 2.0 - SEAT_EDGE_MARGIN, seat.depth / 2.0 - SEAT_EDGE_MARGIN
    if half_w <= 0.0 or half_d <= 0.0:
        return slot.position
    u, v = np.meshgrid(np.linspace(-half_w, half_w, 25), np.linspace(-half_d, half_d, 25))
    grid = (seat.center_xy + u.reshape(-1, 1) * seat.right + v.reshape(-1, 1) * np.asarray(seat.facing))
    clear = np.ones(len(grid), dtype=bool)
    for o in others:
        clear &= point_footprint_distance(o, grid) > 0.0
    if not clear.any():
        return slot.position
    candidates = grid[clear]
    best = candidates[int(np.argmin(np.linalg.norm(candidates - p, axis=1)))]
    return (float(best[0]), float(best[1]))


def _lattice(area: Area, scene: Scene, rng: np.random.Generator) -> NDArray[np.float64]:
    x0 = max(area.hint[0], scene.bounds_min[0])
    y0 = max(area.hint[1], scene.bounds_min[1])
    x1 = min(area.hint[2], scene.bounds_max[0])
    y1 = min(area.hint[3], scene.bounds_max[1])
    if x1 < x0 or y1 < y0:
        return np.zeros((0, 2))
    step = LATTICE_STEP
    while ((x1 - x0) / step + 1) * ((y1 - y0) / step + 1) > MAX_CANDIDATES:
        step *= 1.5
    ox, oy = rng.uniform(0.0, step, size=2)
    xs = np.arange(x0 + ox, x1 + 1e-9, step)
    ys = np.arange(y0 + oy, y1 + 1e-9, step)
    if len(xs) == 0 or len(ys) == 0:  # thinner than one step: use the box centre line
        xs = xs if len(xs) else np.array([(x0 + x1) / 2.0])
        ys = ys if len(ys) else np.array([(y0 + y1) / 2.0])
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def _interior(area: Area, points: NDArray[np.float64]) -> NDArray[np.float64]:
    keep = np.ones(len(points), dtype=bool)
    for dx, dy in (
        (INTERIOR_MARGIN, 0.0),
        (-INTERIOR_MARGIN, 0.0),
        (0.0, INTERIOR_MARGIN),
        (0.0, -INTERIOR_MARGIN),
    ):
        keep &= area.contains(points + np.array([dx, dy]))
    return keep


def sample_position(
    area: Area, floor: FloorMap, constraints: Constraints, rng: np.random.Generator
) -> Placement:
    """One admissible position in ``area`` (see the module docstring for the rules)."""
    c = constraints
    if area.seats:
        seats = _free_seats(area, c) or _companion_seats(area, floor.scene, c)
        if seats:
            if c.group:
                points = np.array([s.position for s in seats])
                near = _near_all(points, c.group, c.group_radius)
                if near.any():
                    seats = [s for s, ok in zip(seats, near, strict=True) if ok]
            slot = seats[int(rng.integers(len(seats)))]
            return Placement(_clear_seat_point(slot, floor), slot.seat, slot.facing)
        if not area.free_region:
            names = sorted({s.seat for s in area.seats})
            raise UnsatisfiableAreaError(
                f"no free seat in '{area.description}': {', '.join(names)} taken by other characters"
            )
    if not area.free_region or not area.hint_nonempty:
        raise UnsatisfiableAreaError(
            f"the area '{area.description}' is empty (its parts do not overlap)"
        )

    try:
        free = _walkable(area, floor, rng)
    except UnsatisfiableAreaError as strict:
        if not area.relaxations:
            raise
        return _sample_relaxed(area, floor, c, rng, strict)
    return _draw(area, free, c, rng)


def _walkable(area: Area, floor: FloorMap, rng: np.random.Generator) -> NDArray[np.float64]:
    """The lattice points of ``area`` on free, reachable floor (others' positions aside)."""
    points = _lattice(area, floor.scene, rng)
    inside = points[area.contains(points)] if len(points) else points
    if len(inside) == 0:
        raise UnsatisfiableAreaError(f"the area '{area.description}' is empty or outside the scene")
    free = inside[floor.free(inside)]
    if len(free) == 0:
        raise UnsatisfiableAreaError(
            f"no free floor in '{area.description}': it is covered by furniture or too close to a wall"
        )
    free = free[floor.reachable(free)]
    if len(free) == 0:
        raise UnsatisfiableAreaError(
            f"no reachable floor in '{area.description}': its free floor is enclosed by furniture"
        )
    return free


def _draw(
    area: Area,
    free: NDArray[np.float64],
    c: Constraints,
    rng: np.random.Generator,
    excess: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
) -> Placement:
    """One of the ``free`` points of ``area`` away from others, by the preferences of the
    module docstring (with ``excess``: first the points nearest the strict area)."""
    clear = free[_far_from(free, c.avoid, c.min_separation)]
    if len(clear) == 0:
        raise UnsatisfiableAreaError(
            f"every free spot in '{area.description}' is within {c.min_separation} m of another character"
        )
    if excess is not None:
        e = excess(clear)
        clear = clear[e <= e.min() + RELAXED_BAND]
    if c.group:
        near = _near_all(clear, c.group, c.group_radius)
        if near.any():
            clear = clear[near]
    interior = _interior(area, clear)
    if interior.any():
        clear = clear[interior]
    chosen = clear[int(rng.integers(len(clear)))]
    return Placement((float(chosen[0]), float(chosen[1])))


def _sample_relaxed(
    area: Area,
    floor: FloorMap,
    c: Constraints,
    rng: np.random.Generator,
    strict: UnsatisfiableAreaError,
) -> Placement:
    """A point of the smallest relaxation of ``area`` with room (``strict``: why the area itself
    has none), else UnsatisfiableAreaError saying that the widest relaxation has none either."""
    crowded = False
    for relaxation in area.relaxations:
        try:
            free = _walkable(relaxation.area, floor, rng)
        except UnsatisfiableAreaError:
            continue
        try:
            return _draw(relaxation.area, free, c, rng, relaxation.excess)
        except UnsatisfiableAreaError:
            crowded = True
    widest = area.relaxations[-1]
    where = widest.describe()
    if crowded:
        raise UnsatisfiableAreaError(
            f"{strict.feedback}; relaxed up to {where}, every free spot is within "
            f"{c.min_separation} m of another character"
        )
    raise UnsatisfiableAreaError(
        f"{strict.feedback}; relaxed up to {where}, there is no free reachable floor either"
    )

"""Navigation grid: which floor cells a standing body may occupy, and which moves are safe.

A cell is *free* when a body disc of radius ``body_radius`` centred on the cell centre stays
inside the scene rectangle and touches no blocking object. A *move* (one of 8 neighbours) is
allowed when both cells are free, a diagonal does not cut a corner past a blocked cell, and the
whole straight segment between the two centres keeps the disc off every blocking footprint
(exact segment-to-rectangle distance, so thin objects between two free cells still block).

Which objects block: every object whose bottom is below ``clearance_height`` (default 1.9 m)
above the floor. That covers floor-supported furniture (bottom within 0.10 m of the floor) and
wall-mounted things a walking body would hit (a TV whose bottom is at 0.77 m); things on a
table lie inside the table's footprint anyway; lamps and shelves mounted above 1.9 m do not
block.

Reference scenes (``grid_map.json``) carry cell overrides on the authors' grid. Inferred from
the data (documented in ``reference_grid_origin``): reference cell ``(a, b)`` has its *centre*
at ``(x_margin + a * step, y_margin + b * step)``; the grid spans ``[margin, bbox_max - margin]``.
With that origin, 105 of the Office's 125 ``unoccupied`` cells sit just in front of chairs and
couches (inside the footprint grown by the reference radius, outside the raw one) and only 2
inside a raw footprint; the ``occupied`` cells draw the Office's interior walls (3 cells thick)
and its doors. ``occupied`` cells are applied as blocked. ``unoccupied`` cells only undo an
``occupied`` entry: they never free a cell our own clearance test blocks (our default radius,
0.25 m, is smaller than the reference's 0.314 m, and seats are reached through
``approach_cell`` instead).

Cells are indexed ``(i, j)`` with ``i`` along +x and ``j`` along +y; ``origin`` is the corner of
cell (0, 0), so cell ``(i, j)`` has its centre at ``origin + (i + 0.5, j + 0.5) * cell_size``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from storyteller.sim.paths.footprint_distance import (
    Obstacles,
    inside_bounds,
    point_rect_distance,
    segment_point_distance,
)
from storyteller.sim.paths.footprint_distance import (
    body_clearance as body_clearance,  # also this module's: callers import it here
)
from storyteller.sim.paths.grid_moves import MOVES as MOVES  # also this module's: callers import it here
from storyteller.sim.paths.grid_moves import allowed_moves, components
from storyteller.sim.scene.model import MAX_NAV_CELLS, Scene, SceneObject, nav_cell_bound

DEFAULT_BODY_RADIUS = 0.25
DEFAULT_CLEARANCE_HEIGHT = 1.9
MAX_SIT_SLIDE_M = 1.0
"""Metres from an approach point to the seat point beyond which the point ranks after every
nearer one (``NavGrid.approach_point``): the sit-down moves the body that far in a straight
line, and further than this it passes through what stands around the seat."""


class NavGridError(ValueError):
    """Bad navigation-grid parameters (one sentence naming the parameter)."""


@dataclass(frozen=True)
class ApproachPoint:
    """Where a character stands to sit on / use an object (see ``NavGrid.approach_point``).

    ``xy``: the exact standing point (metres; generally not a cell centre). ``cell``: the free
    cell a walker goes to first; the straight segment from its centre to ``xy`` is clear of
    furniture for a body of the grid's radius. ``gap``: metres from ``xy`` to the seat point
    (seats) or to the object's footprint (other objects), covered by the sit-down / use
    transition. ``offset``: metres from ``xy`` to the ideal standing point (0 without a facing).
    """

    obj: str
    xy: tuple[float, float]
    cell: tuple[int, int]
    gap: float
    offset: float


@dataclass(frozen=True, eq=False)
class NavGrid:
    """Free cells and allowed moves of one scene for one body radius.

    ``free[i, j]``: a body centred on cell (i, j) touches nothing. ``moves[i, j, k]``: the move
    ``MOVES[k]`` from (i, j) keeps the body clear along the whole segment. ``component[i, j]``:
    connected-component id of free cells under allowed moves (-1 for blocked cells).
    Arrays are read-only.
    """

    free: np.ndarray
    moves: np.ndarray
    component: np.ndarray
    origin: tuple[float, float]
    cell_size: float
    body_radius: float
    obstacles: Obstacles
    bounds_min: tuple[float, float]
    bounds_max: tuple[float, float]
    clearance_height: float = DEFAULT_CLEARANCE_HEIGHT
    _reference_offset: tuple[int, int] | None = field(default=None, repr=False)

    @cached_property
    def near_mask_memo(self) -> dict[int, list[tuple[int, int]]]:
        """A memo the path planners of this grid share (``storyteller.sim.paths.cooperative_astar``: the
        cells a clearance mask covers); it depends only on the grid's cells and radius."""
        return {}

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.free.shape[0]), int(self.free.shape[1]))

    def in_grid(self, i: int, j: int) -> bool:
        nx, ny = self.shape
        return 0 <= i < nx and 0 <= j < ny

    def cell_of(self, xy: np.ndarray | tuple[float, float]) -> tuple[int, int]:
        """The cell containing point ``xy`` (may lie outside the grid; check ``in_grid``)."""
        p = np.asarray(xy, dtype=float)
        return (
            int(math.floor((p[0] - self.origin[0]) / self.cell_size)),
            int(math.floor((p[1] - self.origin[1]) / self.cell_size)),
        )

    def center_of(self, i: int, j: int) -> np.ndarray:
        """Centre (x, y) of cell (i, j), metres."""
        return np.array(
            [self.origin[0] + (i + 0.5) * self.cell_size, self.origin[1] + (j + 0.5) * self.cell_size]
        )

    def centers(self, cells: np.ndarray) -> np.ndarray:
        """Centres (N, 2) of integer cells (N, 2)."""
        c = np.asarray(cells, dtype=float)
        return np.asarray(self.origin) + (c + 0.5) * self.cell_size

    def is_free(self, i: int, j: int) -> bool:
        return self.in_grid(i, j) and bool(self.free[i, j])

    def is_free_xy(self, xy: np.ndarray | tuple[float, float]) -> bool:
        """Whether a body centred exactly at ``xy`` touches no blocking object and stays in bounds."""
        p = np.asarray(xy, dtype=float)
        if not inside_bounds(p[None], self.bounds_min, self.bounds_max, self.body_radius)[0]:
            return False
        return bool(body_clearance(self.obstacles, p[None], p[None], cutoff=self.body_radius)[0] >= self.body_radius - 1e-9)

    def nearest_free_cell(
        self, xy: np.ndarray | tuple[float, float], component: int | None = None
    ) -> tuple[int, int]:
        """The free cell whose centre is closest to ``xy`` (ties: lowest i, then j).

        ``component`` restricts the search to one connected component. Raises ``NavGridError``
        when there is no free cell at all.
        """
        mask = self.free if component is None else self.component == component
        cells = np.argwhere(mask)
        if len(cells) == 0:
            raise NavGridError("the navigation grid has no free cell" + ("" if component is None else " in that component"))
        d2 = np.sum((self.centers(cells) - np.asarray(xy, dtype=float)) ** 2, axis=1)
        k = int(np.argmin(d2))  # argmin takes the first minimum: cells are in (i, j) order
        return (int(cells[k][0]), int(cells[k][1]))

    @property
    def main_component(self) -> int:
        """Id of the largest connected component of free cells (-1 if none)."""
        ids = self.component[self.component >= 0]
        if ids.size == 0:
            return -1
        return int(np.argmax(np.bincount(ids)))

    def approach_cell(self, obj: SceneObject, standoff: float = 0.05) -> tuple[int, int]:
        """The free cell from which a character sits on / uses ``obj``.

        The ideal point is in front of the object (seats and objects with a facing): the front
        edge of the footprint plus ``body_radius + standoff``; for objects without a facing,
        the closest free cell to the footprint. Candidates are restricted to the largest
        connected component, preferring cells with a clear straight line to the seat point
        (or centre) and, for objects with a facing, cells in front of it.
        """
        cells = np.argwhere(self.component == self.main_component)
        if len(cells) == 0:
            raise NavGridError("the navigation grid has no free cell")
        centers = self.centers(cells)
        local = obj.to_local(centers)
        # Prefer cells with a clear line to the object (no other object in between).
        others = [o for o in self.obstacles if o.name != obj.name]
        target = obj.seat_point() if obj.is_seat else obj.center_xy
        visible = body_clearance(others, centers, np.broadcast_to(target, centers.shape)) > 0.0
        keep = visible
        if obj.has_facing or obj.is_seat:
            f = np.asarray(obj.facing, dtype=float)
            ideal = obj.center_xy + f * (obj.depth / 2.0 + self.body_radius + standoff)
            in_front = local[:, 1] > obj.depth / 2.0
            for mask in (visible & in_front, visible, in_front):
                if mask.any():
                    keep = mask
                    break
            d2 = np.sum((centers - ideal) ** 2, axis=1)
        else:
            d2 = point_rect_distance(local, obj.width / 2.0, obj.depth / 2.0) ** 2
        if keep.any():
            cells, d2 = cells[keep], d2[keep]
        k = int(np.argmin(d2))
        return (int(cells[k][0]), int(cells[k][1]))

    def approach_point(
        self,
        obj: SceneObject,
        standoff: float = 0.05,
        resolution: float = 0.05,
        search_radius: float = 1.5,
        component: int | None = None,
        seat_xy: tuple[float, float] | None = None,
        avoid: Sequence[tuple[float, float]] = (),
    ) -> ApproachPoint:
        """The best exact standing point (not a cell centre) from which to sit on / use ``obj``.

        Ideal point: in front of the object (seats and objects with a facing) at
        ``depth / 2 + body_radius + standoff`` from its centre; for objects without a facing, any
        point ``body_radius + standoff`` off the footprint. Candidates are points on a
        ``resolution`` lattice within ``search_radius`` of the footprint where a body fits (clear of
        every blocking object, inside the bounds) and that a walker reaches: some free cell (of
        ``component`` when given, else of any component: check ``component[cell]`` against the
        walker's own to know whether it can get there) has a clear straight segment to the point (``ApproachPoint.cell``; walk
        there on the grid, then ``CrowdNavigator.set_goal(agent, cell, final_xy=xy)``). Preferred:
        points with a clear line to the seat point (or centre) past every other object, then those
        in front, then the closest to the ideal point; ties broken by lattice order (deterministic);
        for a seat, every point within ``MAX_SIT_SLIDE_M`` of the seat point ranks before the
        points further away (an armchair whose front only a narrow gap leads to is sat on from
        its side, not slid onto from 2 m away past a couch).

        ``ApproachPoint.gap`` is the distance (metres) left between the standing point and the seat
        point (seats) or the footprint edge (other objects). The sit-down / use transition covers
        it: the character turns and its root moves the remaining ``gap`` onto the seat (the body
        passes over the seat's own footprint, which is not an obstacle to sitting). When chairs are
        tucked 0.37-0.46 m from their tables no body (0.5 m across) fits in front of them; the point
        is then beside the chair and ``gap`` is larger (e.g. 0.5-0.8 m): callers decide whether that
        is acceptable. Raises ``NavGridError`` when no candidate is reachable.

        ``seat_xy``: one sitting place of a wide seat (a couch's slot) instead of its seat point:
        the ideal point moves sideways with it and the gap is measured to it. ``avoid``: points
        (other bodies) that neither the candidate nor the straight walk onto it from its cell's
        centre may come within two body radii of.
        """
        if not (math.isfinite(resolution) and resolution > 0.0 and math.isfinite(search_radius) and search_radius > 0):
            raise NavGridError("approach_point needs a positive resolution and search_radius in metres")
        r = self.body_radius
        if self.main_component < 0:
            raise NavGridError("the navigation grid has no free cell")
        taken = np.asarray(avoid, dtype=float).reshape(-1, 2)
        pts, local, edge = self._room_points(obj, resolution, search_radius, taken)
        target = np.asarray(seat_xy, dtype=float) if seat_xy is not None else (
            obj.seat_point() if obj.is_seat else obj.center_xy)
        score, tier = self._approach_ranks(obj, pts, local, edge, target, standoff, seat_xy is not None)
        for k in np.lexsort((score, tier)):
            p = pts[k]
            cell = self._entry_cell(p, component)
            if cell is None:
                continue
            if len(taken) and segment_point_distance(self.center_of(*cell), p, taken) < 2.0 * r:
                continue
            gap = float(np.linalg.norm(p - target)) if obj.is_seat else float(edge[k])
            return ApproachPoint(
                obj=obj.name,
                xy=(float(p[0]), float(p[1])),
                cell=cell,
                gap=gap,
                offset=float(score[k]) if obj.has_facing or obj.is_seat else 0.0,
            )
        raise NavGridError(f"no reachable point near {obj.name} has room for a body of radius {r} m")

    def _room_points(
        self, obj: SceneObject, resolution: float, search_radius: float, taken: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``approach_point``'s candidates: the points (N, 2) of the ``resolution`` lattice around
        ``obj`` within ``search_radius`` of its footprint where a body fits (inside the bounds, clear
        of every blocking object, two body radii from every ``taken`` point), their coordinates in
        the object's frame (N, 2) and their distances to the footprint (N,)."""
        r = self.body_radius
        hw, hd = obj.width / 2.0, obj.depth / 2.0
        reach = math.hypot(hw, hd) + search_radius
        c = obj.center_xy
        n = int(math.ceil(reach / resolution))
        ax = np.arange(-n, n + 1) * resolution
        gx, gy = np.meshgrid(ax, ax, indexing="ij")
        pts = c + np.stack([gx.ravel(), gy.ravel()], axis=1)
        local = obj.to_local(pts)
        edge = point_rect_distance(local, hw, hd)
        keep = (edge <= search_radius) & inside_bounds(pts, self.bounds_min, self.bounds_max, r)
        pts, local, edge = pts[keep], local[keep], edge[keep]
        keep = body_clearance(self.obstacles, pts, pts) >= r
        if len(taken):
            keep &= np.min(np.linalg.norm(pts[:, None, :] - taken[None, :, :], axis=2), axis=1) >= 2.0 * r
        pts, local, edge = pts[keep], local[keep], edge[keep]
        if len(pts) == 0:
            raise NavGridError(f"no point near {obj.name} has room for a body of radius {r} m")
        return pts, local, edge

    def _approach_ranks(self, obj: SceneObject, pts: np.ndarray, local: np.ndarray, edge: np.ndarray,
                        target: np.ndarray, standoff: float, at_place: bool) -> tuple[np.ndarray, np.ndarray]:
        """(score, tier) of ``approach_point``'s candidates, best first by tier then score: the
        tier counts against a point no clear line to ``target`` past the other objects (1), not
        being in front (2) and, for a seat, a slide onto it over ``MAX_SIT_SLIDE_M`` (4); the score
        is the distance to the ideal point (``at_place``: in front of ``target``, a place of a
        wide seat) or, for an object without a facing, how far the point's gap to the footprint is
        from ``body_radius + standoff``."""
        r = self.body_radius
        c = obj.center_xy
        hd = obj.depth / 2.0
        others = [o for o in self.obstacles if o.name != obj.name]
        visible = body_clearance(others, pts, np.broadcast_to(target, pts.shape)) > 0.0
        if obj.has_facing or obj.is_seat:
            ideal = c + np.asarray(obj.facing, dtype=float) * (hd + r + standoff)
            if at_place:  # in front of that place
                ideal = ideal + obj.right * float((target - c) @ obj.right)
            score = np.linalg.norm(pts - ideal, axis=1)
            in_front = local[:, 1] > hd
        else:
            score = np.abs(edge - (r + standoff))
            in_front = np.ones(len(pts), dtype=bool)
        tier = np.where(visible & in_front, 0, np.where(visible, 1, np.where(in_front, 2, 3)))
        if obj.is_seat:  # a sit-down slides the body from the point onto the seat: a long slide goes
            # through the furniture around it, so a near point comes before a far one in front
            far = np.linalg.norm(pts - target, axis=1) > MAX_SIT_SLIDE_M
            tier = tier + np.where(far, 4, 0)
        return score, tier

    def entry_cell(self, xy: np.ndarray | tuple[float, float], component: int | None = None) -> tuple[int, int] | None:
        """The free cell (of ``component``, default any) with the shortest clear straight
        segment from its centre to ``xy`` (a body of ``body_radius`` stays off every blocking object
        along it); None when ``xy`` itself is not clear or no cell within 2 cells has a clear line."""
        p = np.asarray(xy, dtype=float)
        if p.shape != (2,) or not np.all(np.isfinite(p)) or not self.is_free_xy(p):
            return None
        return self._entry_cell(p, component)

    def _entry_cell(self, p: np.ndarray, component: int | None) -> tuple[int, int] | None:
        ci, cj = self.cell_of(p)
        nx, ny = self.shape
        i0, i1, j0, j1 = max(ci - 2, 0), min(ci + 3, nx), max(cj - 2, 0), min(cj + 3, ny)
        if i0 >= i1 or j0 >= j1:
            return None
        window = self.component[i0:i1, j0:j1]  # the cells within 2 of p's, in (i, j) order
        ok = window >= 0 if component is None else (window >= 0) & (window == component)
        ii, jj = np.nonzero(ok)
        if len(ii) == 0:
            return None
        cells = np.stack([ii + i0, jj + j0], axis=1)
        centers = self.centers(cells)
        d = np.linalg.norm(centers - p, axis=1)
        clear = body_clearance(self.obstacles, centers, np.broadcast_to(p, centers.shape), cutoff=self.body_radius) >= self.body_radius
        if not clear.any():
            return None
        k = int(np.flatnonzero(clear)[np.argmin(d[clear])])
        return (int(cells[k][0]), int(cells[k][1]))

    def reference_cell(self, a: int, b: int) -> tuple[int, int] | None:
        """Our cell for reference-grid cell (a, b), when the grids are aligned (else None)."""
        if self._reference_offset is None:
            return None
        return (a - self._reference_offset[0], b - self._reference_offset[1])

    def move_allowed(self, cell: tuple[int, int], k: int) -> bool:
        i, j = cell
        return self.in_grid(i, j) and bool(self.moves[i, j, k])


def blocking_objects(scene: Scene, clearance_height: float = DEFAULT_CLEARANCE_HEIGHT) -> Obstacles:
    """Objects a walking body can collide with: bottom below ``clearance_height`` above the floor."""
    return Obstacles(o for o in scene.objects if o.z_min - scene.floor_z < clearance_height)


# ----- reference grid -------------------------------------------------------------------------
def reference_grid_origin(folder: Path | str) -> tuple[float, float] | None:
    """Centre of reference cell (0, 0) from a reference folder's ``grid_map.json`` (None if absent).

    Inferred from the published data: fitting the origin so that the Office's 125
    ``unoccupied`` cells fall just outside raw footprints but inside footprints grown by the
    reference radius gives the best fit (105 good, 2 bad) at centre = (x_margin, y_margin);
    the largest indices (Office i <= 35, j <= 56) match a grid spanning
    ``[margin, bbox_max - margin]``.
    """
    path = Path(folder) / "grid_map.json"
    if not path.exists():
        return None
    data = json.loads(path.read_text(encoding="utf-8"))
    return (float(data.get("x_margin", 0.0)), float(data.get("y_margin", 0.0)))


def with_reference_grid_origin(scene: Scene, folder: Path | str) -> Scene:
    """``scene`` with ``nav.grid_origin`` set from the reference folder's ``grid_map.json``."""
    origin = reference_grid_origin(folder)
    if origin is None:
        return scene
    return scene.model_copy(update={"nav": scene.nav.model_copy(update={"grid_origin": origin})})


# ----- building -----------------------------------------------------------------------------------
def build_nav_grid(
    scene: Scene,
    cell_size: float | None = None,
    body_radius: float = DEFAULT_BODY_RADIUS,
    clearance_height: float = DEFAULT_CLEARANCE_HEIGHT,
    use_reference_overrides: bool = True,
) -> NavGrid:
    """Build the navigation grid of ``scene``.

    ``cell_size`` (metres, default ``scene.nav.cell_size``), ``body_radius`` (metres).
    Reference overrides (``scene.nav.occupied`` / ``unoccupied``) are applied when the cell
    size equals ``scene.nav.cell_size``; then our lattice is aligned with the reference one
    whose cell (0, 0) is centred at ``scene.nav.grid_origin``.
    """
    cs = float(scene.nav.cell_size if cell_size is None else cell_size)
    if not (math.isfinite(cs) and cs > 0.0):
        raise NavGridError(f"cell_size must be a positive number of metres, got {cell_size!r}")
    if not (math.isfinite(body_radius) and body_radius > 0.0):
        raise NavGridError(f"body_radius must be a positive number of metres, got {body_radius!r}")
    lo, hi = scene.bounds_min, scene.bounds_max
    if nav_cell_bound(lo, hi, cs) > MAX_NAV_CELLS:  # counted before any array (or int overflow)
        raise NavGridError(
            f"cell_size {cs:g} m gives more than {MAX_NAV_CELLS:,} cells over the floor; use a larger cell_size"
        )
    has_overrides = bool(scene.nav.occupied or scene.nav.unoccupied)
    aligned = use_reference_overrides and has_overrides and abs(cs - scene.nav.cell_size) < 1e-9
    if aligned:
        ref0 = np.asarray(scene.nav.grid_origin, dtype=float)  # centre of reference cell (0, 0)
        k_lo = np.floor((np.asarray(lo) - ref0) / cs).astype(int)
        origin = ref0 + (k_lo - 0.5) * cs
    else:
        k_lo = np.zeros(2, dtype=int)
        origin = np.asarray(lo, dtype=float)
    nx = max(1, math.ceil((hi[0] - origin[0]) / cs))
    ny = max(1, math.ceil((hi[1] - origin[1]) / cs))
    if nx * ny > MAX_NAV_CELLS:
        raise NavGridError(f"cell_size {cs} m gives {nx} x {ny} cells; use a larger cell_size")

    obstacles = blocking_objects(scene, clearance_height)
    ii, jj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    cells = np.stack([ii.ravel(), jj.ravel()], axis=1)
    centers = origin + (cells + 0.5) * cs
    free = inside_bounds(centers, lo, hi, body_radius) & (body_clearance(obstacles, centers, centers, cutoff=body_radius) >= body_radius)
    free = free.reshape(nx, ny)

    if aligned:
        override = np.zeros((nx, ny), dtype=bool)
        unoccupied = {tuple(c) for c in scene.nav.unoccupied}
        for a, b in scene.nav.occupied:
            if (a, b) in unoccupied:
                continue
            i, j = a - int(k_lo[0]), b - int(k_lo[1])
            if 0 <= i < nx and 0 <= j < ny:
                override[i, j] = True
        free &= ~override

    moves = allowed_moves(free, origin, cs, body_radius, obstacles)
    component = components(free, moves)
    for arr in (free, moves, component):
        arr.flags.writeable = False
    return NavGrid(
        free=free,
        moves=moves,
        component=component,
        origin=(float(origin[0]), float(origin[1])),
        cell_size=cs,
        body_radius=float(body_radius),
        obstacles=obstacles,
        bounds_min=(float(lo[0]), float(lo[1])),
        bounds_max=(float(hi[0]), float(hi[1])),
        clearance_height=float(clearance_height),
        _reference_offset=(int(k_lo[0]), int(k_lo[1])) if aligned else None,
    )

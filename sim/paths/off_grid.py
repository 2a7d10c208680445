"""Exact off-grid points of walkers (``storyteller.sim.paths.following.CrowdNavigator``).

A goal may carry ``final_xy`` (``set_goal(agent, cell, final_xy=...)``): after reaching ``cell``
the walker takes a straight *leg* (:class:`Leg`) from the cell centre to that exact point, and
a walker parked off the grid (arrived at such a point, or added with ``start_xy``) first takes a
leg back to its cell before walking on. A leg starts only at a step boundary and only when every
other body (walker cells, parked points, other legs, stationary discs) is at least
``2 * body_radius`` from the whole segment; during the leg (and while parked) the body is a
static segment / disc for the planner, which then keeps every move from getting closer than
``min(2r, distance at the move's start)``. The segment itself is checked against furniture when
the goal is set (:func:`target_problem`: why a body cannot stand at, or walk straight to, the
point).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.paths.footprint_distance import body_clearance
from storyteller.sim.paths.nav_grid import NavGrid
from storyteller.sim.paths.plan_types import Cell


@dataclass(frozen=True)
class Leg:
    """A straight off-grid walk from ``a`` to ``b`` (metres) starting at ``frame``."""

    a: NDArray[np.float64]
    b: NDArray[np.float64]
    frame: int
    frames: int  # frames to cover the segment at walking speed (>= 1)
    inbound: bool  # True: cell centre -> exact target; False: parked point -> cell centre

    def at(self, frame: int) -> NDArray[np.float64]:
        s = min(1.0, max(0.0, (frame - self.frame) / self.frames))
        return (1.0 - s) * self.a + s * self.b


def target_problem(grid: NavGrid, goal: Cell, xy: NDArray[np.float64] | tuple[float, float]) -> str | None:
    """Why a body cannot end at ``xy`` coming straight from ``goal``'s centre (None: it can).

    Checks that ``xy`` is finite, that a body there touches no blocking object and stays in
    bounds, that ``goal`` is free, and that the straight segment between them keeps the body
    off every blocking footprint. Other characters are handled at run time (the leg waits).
    """
    p = np.asarray(xy, dtype=np.float64)
    if p.shape != (2,) or not np.all(np.isfinite(p)):
        return f"target {xy!r} is not a finite (x, y) point"
    g = grid
    if not g.is_free(int(goal[0]), int(goal[1])):
        return f"goal cell {tuple(goal)} is blocked or outside the grid"
    if not g.is_free_xy(p):
        near = _nearest_obstacle(g, p)
        return (f"a body of radius {g.body_radius} m at ({p[0]:.2f}, {p[1]:.2f}) would leave the floor"
                if near is None else
                f"a body of radius {g.body_radius} m at ({p[0]:.2f}, {p[1]:.2f}) would overlap {near}")
    c = g.center_of(int(goal[0]), int(goal[1]))
    if float(body_clearance(g.obstacles, c[None], p[None], cutoff=g.body_radius)[0]) < g.body_radius - 1e-9:
        near = _nearest_obstacle(g, p, c)
        return f"the straight walk from cell {tuple(goal)} to ({p[0]:.2f}, {p[1]:.2f}) would touch {near}"
    return None


def _nearest_obstacle(grid: NavGrid, p: NDArray[np.float64], a: NDArray[np.float64] | None = None) -> str | None:
    """Name of the blocking object closest to the point p (or the segment a-p)."""
    if not grid.obstacles:
        return None
    a = p if a is None else a
    d = [float(body_clearance([o], a[None], p[None])[0]) for o in grid.obstacles]
    k = int(np.argmin(d))
    return grid.obstacles[k].name if d[k] < grid.body_radius else None

"""The clearance rule in continuous space (``storyteller.sim.paths.cooperative_astar`` states it): the
closest approach of two linear motions over one step, the exact distance between segments,
positions on a planned path, and the check that finds every pair of plans breaking the rule.

Pure functions of their inputs; the planner's move tables (``storyteller.sim.paths.move_tables``) and its
stationary-body moves (``storyteller.sim.paths.static_bodies``) are tabulated from them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.paths.nav_grid import NavGrid
from storyteller.sim.paths.plan_types import Agent, Cell, PlanningError


def segment_min_norm(px: float, py: float, wx: float, wy: float) -> float:
    """min over s in [0, 1] of |p + s w|."""
    ww = wx * wx + wy * wy
    s = 0.0 if ww == 0 else min(1.0, max(0.0, -(px * wx + py * wy) / ww))
    return math.hypot(px + s * wx, py + s * wy)


def segment_distance(a: NDArray[np.float64], b: NDArray[np.float64], p: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Exact distance (N,) between 2-D segments a->b and p->q (arrays (N, 2); points allowed)."""
    a, b, p, q = (np.asarray(x, dtype=np.float64).reshape(-1, 2) for x in (a, b, p, q))

    def point_seg(x: NDArray[np.float64], s0: NDArray[np.float64], s1: NDArray[np.float64]) -> NDArray[np.float64]:
        d = s1 - s0
        dd = np.sum(d * d, axis=1)
        t = np.where(dd > 0, np.clip(np.sum((x - s0) * d, axis=1) / np.where(dd > 0, dd, 1.0), 0.0, 1.0), 0.0)
        dist: NDArray[np.float64] = np.linalg.norm(x - s0 - t[:, None] * d, axis=1)
        return dist

    out = np.minimum(np.minimum(point_seg(a, p, q), point_seg(b, p, q)), np.minimum(point_seg(p, a, b), point_seg(q, a, b)))

    def cross(u: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
        return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]

    d1, d2 = cross(b - a, p - a), cross(b - a, q - a)
    d3, d4 = cross(q - p, a - p), cross(q - p, b - p)
    proper = (d1 * d2 < 0) & (d3 * d4 < 0)
    return np.where(proper, 0.0, out)


def position_at(path: Sequence[Cell], t: float, grid: NavGrid, step_time: float, t_start: float = 0.0) -> NDArray[np.float64]:
    """Continuous xy (metres) on a planned path at time ``t`` seconds.

    ``path[k]`` is the cell at time ``t_start + k * step_time``; positions are linear between
    cell centres and clamped to the first / last cell outside the path's time span.
    """
    if not path:
        raise PlanningError("position_at needs a non-empty path")
    u = (t - t_start) / step_time
    if u <= 0:
        return grid.center_of(*path[0])
    k = int(math.floor(u))
    if k >= len(path) - 1:
        return grid.center_of(*path[-1])
    s = u - k
    return (1.0 - s) * grid.center_of(*path[k]) + s * grid.center_of(*path[k + 1])


def plan_conflicts(
    paths: Mapping[Agent, Sequence[Cell]], cell_size: float, body_radius: float, steps: int | None = None
) -> list[tuple[int, Agent, Agent, float]]:
    """Pairs that break the clearance rule: (step, a, b, closest distance in metres).

    Checks every step of every pair with the exact closest approach of linear motion; a pair
    breaks the rule when it gets closer than ``min(2r, its distance at the step start)``.
    """
    names = list(paths)
    n = min(len(p) for p in paths.values()) - 1 if steps is None else steps
    pos = np.array([[paths[a][k] for k in range(n + 1)] for a in names], dtype=np.float64) * cell_size
    out: list[tuple[int, Agent, Agent, float]] = []
    dmin = 2.0 * body_radius
    for k in range(n):
        p0 = pos[:, k]
        v = pos[:, k + 1] - p0
        rel = p0[None, :, :] - p0[:, None, :]
        w = v[None, :, :] - v[:, None, :]
        ww = np.sum(w * w, axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(ww > 0, np.clip(-np.sum(rel * w, axis=-1) / ww, 0.0, 1.0), 0.0)
        closest = np.linalg.norm(rel + s[..., None] * w, axis=-1)
        start = np.linalg.norm(rel, axis=-1)
        bad = closest < np.minimum(dmin, start) - 1e-7
        for i, j in zip(*np.nonzero(np.triu(bad, 1)), strict=True):
            out.append((k, names[i], names[j], float(closest[i, j])))
    return out

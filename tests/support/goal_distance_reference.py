"""The planner's heuristic as it was first computed: ``scipy.sparse.csgraph.dijkstra`` on a
sparse graph of the grid's moves. The oracle of the compiled ``storyteller.sim.paths.heuristics.goal_distances``
(``tests/sim/paths/test_astar_kernel.py`` checks the very same floats). Not used by the simulation.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from storyteller.sim.paths.cooperative_astar import Cell, PathPlanner
from storyteller.sim.paths.nav_grid import MOVES


def scipy_goal_distances(planner: PathPlanner, goal: Cell) -> np.ndarray:
    """Static distances (cells) to ``goal`` per padded cell id (inf: unreachable)."""
    g = planner.grid
    nx, ny = g.shape
    rows, cols, w = [], [], []
    for k, (dx, dy) in enumerate(MOVES):
        src = np.argwhere(g.moves[:, :, k])
        rows.append(src[:, 0] * ny + src[:, 1])
        cols.append((src[:, 0] + dx) * ny + src[:, 1] + dy)
        w.append(np.full(len(src), math.hypot(dx, dy)))
    graph = coo_matrix((np.concatenate(w), (np.concatenate(rows), np.concatenate(cols))), shape=(nx * ny, nx * ny)).tocsr()
    d = dijkstra(graph, directed=True, indices=[goal[0] * ny + goal[1]])[0]
    tables = planner.tables
    full = np.full((tables.nx_p, tables.ny_p), np.inf)
    full[tables.pad: tables.pad + nx, tables.pad: tables.pad + ny] = d.reshape(nx, ny)
    return full.ravel()

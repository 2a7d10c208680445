"""The 8-neighbour move graph of a navigation grid (``storyteller.sim.paths.nav_grid``): the moves in their
fixed order, which moves a body of radius ``r`` may take between free cells (no corner cutting,
the whole segment clear of every blocking footprint) and the strongly connected components of
the free cells under those moves.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from storyteller.sim.paths.footprint_distance import body_clearance
from storyteller.sim.scene.model import SceneObject

# The 8 moves, in a fixed order (index k is used in move masks): 4 straight, then 4 diagonal.
MOVES: tuple[tuple[int, int], ...] = ((1, 0), (0, 1), (-1, 0), (0, -1), (1, 1), (-1, 1), (-1, -1), (1, -1))
MOVE_LENGTHS: tuple[float, ...] = tuple(math.hypot(dx, dy) for dx, dy in MOVES)


def allowed_moves(
    free: np.ndarray, origin: np.ndarray, cs: float, r: float, obstacles: tuple[SceneObject, ...]
) -> np.ndarray:
    """Allowed moves (nx, ny, 8) of the free cells (nx, ny) of a grid whose cell (0, 0) has its
    corner at ``origin`` (cells of ``cs`` metres), for a body of radius ``r``."""
    nx, ny = free.shape
    padded = np.zeros((nx + 2, ny + 2), dtype=bool)
    padded[1:-1, 1:-1] = free
    moves = np.zeros((nx, ny, len(MOVES)), dtype=bool)
    for k, (dx, dy) in enumerate(MOVES):
        ok = free & padded[1 + dx : nx + 1 + dx, 1 + dy : ny + 1 + dy]
        if dx and dy:  # no corner cutting: both orthogonal neighbours must be free
            ok &= padded[1 + dx : nx + 1 + dx, 1 : ny + 1] & padded[1 : nx + 1, 1 + dy : ny + 1 + dy]
        src = np.argwhere(ok)
        if len(src) and obstacles:
            a = origin + (src + 0.5) * cs
            b = a + np.array([dx, dy], dtype=float) * cs
            clear = body_clearance(obstacles, a, b, cutoff=r) >= r
            ok[src[~clear, 0], src[~clear, 1]] = False
        moves[:, :, k] = ok
    return moves


def components(free: np.ndarray, moves: np.ndarray) -> np.ndarray:
    """Component id (nx, ny) of every free cell under ``moves``, -1 for a blocked cell."""
    nx, ny = free.shape
    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    for k, (dx, dy) in enumerate(MOVES):
        src = np.argwhere(moves[:, :, k])
        rows.append(src[:, 0] * ny + src[:, 1])
        cols.append((src[:, 0] + dx) * ny + src[:, 1] + dy)
    r = np.concatenate(rows) if rows else np.zeros(0, dtype=int)
    c = np.concatenate(cols) if cols else np.zeros(0, dtype=int)
    graph = coo_matrix((np.ones(len(r)), (r, c)), shape=(nx * ny, nx * ny)).tocsr()
    _, labels = connected_components(graph, directed=True, connection="strong")
    comp = labels.reshape(nx, ny).astype(np.int64)
    comp[~free] = -1
    # Renumber so ids are dense and ordered by first cell (deterministic).
    out = np.full_like(comp, -1)
    mapping: dict[int, int] = {}
    for idx in np.flatnonzero(free.ravel()):
        lab = int(comp.ravel()[idx])
        if lab not in mapping:
            mapping[lab] = len(mapping)
    flat = out.ravel()
    for idx in np.flatnonzero(free.ravel()):
        flat[idx] = mapping[int(comp.ravel()[idx])]
    return flat.reshape(nx, ny)

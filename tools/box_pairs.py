"""Which axis-aligned 2-D boxes overlap: a uniform-grid index, so the scene graph and the region
clusters test only the pairs of objects that can be within a relation's reach.

Guarantee: :func:`overlapping_pairs` returns exactly the pairs ``(i, j)`` whose closed boxes
``a[i]`` and ``b[j]`` overlap on both axes (touching counts), each pair once, sorted by ``i`` then
``j``; the same pairs as the brute-force test of every pair (``tests/tools/test_scene_graph_index.py``).
Callers grow their boxes by the reach they need (a relation's maximum distance, DBSCAN's ``eps``)
and then decide each returned pair with their exact test, so the index only skips pairs that
the exact test would refuse.

Cost: boxes no larger than half the grid's cell (most of a scene) are filed under one cell and meet
only the boxes of the 3 x 3 cells around it, so for furniture of bounded density the work grows
with the objects and the pairs returned; each larger box (a wall, a floor-wide rug) is tested
against every box of the other set with one vectorised comparison.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

_SMALL_QUANTILE = 75.0
"""Percentile of the boxes' extents up to which a box is "small": about a quarter of the boxes at
most are "large" (tested against everything). The grid's cell is twice that extent, so a small
box spans at most 2 x 2 cells with half a cell to spare (no rounding can push it further)."""


def overlapping_pairs(
    a_lo: NDArray[np.float64],
    a_hi: NDArray[np.float64],
    b_lo: NDArray[np.float64],
    b_hi: NDArray[np.float64],
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Index arrays ``(ia, ib)`` of every pair of overlapping boxes ``a[ia] x b[ib]``.

    ``*_lo`` / ``*_hi`` are (N, 2) lower and upper corners (finite, ``lo <= hi``). Pass the same
    arrays for ``a`` and ``b`` to get the pairs within one set (``i == j`` included: callers
    drop them or keep ``i < j``).
    """
    a_lo, a_hi = _corners(a_lo), _corners(a_hi)
    b_lo, b_hi = _corners(b_lo), _corners(b_hi)
    empty = np.zeros(0, dtype=np.int64)
    if not len(a_lo) or not len(b_lo):
        return empty, empty
    extents = np.concatenate([a_hi - a_lo, b_hi - b_lo]).max(axis=1)
    span = float(np.ptp(np.concatenate([a_lo, a_hi, b_lo, b_hi]), axis=0).max())
    small = max(float(np.percentile(extents, _SMALL_QUANTILE)), span * 1e-6, 1e-9)
    cell = 2.0 * small
    a_large = (a_hi - a_lo).max(axis=1) > small
    b_large = (b_hi - b_lo).max(axis=1) > small
    found_a: list[NDArray[np.int64]] = []
    found_b: list[NDArray[np.int64]] = []

    def keep(ia: NDArray[np.int64], ib: NDArray[np.int64]) -> None:
        hit = np.all((a_lo[ia] <= b_hi[ib]) & (b_lo[ib] <= a_hi[ia]), axis=1)
        found_a.append(ia[hit])
        found_b.append(ib[hit])

    all_b = np.arange(len(b_lo), dtype=np.int64)
    for i in np.flatnonzero(a_large):  # large a: against every b
        keep(np.full(len(all_b), i, dtype=np.int64), all_b)
    small_a = np.flatnonzero(~a_large)
    for j in np.flatnonzero(b_large):  # large b: against every small a (large a done above)
        keep(small_a, np.full(len(small_a), j, dtype=np.int64))

    # small boxes: filed under the cell of their lower corner; a box spans at most that cell and
    # the next one on each axis, so two overlapping small boxes have cells at most 1 apart.
    small_b = np.flatnonzero(~b_large)
    origin = np.minimum(a_lo.min(axis=0), b_lo.min(axis=0))
    cells_b = _group(np.floor((b_lo[small_b] - origin) / cell).astype(np.int64), small_b)
    cells_a = _group(np.floor((a_lo[small_a] - origin) / cell).astype(np.int64), small_a)
    for (cx, cy), members_a in cells_a.items():
        near = [
            cells_b[key]
            for key in ((cx + dx, cy + dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1))
            if key in cells_b
        ]
        if not near:
            continue
        members_b = np.concatenate(near)
        ia = np.repeat(members_a, len(members_b))
        ib = np.tile(members_b, len(members_a))
        keep(ia, ib)

    ia_all = np.concatenate(found_a) if found_a else empty
    ib_all = np.concatenate(found_b) if found_b else empty
    order = np.lexsort((ib_all, ia_all))
    return ia_all[order], ib_all[order]


def _corners(values: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray(values, dtype=np.float64).reshape(-1, 2)


def _group(cells: NDArray[np.int64], members: NDArray[np.int64]) -> dict[tuple[int, int], NDArray[np.int64]]:
    """Members grouped by their (cx, cy) cell, each group in ascending member order."""
    groups: dict[tuple[int, int], list[int]] = {}
    for (cx, cy), m in zip(cells.tolist(), members.tolist(), strict=True):
        groups.setdefault((cx, cy), []).append(m)
    return {key: np.asarray(value, dtype=np.int64) for key, value in groups.items()}

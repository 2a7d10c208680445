"""Distances between convex footprints (oriented rectangles), many pairs at once.

Guarantee: :func:`polygon_distance` of one pair is :func:`polygon_distances` of a batch of one,
so a relation decided one pair at a time (the spatial API) and one decided for a batch (the
scene graph, the region clusters) see the same floats. The arithmetic is element-wise (no
matrix products, whose fused multiply-adds would round differently between the two paths).

The distance is 0 when the polygons overlap (separating-axis test), else the smallest distance
from a corner of either polygon to an edge of the other.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

_DEGENERATE = 1e-18
"""Squared length below which an edge is a point: no axis (separation), no direction (distance)."""


def _separated(p: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(K,) whether polygons p[k] (K, N, 2) and q[k] (K, M, 2) have a separating edge axis."""
    out = np.zeros(len(p), dtype=bool)
    for poly in (p, q):
        edges = np.roll(poly, -1, axis=1) - poly  # (K, E, 2)
        ax, ay = -edges[..., 1], edges[..., 0]
        valid = ax * ax + ay * ay >= _DEGENERATE
        pp = p[:, None, :, 0] * ax[..., None] + p[:, None, :, 1] * ay[..., None]  # (K, E, N)
        qq = q[:, None, :, 0] * ax[..., None] + q[:, None, :, 1] * ay[..., None]
        apart = (pp.max(axis=2) < qq.min(axis=2)) | (qq.max(axis=2) < pp.min(axis=2))
        out |= np.any(apart & valid, axis=1)
    return out


def _corner_edge_distances(points: NDArray[np.float64], poly: NDArray[np.float64]) -> NDArray[np.float64]:
    """(K,) smallest distance from the corners points[k] (K, N, 2) to the edges of poly[k]."""
    a = poly
    ab = np.roll(poly, -1, axis=1) - poly  # (K, E, 2)
    denom = ab[..., 0] * ab[..., 0] + ab[..., 1] * ab[..., 1]  # (K, E)
    dx = points[:, None, :, 0] - a[..., 0][..., None]  # (K, E, N)
    dy = points[:, None, :, 1] - a[..., 1][..., None]
    dot = dx * ab[..., 0][..., None] + dy * ab[..., 1][..., None]
    point_edge = denom < _DEGENERATE
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(point_edge[..., None], 0.0, np.clip(dot / denom[..., None], 0.0, 1.0))
    ex = points[:, None, :, 0] - (a[..., 0][..., None] + t * ab[..., 0][..., None])
    ey = points[:, None, :, 1] - (a[..., 1][..., None] + t * ab[..., 1][..., None])
    distances: NDArray[np.float64] = np.sqrt(ex * ex + ey * ey).min(axis=(1, 2))
    return distances


def polygon_distances(p: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.float64]:
    """(K,) distances between convex polygons p[k] (K, N, 2) and q[k] (K, M, 2), corners in
    order; 0 where they overlap."""
    p = np.asarray(p, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    out = np.zeros(len(p))
    apart = _separated(p, q)
    if apart.any():
        ps, qs = p[apart], q[apart]
        out[apart] = np.minimum(_corner_edge_distances(ps, qs), _corner_edge_distances(qs, ps))
    return out


def polygon_distance(p: NDArray[np.float64], q: NDArray[np.float64]) -> float:
    """Distance between two convex polygons (corners (N, 2) in order); 0 when they overlap."""
    return float(polygon_distances(np.asarray(p)[None], np.asarray(q)[None])[0])


def centre_distances(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """(K,) distances between xy points a[k] and b[k] (K, 2), element-wise arithmetic."""
    dx = a[..., 0] - b[..., 0]
    dy = a[..., 1] - b[..., 1]
    distances: NDArray[np.float64] = np.sqrt(dx * dx + dy * dy)
    return distances

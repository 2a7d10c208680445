"""``body_clearance`` in plain numpy: the oracle of the compiled loops in ``storyteller.sim.paths.footprint_distance``.

``body_clearance_reference`` takes the same arguments as ``storyteller.sim.paths.footprint_distance.body_clearance``
and must give the very same floats (``tests/sim/paths/test_body_clearance_kernels.py`` compares them);
the rotation into each object's frame is ``SceneObject.to_local``. Not used by the simulation.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from storyteller.sim.paths.footprint_distance import bounding_circles
from storyteller.sim.scene.model import SceneObject


def _point_rect_distance(local: np.ndarray, hw: float, hd: float) -> np.ndarray:
    """Distance of local points (N, 2) to the axis-aligned rectangle [-hw, hw] x [-hd, hd]."""
    dx = np.maximum(np.abs(local[:, 0]) - hw, 0.0)
    dy = np.maximum(np.abs(local[:, 1]) - hd, 0.0)
    distance: np.ndarray = np.hypot(dx, dy)
    return distance


def segment_rect_distance(a: np.ndarray, b: np.ndarray, hw: float, hd: float) -> np.ndarray:
    """Exact distance between local segments a->b (N, 2) and the rectangle [-hw, hw] x [-hd, hd]."""
    d = b - a
    # Liang-Barsky clip: does the segment cross the rectangle?
    t_lo = np.zeros(len(a))
    t_hi = np.ones(len(a))
    inside = np.ones(len(a), dtype=bool)
    for axis, h in ((0, hw), (1, hd)):
        da = d[:, axis]
        pa = a[:, axis]
        flat = np.abs(da) < 1e-12
        inside &= ~flat | (np.abs(pa) <= h)
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-h - pa) / da
            t2 = (h - pa) / da
        t_lo = np.where(flat, t_lo, np.maximum(t_lo, np.minimum(t1, t2)))
        t_hi = np.where(flat, t_hi, np.minimum(t_hi, np.maximum(t1, t2)))
    crosses = inside & (t_lo <= t_hi)
    # Otherwise the closest pair involves an endpoint of the segment or a corner of the box.
    dist = np.minimum(_point_rect_distance(a, hw, hd), _point_rect_distance(b, hw, hd))
    dd = np.maximum(np.sum(d * d, axis=1), 1e-18)
    for cx, cy in ((-hw, -hd), (hw, -hd), (hw, hd), (-hw, hd)):
        c = np.array([cx, cy])
        t = np.clip(np.sum((c - a) * d, axis=1) / dd, 0.0, 1.0)
        dist = np.minimum(dist, np.linalg.norm(a + t[:, None] * d - c, axis=1))
    return np.where(crosses, 0.0, dist)


def body_clearance_reference(
    obstacles: Sequence[SceneObject], a: np.ndarray, b: np.ndarray, cutoff: float | None = None
) -> np.ndarray:
    """``body_clearance`` in plain numpy (the oracle its compiled loops reproduce)."""
    a = np.asarray(a, dtype=float).reshape(-1, 2)
    b = np.asarray(b, dtype=float).reshape(-1, 2)
    out = np.full(len(a), np.inf)
    objs = list(obstacles)
    if cutoff is not None and objs and len(a):
        centres, radii = bounding_circles(objs)
        d = b - a
        dd = np.maximum(np.sum(d * d, axis=1), 1e-18)[:, None]  # (N, 1)
        rel = centres[None, :, :] - a[:, None, :]  # (N, M, 2)
        t = np.clip((rel[..., 0] * d[:, None, 0] + rel[..., 1] * d[:, None, 1]) / dd, 0.0, 1.0)
        gap = np.hypot(rel[..., 0] - t * d[:, None, 0], rel[..., 1] - t * d[:, None, 1]) - radii[None, :]
        near = np.flatnonzero(np.min(gap, axis=0) < cutoff + 1e-6)
        objs = [objs[k] for k in near]
    for obj in objs:
        out = np.minimum(out, segment_rect_distance(obj.to_local(a), obj.to_local(b), obj.width / 2.0, obj.depth / 2.0))
    return out

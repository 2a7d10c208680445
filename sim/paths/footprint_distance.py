"""How far a body walking a straight segment stays from the objects' footprints (metres): the
clearance every navigation rule is built on (``storyteller.sim.paths.nav_grid`` tests cells and moves with it,
``storyteller.sim.paths.following`` off-grid legs, ``storyteller.sim.world.navigation`` targets).

:func:`body_clearance` gives the smallest distance from segments to any footprint (a footprint is
an object's rectangle in its own frame, ``SceneObject.to_local``); its per-element arithmetic runs
compiled (``_near_circles``, ``_min_segment_rect_distance``). :class:`Obstacles` keeps the
geometry it reads for a fixed set of objects. The plain helpers: the distance of points to a
segment and to an axis-aligned rectangle, and whether a disc fits inside the bounds.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import cached_property

import numpy as np
from numba import njit
from numpy.typing import NDArray

from storyteller.sim.scene.model import SceneObject


def segment_point_distance(a: NDArray[np.float64], b: NDArray[np.float64], q: NDArray[np.float64]) -> float:
    """Smallest distance (metres) from the points ``q`` (N, 2) to the segment a-b."""
    ab = b - a
    denom = float(ab @ ab)
    t = np.zeros(len(q)) if denom <= 0.0 else np.clip((q - a) @ ab / denom, 0.0, 1.0)
    return float(np.min(np.linalg.norm(q - (a + t[:, None] * ab), axis=1)))


def point_rect_distance(local: NDArray[np.float64], hw: float, hd: float) -> NDArray[np.float64]:
    """Distance of local points (N, 2) to the axis-aligned rectangle [-hw, hw] x [-hd, hd]."""
    dx = np.maximum(np.abs(local[:, 0]) - hw, 0.0)
    dy = np.maximum(np.abs(local[:, 1]) - hd, 0.0)
    return np.asarray(np.hypot(dx, dy), dtype=np.float64)


def body_clearance(
    obstacles: tuple[SceneObject, ...] | list[SceneObject], a: np.ndarray, b: np.ndarray, cutoff: float | None = None
) -> np.ndarray:
    """Smallest distance (N,) from segments a->b (N, 2) to any obstacle footprint (inf if none).

    ``cutoff`` (metres): only distances below it are needed. Obstacles whose bounding circle
    is at least ``cutoff`` from every segment are skipped, so a returned value below
    ``cutoff`` is exact (the same floats as without it) and a value >= ``cutoff`` only says
    "at least ``cutoff``" (comparisons against thresholds <= ``cutoff`` are unchanged).

    The per-element arithmetic runs compiled (``_near_circles``, ``_min_segment_rect_distance``)
    with the float operations of the numpy oracle in ``tests/support/clearance_reference.py`` (the
    same floats; ``tests/sim/paths/test_body_clearance_kernels.py`` compares them); the rotation into each object's frame
    stays ``SceneObject.to_local``.
    """
    a = np.ascontiguousarray(np.asarray(a, dtype=float).reshape(-1, 2))
    b = np.ascontiguousarray(np.asarray(b, dtype=float).reshape(-1, 2))
    out = np.full(len(a), np.inf)
    objs = list(obstacles)
    known = obstacles if isinstance(obstacles, Obstacles) else None  # geometry computed once
    if cutoff is not None and len(objs) * len(a) > PRUNE_PAIRS:
        return _pruned_clearance(objs, known, a, b, float(cutoff), out)
    which: Sequence[int] = range(len(objs))
    if cutoff is not None and objs and len(a):
        centres, radii = known.circles if known is not None else bounding_circles(objs)
        which = np.flatnonzero(_near_circles(a, b, centres, radii, float(cutoff) + 1e-6)).tolist()
    same = a is b or np.array_equal(a, b)
    for k in which:  # SceneObject.to_local's arithmetic, with the object's frame looked up once
        obj = objs[k]
        centre, right, facing = known.frames[k] if known is not None else object_frame(obj)
        da = a - centre
        ax, ay = da @ right, da @ facing
        if same:
            bx, by = ax, ay
        else:
            db = b - centre
            bx, by = db @ right, db @ facing
        _min_segment_rect_distance(ax, ay, bx, by, obj.width / 2.0, obj.depth / 2.0, out)
    return out


PRUNE_PAIRS = 1_000_000
"""Segment-object pairs above which :func:`body_clearance` with a ``cutoff`` looks at each
object's nearby segments only (found through segments sorted by x) instead of all of them: a
scene's whole grid against each of its objects grows with cells x objects, and a 2,000-object
scene cost 40 s. The bundled and reference scenes stay below it (the office: 3,300 cells x 41 objects)."""


def _pruned_clearance(objs: list[SceneObject], known: Obstacles | None, a: np.ndarray, b: np.ndarray, cutoff: float,
                      out: np.ndarray) -> np.ndarray:
    """``body_clearance`` with a ``cutoff`` in time near-linear in segments + objects: each object
    against the segments whose bounding box meets the square around its bounding circle grown by
    ``cutoff`` (the others are at least ``cutoff`` away). Values below ``cutoff`` are exact."""
    centres, radii = known.circles if known is not None else bounding_circles(objs)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.argsort(lo[:, 0], kind="stable")
    lo_x = lo[order, 0]
    widest = float((hi[:, 0] - lo[:, 0]).max()) if len(a) else 0.0
    for k, obj in enumerate(objs):
        reach = float(radii[k]) + cutoff + 1e-6
        cx, cy = float(centres[k, 0]), float(centres[k, 1])
        start, stop = np.searchsorted(lo_x, [cx - reach - widest, cx + reach], side="right")
        near = order[start:stop]
        near = near[(hi[near, 0] >= cx - reach) & (lo[near, 1] <= cy + reach) & (hi[near, 1] >= cy - reach)]
        if not len(near):
            continue
        centre, right, facing = known.frames[k] if known is not None else object_frame(obj)
        da, db = a[near] - centre, b[near] - centre
        part = out[near]
        _min_segment_rect_distance(da @ right, da @ facing, db @ right, db @ facing, obj.width / 2.0, obj.depth / 2.0,
                                   part)
        out[near] = part
    return out


def object_frame(obj: SceneObject) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(``center_xy``, ``right``, facing) arrays of an object: its footprint's frame."""
    return obj.center_xy, obj.right, np.array(obj.facing, dtype=float)


def bounding_circles(obstacles: Sequence[SceneObject]) -> tuple[np.ndarray, np.ndarray]:
    """Centres (M, 2) and radii (M,) of circles containing each footprint."""
    centres = np.array([o.center[:2] for o in obstacles], dtype=float).reshape(-1, 2)
    radii = np.array([math.hypot(o.width / 2.0, o.depth / 2.0) for o in obstacles], dtype=float) * (1 + 1e-9) + 1e-9
    return centres, radii


class Obstacles(tuple[SceneObject, ...]):
    """The blocking objects of a grid: a tuple that keeps the geometry ``body_clearance`` reads
    for each of them (bounding circles, footprint frames), computed once on first use (objects
    are immutable, so it never goes stale)."""

    @cached_property
    def circles(self) -> tuple[np.ndarray, np.ndarray]:
        """``bounding_circles`` of the objects."""
        return bounding_circles(self)

    @cached_property
    def frames(self) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]:
        """``object_frame`` of every object, in order."""
        return tuple(object_frame(o) for o in self)


@njit(cache=True, nogil=True)
def _near_circles(a: np.ndarray, b: np.ndarray, centres: np.ndarray, radii: np.ndarray,
                  limit: float) -> np.ndarray:  # pragma: no cover - compiled
    """Which circles (M,) come closer than ``limit`` to some segment a->b (N, 2) (a NaN gap:
    not near, like numpy's NaN-propagating min)."""
    m = centres.shape[0]
    near = np.zeros(m, dtype=np.bool_)
    for j in range(m):
        lowest = np.inf
        nan = False
        for i in range(a.shape[0]):
            d0 = b[i, 0] - a[i, 0]
            d1 = b[i, 1] - a[i, 1]
            dd = _fmax(d0 * d0 + d1 * d1, 1e-18)
            r0 = centres[j, 0] - a[i, 0]
            r1 = centres[j, 1] - a[i, 1]
            t = _fmin(_fmax((r0 * d0 + r1 * d1) / dd, 0.0), 1.0)
            gap = math.hypot(r0 - t * d0, r1 - t * d1) - radii[j]
            if gap != gap:
                nan = True
            elif gap < lowest:
                lowest = gap
        near[j] = not nan and lowest < limit
    return near


@njit(cache=True, nogil=True)
def _min_segment_rect_distance(ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray, hw: float, hd: float,
                               out: np.ndarray) -> None:  # pragma: no cover - compiled
    """``out = np.minimum(out, segment_rect_distance(a, b, hw, hd))`` (the numpy oracle in
    ``tests/support/clearance_reference.py``) element by element, for
    local segments a -> b given by their coordinates (ax, ay) -> (bx, by)."""
    for i in range(ax.shape[0]):
        a0, a1 = ax[i], ay[i]
        b0, b1 = bx[i], by[i]
        d0, d1 = b0 - a0, b1 - a1
        t_lo, t_hi, inside = 0.0, 1.0, True
        for axis in range(2):
            da = d0 if axis == 0 else d1
            pa = a0 if axis == 0 else a1
            h = hw if axis == 0 else hd
            if abs(da) < 1e-12:
                inside = inside and abs(pa) <= h
            else:
                t1 = (-h - pa) / da
                t2 = (h - pa) / da
                t_lo = _fmax(t_lo, _fmin(t1, t2))
                t_hi = _fmin(t_hi, _fmax(t1, t2))
        if inside and t_lo <= t_hi:
            dist = 0.0
        else:
            dist = _fmin(math.hypot(_fmax(abs(a0) - hw, 0.0), _fmax(abs(a1) - hd, 0.0)),
                         math.hypot(_fmax(abs(b0) - hw, 0.0), _fmax(abs(b1) - hd, 0.0)))
            dd = _fmax(d0 * d0 + d1 * d1, 1e-18)
            for corner in range(4):
                cx = -hw if corner == 0 or corner == 3 else hw
                cy = -hd if corner < 2 else hd
                t = _fmin(_fmax(((cx - a0) * d0 + (cy - a1) * d1) / dd, 0.0), 1.0)
                e0 = (a0 + t * d0) - cx
                e1 = (a1 + t * d1) - cy
                dist = _fmin(dist, math.sqrt(e0 * e0 + e1 * e1))
        out[i] = _fmin(out[i], dist)


@njit(cache=True, inline="always")
def _fmin(x: float, y: float) -> float:  # pragma: no cover - compiled
    """``np.minimum`` of two floats (NaN propagates)."""
    if x != x or y != y:
        return math.nan
    return x if x <= y else y


@njit(cache=True, inline="always")
def _fmax(x: float, y: float) -> float:  # pragma: no cover - compiled
    """``np.maximum`` of two floats (NaN propagates)."""
    if x != x or y != y:
        return math.nan
    return x if x >= y else y


def inside_bounds(p: np.ndarray, lo: tuple[float, float], hi: tuple[float, float], r: float) -> np.ndarray:
    return (
        (p[:, 0] >= lo[0] + r - 1e-9)
        & (p[:, 0] <= hi[0] - r + 1e-9)
        & (p[:, 1] >= lo[1] + r - 1e-9)
        & (p[:, 1] <= hi[1] - r + 1e-9)
    )

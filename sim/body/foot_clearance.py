"""Floor-standing furniture footprints and the shortest horizontal push out of them.

A footprint is an object's oriented xy box (``SceneObject.to_local``: x along its right, y
along its facing), grown by a margin. ``push_out`` moves rigid groups of points (a foot's ankle
and toe) out of every footprint at once: each pass tries, for every box the group is in, the
exits through its four sides and keeps the one that leaves the least summed depth inside all
boxes, then the shortest (a chair's box under a table's is left through a side that clears
both). The loop is a numba kernel; ``_push_out_kernel.py_func`` is the same code in Python
(``tests/sim/body/test_foot_ik.py`` checks they agree bit for bit). A group that starts inside no box
is not moved; ``BoxGrid`` finds, per point, the few boxes it may be inside, so a crowd's feet
are not each tested against every box of a large scene (``_may_be_inside``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from storyteller.sim.scene.model import Scene

__all__ = ["BoxGrid", "Footprints", "push_out"]


@dataclass(frozen=True)
class Footprints:
    """Oriented xy boxes: centres, unit right / facing axes (B, 2) and half sizes (B, 2)
    (along right, along facing), already grown by the margin."""

    centers: NDArray[np.float64]
    rights: NDArray[np.float64]
    facings: NDArray[np.float64]
    halves: NDArray[np.float64]

    @classmethod
    def from_scene(cls, scene: Scene, margin: float, floor_support: float = 0.10) -> Footprints:
        """The footprints of the objects standing on the floor (bottom within
        ``floor_support`` of ``scene.floor_z``), each grown by ``margin`` metres."""
        objs = [o for o in scene.objects if o.z_min - scene.floor_z < floor_support]
        if not objs:
            empty = np.zeros((0, 2))
            return cls(empty, empty.copy(), empty.copy(), empty.copy())
        return cls(
            centers=np.array([o.center_xy for o in objs], dtype=np.float64),
            rights=np.array([o.right for o in objs], dtype=np.float64),
            facings=np.array([o.facing for o in objs], dtype=np.float64),
            halves=np.array([[o.width / 2 + margin, o.depth / 2 + margin] for o in objs], dtype=np.float64),
        )

    def __len__(self) -> int:
        return len(self.centers)


@njit(cache=True)
def _depth(x: float, y: float, centers: NDArray[np.float64], rights: NDArray[np.float64], facings: NDArray[np.float64],
           halves: NDArray[np.float64], b: int) -> float:  # pragma: no cover - compiled
    """How deep (m) point (x, y) is inside box ``b`` (<= 0: outside or on its edge)."""
    dx = x - centers[b, 0]
    dy = y - centers[b, 1]
    lx = dx * rights[b, 0] + dy * rights[b, 1]
    ly = dx * facings[b, 0] + dy * facings[b, 1]
    depth: float = min(halves[b, 0] - abs(lx), halves[b, 1] - abs(ly))
    return depth


@njit(cache=True)
def _penetration(points: NDArray[np.float64], m: int, sx: float, sy: float, centers: NDArray[np.float64],
                 rights: NDArray[np.float64], facings: NDArray[np.float64], halves: NDArray[np.float64]) -> float:  # pragma: no cover - compiled
    """Summed depth of foot ``m``'s points, shifted by (sx, sy), inside all boxes."""
    total = 0.0
    for b in range(centers.shape[0]):
        for p in range(points.shape[1]):
            d = _depth(points[m, p, 0] + sx, points[m, p, 1] + sy, centers, rights, facings, halves, b)
            if d > 0.0:
                total += d
    return total


@njit(cache=True)
def _push_out_kernel(points: NDArray[np.float64], centers: NDArray[np.float64], rights: NDArray[np.float64], facings: NDArray[np.float64],
                     halves: NDArray[np.float64], passes: int) -> NDArray[np.float64]:  # pragma: no cover - compiled
    m_count = points.shape[0]
    shift = np.zeros((m_count, 2))
    for m in range(m_count):
        sx = 0.0
        sy = 0.0
        for _ in range(passes):
            if _penetration(points, m, sx, sy, centers, rights, facings, halves) <= 0.0:
                break
            best_pen = np.inf
            best_len = np.inf
            bx = sx
            by = sy
            for b in range(centers.shape[0]):
                inside = False
                for p in range(points.shape[1]):
                    if _depth(points[m, p, 0] + sx, points[m, p, 1] + sy, centers, rights, facings, halves, b) > 0.0:
                        inside = True
                if not inside:
                    continue
                for side in range(4):
                    axis = side // 2
                    sign = 1.0 if side % 2 == 0 else -1.0
                    ax = rights[b, 0] if axis == 0 else facings[b, 0]
                    ay = rights[b, 1] if axis == 0 else facings[b, 1]
                    need = 0.0  # move along sign*axis until every inside point leaves box b
                    for p in range(points.shape[1]):
                        x = points[m, p, 0] + sx
                        y = points[m, p, 1] + sy
                        if _depth(x, y, centers, rights, facings, halves, b) > 0.0:
                            loc = (x - centers[b, 0]) * ax + (y - centers[b, 1]) * ay
                            need = max(need, halves[b, axis] - sign * loc)
                    cx = sx + sign * ax * need
                    cy = sy + sign * ay * need
                    pen = _penetration(points, m, cx, cy, centers, rights, facings, halves)
                    length = np.hypot(cx, cy)
                    if pen < best_pen - 1e-12 or (pen <= best_pen + 1e-12 and length < best_len):
                        best_pen = pen
                        best_len = length
                        bx = cx
                        by = cy
            sx = bx
            sy = by
        shift[m, 0] = sx
        shift[m, 1] = sy
    return shift


@dataclass(frozen=True)
class BoxGrid:
    """A uniform grid over footprints: cell (i, j) lists (``items[starts[k]:starts[k + 1]]``,
    k = i * ny + j) every box whose bounding circle (grown by ``SLACK``) overlaps it, so the
    boxes a point may be inside are found without visiting every box of the scene."""

    origin: NDArray[np.float64]  # (2,) xy of cell (0, 0)'s corner, metres
    cell: float  # metres
    shape: tuple[int, int]
    starts: NDArray[np.int64]
    items: NDArray[np.int64]

    SLACK = 0.01  # metres added to a box's circumradius (rounding of its axes)

    @classmethod
    def of(cls, footprints: Footprints, cell: float = 1.0) -> BoxGrid:
        c, h = footprints.centers, footprints.halves
        if len(c) == 0:
            return cls(np.zeros(2), cell, (0, 0), np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64))
        r = np.hypot(h[:, 0], h[:, 1]) + cls.SLACK
        lo, hi = (c - r[:, None]).min(axis=0), (c + r[:, None]).max(axis=0)
        nx, ny = (int(v) + 1 for v in np.floor((hi - lo) / cell))
        lists: list[list[int]] = [[] for _ in range(nx * ny)]
        for b in range(len(c)):
            i0, j0 = (int(v) for v in np.floor((c[b] - r[b] - lo) / cell))
            i1, j1 = (int(v) for v in np.floor((c[b] + r[b] - lo) / cell))
            for i in range(max(i0, 0), min(i1, nx - 1) + 1):
                for j in range(max(j0, 0), min(j1, ny - 1) + 1):
                    lists[i * ny + j].append(b)
        starts = np.cumsum([0] + [len(x) for x in lists]).astype(np.int64)
        items = np.array([b for x in lists for b in x], dtype=np.int64)
        return cls(lo.astype(np.float64), float(cell), (nx, ny), starts, items)


@njit(cache=True)
def _may_be_inside(points: NDArray[np.float64], centers: NDArray[np.float64], rights: NDArray[np.float64],
                   facings: NDArray[np.float64], halves: NDArray[np.float64], origin: NDArray[np.float64],
                   cell: float, nx: int, ny: int, starts: NDArray[np.int64],
                   items: NDArray[np.int64]) -> NDArray[np.bool_]:  # pragma: no cover - compiled
    """Per group m of ``points`` (M, P, 2): whether some point is inside some box (depth > 0),
    the test ``_push_out_kernel`` starts with, on the boxes of the point's grid cell only."""
    out = np.zeros(points.shape[0], dtype=np.bool_)
    for m in range(points.shape[0]):
        for p in range(points.shape[1]):
            x, y = points[m, p, 0], points[m, p, 1]
            i = int(np.floor((x - origin[0]) / cell))
            j = int(np.floor((y - origin[1]) / cell))
            if i < 0 or j < 0 or i >= nx or j >= ny:
                continue
            k = i * ny + j
            for q in range(starts[k], starts[k + 1]):
                if _depth(x + 0.0, y + 0.0, centers, rights, facings, halves, items[q]) > 0.0:
                    out[m] = True
                    break
            if out[m]:
                break
    return out


def push_out(points: NDArray[np.float64], footprints: Footprints, passes: int = 4) -> NDArray[np.float64]:
    """Horizontal shifts (M, 2) that move each rigid group of points (M, P, 2) out of every
    footprint: each pass tries, for every box the group is in, the four sides' exits and keeps
    the one leaving the least summed depth inside all boxes (then the shortest); a group that
    cannot be cleared in ``passes`` passes keeps the best shift found."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim != 3 or pts.shape[2] != 2:
        raise ValueError(f"points must be (M, P, 2), got {pts.shape}")
    if len(footprints) == 0 or len(pts) == 0:
        return np.zeros((len(pts), 2))
    return _push_out_kernel(pts, footprints.centers, footprints.rights, footprints.facings,
                            footprints.halves, int(passes))

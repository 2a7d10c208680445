"""The moves stationary bodies leave: a planning call's discs (characters standing still) and
segments (bodies sweeping an off-grid leg during the step) remove, per cell, every move whose
closest approach to them is below ``min(2r, distance at the move's start)`` (the clearance rule
of ``storyteller.sim.paths.cooperative_astar``).

Two views of the same removal: per padded cell the bit mask of the moves left (what the compiled
passes and the goal / detour distances read, ``static_allow_of``), and neighbour lists with the
moves taken out (the pure-Python backend, ``static_overrides``). Both are memoised per exact
body position, so a body standing still for many replans costs one geometry pass.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.paths.clearance import segment_distance
from storyteller.sim.paths.move_tables import Move, MoveTables, Neighbour

Segment = tuple[NDArray[np.float64], NDArray[np.float64]]


class StaticBodies:
    """The moves left by stationary bodies on ``tables`` for bodies ``min_distance`` metres
    apart (centre to centre)."""

    def __init__(self, tables: MoveTables, min_distance: float) -> None:
        self.tables = tables
        self.min_distance = min_distance
        self._removed_memo: dict[tuple[bytes, bytes], dict[int, frozenset[int]]] = {}
        self._removed_bits_memo: dict[tuple[bytes, bytes], tuple[NDArray[np.int64], NDArray[np.int64]]] = {}

    def static_allow_of(self, statics: Sequence[NDArray[np.float64]], segments: Sequence[Segment]) -> NDArray[np.int64]:
        """``static_allow(overrides)`` for the overrides ``static_overrides(statics, segments)``
        would build, folded directly from the memoised removed moves of each body (arrays)."""
        tables = self.tables
        segs = [(np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)) for p, q in segments]
        segs += [(np.asarray(p, dtype=np.float64), np.asarray(p, dtype=np.float64)) for p in statics]
        if not segs:
            return tables.all_allowed
        parts = [self._removed_bits(p, q) for p, q in segs]
        cids = np.concatenate([c for c, _ in parts])
        bits = np.concatenate([b for _, b in parts])
        removed = np.zeros(len(tables.all_allowed), dtype=np.int64)
        np.bitwise_or.at(removed, cids, bits)
        out = tables.all_allowed.copy()
        touched = np.unique(cids)
        out[touched] = tables.cell_bits[touched] & ~removed[touched]
        return out

    def _removed_bits(self, p: NDArray[np.float64], q: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """``_removed_moves(p, q)`` as (cell ids, bit mask of the removed moves per cell), memoised."""
        key = (p.tobytes(), q.tobytes())
        hit = self._removed_bits_memo.get(key)
        if hit is None:
            per = self._removed_moves(p, q)
            nbrs = self.tables.nbrs
            cids = np.fromiter(per, dtype=np.int64, count=len(per))
            bits = np.array([sum(1 << (nbrs[cid][k][4] + 6) for k in ks) for cid, ks in per.items()],
                            dtype=np.int64).reshape(-1)
            if len(self._removed_bits_memo) > 4096:
                self._removed_bits_memo.clear()
            hit = self._removed_bits_memo[key] = (cids, bits)
        return hit

    def static_allow(self, overrides: Mapping[int, list[Move]]) -> NDArray[np.int64]:
        """Per padded cell, the bit mask of the moves left by ``overrides`` (all elsewhere)."""
        if not overrides:
            return self.tables.all_allowed
        out = self.tables.all_allowed.copy()
        for cid, lst in overrides.items():
            mask = 0
            for nb in lst:
                mask |= nb[2]
            out[cid] = mask
        return out

    def static_overrides(
        self, statics: Sequence[NDArray[np.float64]], segments: Sequence[Segment] = ()
    ) -> dict[int, list[Neighbour]]:
        """Neighbour lists with moves removed that bring a body too close to a stationary one.

        ``statics``: disc centres (metres). ``segments``: bodies that sweep a straight segment
        (p, q) during the step (an off-grid leg): a move is kept when its closest approach to
        every static point / segment is >= ``min(2r, distance at the move's start)``.
        """
        segs = [(np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)) for p, q in segments]
        segs += [(np.asarray(p, dtype=np.float64), np.asarray(p, dtype=np.float64)) for p in statics]
        if not segs:
            return {}
        removed: dict[int, set[int]] = {}
        for p, q in segs:
            for cid, ks in self._removed_moves(p, q).items():
                hit = removed.get(cid)
                if hit is None:
                    removed[cid] = set(ks)
                else:
                    hit.update(ks)
        nbrs = self.tables.nbrs
        return {cid: [nb for k, nb in enumerate(nbrs[cid]) if k not in ks] for cid, ks in removed.items()}

    def _removed_moves(self, p: NDArray[np.float64], q: NDArray[np.float64]) -> dict[int, frozenset[int]]:
        """For one static point / segment (p, q): cell id -> indices into ``nbrs[cell]`` of the
        moves that break the clearance rule against it (memoised per exact (p, q)).

        Only cells within ``reach`` of the segment can lose a move; the test per move is the one
        of ``static_overrides`` (closest approach >= ``min(2r, distance at the move's start)``).
        """
        key = (p.tobytes(), q.tobytes())
        hit = self._removed_memo.get(key)
        if hit is not None:
            return hit
        tables = self.tables
        g = tables.grid
        cs = g.cell_size
        reach_m = self.min_distance + 2.0 * cs
        rr = int(math.ceil(reach_m / cs)) + 1
        (i0, j0), (i1, j1) = g.cell_of(p), g.cell_of(q)
        cand = sorted(
            tables.cell_id((i, j))
            for i in range(min(i0, i1) - rr, max(i0, i1) + rr + 1)
            for j in range(min(j0, j1) - rr, max(j0, j1) + rr + 1)
            if g.is_free(i, j)
        )
        out: dict[int, frozenset[int]] = {}
        if cand:
            centres = np.array([g.center_of(*tables.id_cell(cid)) for cid in cand])
            start = segment_distance(centres, centres, np.broadcast_to(p, centres.shape), np.broadcast_to(q, centres.shape))
            limit = np.minimum(self.min_distance, start) - 1e-7
            row_cell, row_k, dxy = [], [], []
            for r, cid in enumerate(cand):
                for k, nb in enumerate(tables.nbrs[cid]):
                    row_cell.append(r)
                    row_k.append(k)
                    dxy.append((nb[2], nb[3]))
            rc = np.array(row_cell)
            a = centres[rc]
            b = a + np.array(dxy, dtype=np.float64) * cs
            closest = segment_distance(a, b, np.broadcast_to(p, a.shape), np.broadcast_to(q, a.shape))
            bad = np.flatnonzero(~(closest >= limit[rc]))
            per: dict[int, list[int]] = {}
            for r in bad.tolist():
                per.setdefault(cand[row_cell[r]], []).append(row_k[r])
            out = {cid: frozenset(ks) for cid, ks in per.items()}
        if len(self._removed_memo) > 4096:
            self._removed_memo.clear()
        self._removed_memo[key] = out
        return out

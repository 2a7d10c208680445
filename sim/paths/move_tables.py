"""The planner's move tables for one grid and body radius, built once per ``PathPlanner``.

Cells are addressed by *padded ids*: the grid with ``pad`` blocked cells on every side, row-major,
so that a neighbourhood of an id never leaves the table. Per free cell the moves out of it (wait
first, then the grid's allowed ``MOVES``); per relative offset and velocity of another agent (a
*clearance-table base*, ``storyteller.sim.paths.clearance``), the bit mask of our moves that keep the
clearance rule against it. Move bits: bit ``m + 6`` for the move with code ``m = 5 * dx + dy``
(waiting is bit 6, ``WAIT_BIT``). The same tables as arrays feed the compiled kernels
(``storyteller.sim.paths.astar_kernel``); the lists feed the pure-Python backend (``storyteller.sim.paths.python_backend``).

Pure: a function of the grid and the reach; nothing here changes after construction except the
memos of ``near_cells`` and ``near_masks`` (the latter shared by the planners of one grid).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from storyteller.sim.paths.clearance import segment_distance, segment_min_norm
from storyteller.sim.paths.grid_moves import MOVES
from storyteller.sim.paths.nav_grid import NavGrid
from storyteller.sim.paths.plan_types import Cell

WAIT_BIT = 1 << 6  # the move bit of waiting (move code 0)
WAIT_CODE = 12  # the velocity code (dx + 2) * 5 + (dy + 2) of waiting
STRIDE_SAMPLES = 17  # instants of a step at which two striding walkers are checked
LEG_REACH_M = 0.38
"""Metres a walking body's foot reaches ahead of (and behind) its pelvis along its direction of
travel (the stride; crossing walkers touched feet and thighs with their pelvises 0.61-0.65 m
apart)."""
LEG_TRAIL_M = 0.3
LEG_RADIUS_M = 0.07  # a leg's radius (the thigh's) in metres
HIP_RADIUS_M = 0.17  # metres from the pelvis to the outside of a hip
Move2 = tuple[int, int]
# a move out of a cell: (next padded id, cost in cells, dx, dy, move code 5 * dx + dy)
Neighbour = tuple[int, float, int, int, int]
# the same move as the search sees it: (next padded id, cost in cells, move bit)
Move = tuple[int, float, int]


class MoveTables:
    """The moves of ``grid`` and the clearance masks for agents within ``reach`` cells
    (Chebyshev) of each other; ``d_cells``: the clearance distance (2 body radii) in cells. Two
    agents that both move in a step also keep their legs apart (``striding_safe``; see
    ``sim.paths.cooperative_astar``); ``reach`` must cover their legs end to end."""

    def __init__(self, grid: NavGrid, reach: int, d_cells: float) -> None:
        self.grid = grid
        self.reach = reach
        self.pad = reach
        nx, ny = grid.shape
        self.nx_p, self.ny_p = nx + 2 * self.pad, ny + 2 * self.pad
        self._build_neighbours()
        self._build_clearance_table(d_cells)
        self._build_move_masks(striding_safe(reach - 1, d_cells, grid.cell_size))
        self._build_dense_tables()

    # ----- ids -----------------------------------------------------------------------------
    def cell_id(self, cell: Cell) -> int:
        return (cell[0] + self.pad) * self.ny_p + cell[1] + self.pad

    def id_cell(self, cid: int) -> Cell:
        return (cid // self.ny_p - self.pad, cid % self.ny_p - self.pad)

    # ----- tables ----------------------------------------------------------------------------
    def _build_neighbours(self) -> None:
        g = self.grid
        nyp = self.ny_p
        self.nbrs: dict[int, list[Neighbour]] = {}
        for i, j in np.argwhere(g.free):
            cid = self.cell_id((int(i), int(j)))
            out: list[Neighbour] = [(cid, 1.0, 0, 0, 0)]
            for k, (dx, dy) in enumerate(MOVES):
                if g.moves[i, j, k]:
                    out.append((cid + dx * nyp + dy, math.hypot(dx, dy), dx, dy, 5 * dx + dy))
            self.nbrs[cid] = out
        rr = self.reach - 1
        side = 2 * rr + 1
        self.nbhd_bases = [
            (di * nyp + dj, ((di + rr) * side + (dj + rr)) * 25) for di in range(-rr, rr + 1) for dj in range(-rr, rr + 1)
        ]
        self._near_cells_memo: dict[int, list[tuple[int, int]]] | None = None

    @property
    def near_cells(self) -> dict[int, list[tuple[int, int]]]:
        """For an agent at cell a: the free cells within reach and the table base of a seen from
        them (built on first use: only the pure-Python backend reads it)."""
        if self._near_cells_memo is None:
            nbrs = self.nbrs
            self._near_cells_memo = {
                a: [(a - off, base) for off, base in self.nbhd_bases if (a - off) in nbrs] for a in nbrs
            }
        return self._near_cells_memo

    def _build_clearance_table(self, d_cells: float) -> None:
        """safe[(di, dj, wx, wy)]: other at offset (di, dj), relative velocity (wx, wy) in cells/step."""
        rr = self.reach - 1
        self.safe: list[bool] = []
        for di in range(-rr, rr + 1):
            for dj in range(-rr, rr + 1):
                for wx in range(-2, 3):
                    for wy in range(-2, 3):
                        start = math.hypot(di, dj)
                        closest = segment_min_norm(di, dj, wx, wy)
                        self.safe.append(closest >= min(d_cells, start) - 1e-7)

    def _build_move_masks(self, striding: dict[tuple[int, int, Move2, Move2], bool]) -> None:
        """Search tables: per cell the moves as (next id, cost, move bit); per clearance-table
        base (offset and the other's velocity code ``base % 25``, ``WAIT_CODE`` when it waits)
        the bit mask of our moves it allows: ``safe`` when one of the two waits, else
        ``striding_safe`` (the walkers' strides)."""
        self.full_mask = sum(1 << (5 * dx + dy + 6) for dx in (-1, 0, 1) for dy in (-1, 0, 1))
        self.snbrs: dict[int, list[Move]] = {
            cid: [(nb[0], nb[1], 1 << (nb[4] + 6)) for nb in lst] for cid, lst in self.nbrs.items()
        }
        rr = self.reach - 1
        side = 2 * rr + 1
        safe = self.safe
        self.mask_of: list[int] = []
        for base in range(len(safe)):
            block, code = divmod(base, 25)
            mask = 0
            for dx in (-1, 0, 1):
                for dy in (-1, 0, 1):
                    k = base - (5 * dx + dy)
                    if not (0 <= k < len(safe) and k // 25 == block):
                        continue
                    other = (code // 5 - 2, code % 5 - 2)  # a reserved agent's move is in -1..1
                    key = (block // side - rr, block % side - rr, other, (dx, dy))
                    ok = striding[key] if key in striding else safe[k]  # else: one of the two waits
                    if ok:
                        mask |= 1 << (5 * dx + dy + 6)
            self.mask_of.append(mask)
        # shared by the planners of one grid (the masks depend only on the grid's cells and radius)
        self._near_mask_memo: dict[int, list[tuple[int, int]]] = self.grid.near_mask_memo

    def _build_dense_tables(self) -> None:
        """The search tables as arrays for the compiled kernels (``storyteller.sim.paths.astar_kernel``)."""
        n = self.nx_p * self.ny_p
        self.nb_id = np.full((n, 9), -1, dtype=np.int64)
        self.nb_cost = np.zeros((n, 9), dtype=np.float64)
        self.nb_bit = np.zeros((n, 9), dtype=np.int64)
        self.free_arr = np.zeros(n, dtype=np.bool_)
        for cid, lst in self.snbrs.items():
            self.free_arr[cid] = True
            for m, (nid, cost, bit) in enumerate(lst):
                self.nb_id[cid, m], self.nb_cost[cid, m], self.nb_bit[cid, m] = nid, cost, bit
        self.nbhd_off = np.array([off for off, _ in self.nbhd_bases], dtype=np.int64)
        self.nbhd_base = np.array([base for _, base in self.nbhd_bases], dtype=np.int64)
        self.mask_arr = np.array(self.mask_of, dtype=np.int64)
        self.all_allowed = np.full(n, self.full_mask, dtype=np.int64)
        self.cell_bits = np.bitwise_or.reduce(self.nb_bit, axis=1)  # the moves a cell has
        # the bit of the opposite move (v -> u for the entry u -> v): bit 1 << (c + 6) <-> 1 << (6 - c)
        code = np.log2(np.maximum(self.nb_bit, 1)).round().astype(np.int64)
        self.nb_rev_bit = np.where(self.nb_bit > 0, np.left_shift(1, 12 - code), 0).astype(np.int64)

    def near_masks(self, a: int, vel: int) -> list[tuple[int, int]]:
        """(cell, mask) for the cells near an agent leaving cell id ``a`` with velocity code
        ``vel``, skipping cells where it allows every move (memoised)."""
        key = a * 25 + vel
        out = self._near_mask_memo.get(key)
        if out is None:
            full, mask_of = self.full_mask, self.mask_of
            out = [(cell, m) for cell, base in self.near_cells[a] if (m := mask_of[base + vel]) != full]
            self._near_mask_memo[key] = out
        return out


@lru_cache(maxsize=8)
def striding_safe(rr: int, d_cells: float, cell_size: float) -> dict[tuple[int, int, Move2, Move2], bool]:
    """Whether two agents that both move in a step keep clear, per (di, dj, other's move, our
    move) with the other at offset (di, dj) cells (Chebyshev <= ``rr``).

    A walking body is its disc (``d_cells`` between centres, the rule of ``safe``) and its legs:
    a segment through its centre along its own direction of travel, ``LEG_REACH_M`` ahead and
    ``LEG_TRAIL_M`` behind (the swinging feet), of radius ``LEG_RADIUS_M``. The legs must keep ``2 *
    LEG_RADIUS_M`` from the other's legs and ``LEG_RADIUS_M + HIP_RADIUS_M`` from the other's
    centre (its hips), at ``STRIDE_SAMPLES`` instants of the step and at the closest approach of
    the centres; a pair that starts closer than that gets no closer. Walkers side by side keep
    the discs' distance; crossing walkers keep their feet apart."""
    reach, leg, hip = LEG_REACH_M / cell_size, LEG_RADIUS_M / cell_size, HIP_RADIUS_M / cell_size
    samples = np.linspace(0.0, 1.0, STRIDE_SAMPLES)
    steps = [(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if (dx, dy) != (0, 0)]
    offsets = [(di, dj) for di in range(-rr, rr + 1) for dj in range(-rr, rr + 1)]
    p0 = np.asarray(offsets, dtype=np.float64)  # (K, 2)
    n = len(samples) + 1
    out: dict[tuple[int, int, Move2, Move2], bool] = {}
    for other in steps:
        a = np.asarray(other, dtype=np.float64)
        for ours in steps:
            b = np.asarray(ours, dtype=np.float64)
            w = a - b
            ww = float(w @ w)
            closest = np.zeros(len(p0)) if ww == 0 else np.clip(-(p0 @ w) / ww, 0.0, 1.0)
            s = np.concatenate([np.broadcast_to(samples, (len(p0), n - 1)), closest[:, None]], axis=1)  # (K, n)
            p = (p0[:, None, :] + s[..., None] * w).reshape(-1, 2)  # the other's centre, ours at 0
            ua, ub = reach * a / np.linalg.norm(a), reach * b / np.linalg.norm(b)
            zero = np.zeros_like(p)
            centres = np.linalg.norm(p, axis=1)
            ta, tb = ua * (LEG_TRAIL_M / LEG_REACH_M), ub * (LEG_TRAIL_M / LEG_REACH_M)
            legs = segment_distance(p - ta, p + ua, zero - tb, zero + ub)
            our_legs = segment_distance(zero - tb, zero + ub, p, p)
            their_legs = segment_distance(p - ta, p + ua, zero, zero)
            ok = np.ones(len(p0), dtype=bool)
            for value, need in ((centres, d_cells), (legs, 2.0 * leg), (our_legs, leg + hip), (their_legs, leg + hip)):
                v = value.reshape(len(p0), n)
                ok &= np.all(v >= np.minimum(need, v[:, :1]) - 1e-7, axis=1)
            for (di, dj), good in zip(offsets, ok.tolist(), strict=True):
                out[(di, dj, other, ours)] = good
    return out

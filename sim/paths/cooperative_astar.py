"""Windowed hierarchical cooperative A* (WHCA*) with a continuous clearance guarantee.

Time is discrete: one *step* lasts ``step_time`` seconds (default ``cell_size / walking_speed``
= 0.3 s = 9 frames at 30 fps). In one step every walking agent either waits or moves to one of
its 8 neighbour cells, moving in a straight line at constant speed (so straight moves run at
the walking speed and diagonals at sqrt(2) times it). All agents share the step clock, so two
agents' relative motion within a step is linear and its closest approach has a closed form.

Clearance rule (the guarantee): for every pair of agents and every step, the centre distance
over the whole step never drops below ``min(2 * body_radius, distance at the step start)``.
Hence agents that start apart (>= 2r) stay apart at every instant, including mid-move and
during diagonal moves, and agents that start too close (e.g. placed by hand) never get closer.
The rule is tabulated once over relative start offsets and relative velocities (cell units),
which covers vertex, swap and following conflicts; an agent farther than ``2 + 2r / cell`` cells
(Chebyshev) cannot conflict within one step. Stationary characters are discs at arbitrary
positions; a move is forbidden for them by the same rule.

Planning pass (prioritized): agents plan one after another in a space-time A* over
``window`` steps against a reservation table of the agents planned before them (plain WHCA*).
If some agent's search fails (it is cornered), the call is planned again with every agent's
"wait where it stands" for the first ``commit_steps`` steps reserved up front and the failed
agents first: then an agent whose search still fails can safely wait, so the committed prefix
of every returned plan is conflict-free. A repair pass (same order, hints and window) takes
the pass before's result for every agent whose search read only reservation entries that
cannot have changed (the compiled search reports the entries it read), so its cost grows with
the neighbourhood of the failed agents, not with the crowd; the plans are the same.
Costs: a move costs its length in cells, waiting costs 1 per step except at the goal (free).
The heuristic is the exact distance on the static grid (Dijkstra per goal, compiled, cached).
Agents named in ``plan(detour=...)`` (walkers that stopped making progress: a stationary body,
such as a member waiting at its target, closes the corridor the static distance leads into)
use instead the exact distance along the moves the stationary bodies leave (Dijkstra per goal
and set of stationary bodies), so their search walks around the blockage; when the bodies
cut the goal off entirely they keep the static distance (and wait for the way to open).
Plans are deterministic: fixed move order, tie-breaking on (f, h, cell), explicit orders.
"""

from __future__ import annotations

import hashlib
import heapq
import math
from collections.abc import Collection, Hashable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, get_args

import numpy as np
from numpy.typing import NDArray

from sim.paths.astar_kernel import (
    dense_pass,
    goal_distances,
    release_path,
    reserve_path,
)
from sim.paths.fallback import failed_first
from sim.paths.nav_grid import MOVES, NavGrid

Cell = tuple[int, int]
Agent = Hashable

_WAIT = (0, 0)
_WAIT_BIT = 1 << 6  # the move bit of waiting (move code 0)
_EPS = 1e-9
Backend = Literal["numba", "python"]
BACKENDS: tuple[Backend, ...] = get_args(Backend)
# a move out of a cell: (next padded id, cost in cells, dx, dy, move code 5 * dx + dy)
_Neighbour = tuple[int, float, int, int, int]
# the same move as the search sees it: (next padded id, cost in cells, move bit)
_Move = tuple[int, float, int]


class PlanningError(ValueError):
    """Bad planner input (unknown cell, blocked start...)."""


@dataclass(frozen=True)
class PlanResult:
    """One planning call. ``paths[a]`` lists ``window + 1`` cells: the start, then one per step
    (only ``commit_steps + 1`` cells, all the start, for agents whose search failed).

    ``failed``: agents for which the windowed search found nothing (they wait in place);
    ``reused``: agents whose ``hints`` path was kept (checked, extended) instead of searched;
    ``fallback``: agents planned again by the fallback pass; ``goals``: the goal actually used
    per agent (replaced by the nearest reachable cell when the requested one is unreachable).
    """

    paths: dict[Agent, list[Cell]]
    failed: frozenset[Agent]
    fallback: frozenset[Agent]
    goals: dict[Agent, Cell]
    expansions: int = 0
    reused: frozenset[Agent] = frozenset()
    detour: dict[Agent, float] = field(default_factory=dict)
    """For the ``detour`` agents planned around the stationary bodies: the distance (cells)
    from the start to the used goal along the moves those bodies leave."""


@dataclass(frozen=True)
class _PassRecord:
    """The outcomes of one dense pass (``astar_kernel.dense_pass``), row k for ``order[k]``:
    the padded ids it reserved (``ids[k, :ids_len[k]]``: its path, or its wait), the
    reservation entries (``t * cells + cell``) its kept-path check and search read
    (``reads[off[k]:off[k + 1]]``), the search's expansions, whether the path was a kept hint,
    whether the search failed, and whether the outcome was taken over from the pass before."""

    order: tuple[Agent, ...]
    ids: NDArray[np.int64]
    ids_len: NDArray[np.int64]
    reads: NDArray[np.int64]
    off: NDArray[np.int64]
    expansions: NDArray[np.int64]
    reused: NDArray[np.bool_]
    failed: NDArray[np.bool_]
    taken: NDArray[np.bool_]


# ``dense_pass``'s previous-pass arguments when there is no pass before
_NO_RECORD: tuple[NDArray[Any], ...] = (
    np.zeros((1, 1), dtype=np.int64), np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64),
    np.zeros(2, dtype=np.int64), np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.bool_), np.zeros(1, dtype=np.bool_),
)


class _Reservations:
    """Per step t (relative to the plan start): for every cell id near a reserved agent, the
    moves those agents still allow there, so that a search looks up one int per expansion.

    ``near[t][cell]`` is a bit mask: bit ``m + 6`` is set when the move with code
    ``m = 5 * dx + dy`` from ``cell`` keeps clear of every agent reserved during step t (cells
    where every move is allowed are absent). ``moves[t]`` keeps each agent's (cell id,
    velocity code) at step t so that ``remove`` can rebuild the masks of a step.
    """

    def __init__(self, n_steps: int, planner: PathPlanner) -> None:
        self.near: list[dict[int, int]] = [{} for _ in range(n_steps)]
        self.moves: list[dict[Agent, tuple[int, int]]] = [{} for _ in range(n_steps)]
        self._planner = planner

    def add(self, agent: Agent, ids: Sequence[int] | NDArray[np.int64], upto: int) -> None:
        nyp = self._planner._ny_p
        masks = self._planner._near_masks
        full = self._planner._full_mask
        for t in range(min(upto, len(ids) - 1, len(self.near))):
            a, b = ids[t], ids[t + 1]
            d = b - a
            dx = round(d / nyp) if abs(d) > 1 else 0
            dy = d - dx * nyp
            vel = (dx + 2) * 5 + (dy + 2)
            self.moves[t][agent] = (a, vel)
            near = self.near[t]
            for cell, mask in masks(a, vel):
                near[cell] = near.get(cell, full) & mask

    def remove(self, agent: Agent, ids: Sequence[int], upto: int) -> None:
        masks = self._planner._near_masks
        full = self._planner._full_mask
        for t in range(min(upto, len(ids) - 1, len(self.near))):
            moves = self.moves[t]
            if moves.pop(agent, None) is None:
                continue
            near: dict[int, int] = {}
            for a, vel in moves.values():
                for cell, mask in masks(a, vel):
                    near[cell] = near.get(cell, full) & mask
            self.near[t] = near

    def allow(self, t: int, cid: int) -> int:
        """Bit mask of the moves from ``cid`` at step ``t`` that keep clear of the reserved agents."""
        return self.near[t].get(cid, self._planner._full_mask) if t < len(self.near) else self._planner._full_mask


class _DenseReservations:
    """The same reservations as ``_Reservations`` on a dense (steps, cells) mask array, folded
    by the compiled ``reserve_path`` and ``release_path`` (the ``numba`` backend). The moves
    are kept per step in one column per agent (``cells``: the cell left, -1 for none;
    ``vels``: the velocity code), so that adding a path is one compiled call."""

    def __init__(self, n_steps: int, planner: PathPlanner, agents: int = 16) -> None:
        self._planner = planner
        self.near = np.full((n_steps, planner._nx_p * planner._ny_p), planner._full_mask, dtype=np.int64)
        self.cells = np.full((n_steps, max(1, agents)), -1, dtype=np.int64)
        self.vels = np.zeros((n_steps, max(1, agents)), dtype=np.int64)
        self._slots: dict[Agent, int] = {}

    def _slot(self, agent: Agent) -> int:
        slot = self._slots.get(agent)
        if slot is None:
            slot = self._slots[agent] = len(self._slots)
            if slot >= self.cells.shape[1]:  # grow the columns (doubling)
                grow = self.cells.shape[1]
                self.cells = np.hstack([self.cells, np.full((len(self.near), grow), -1, dtype=np.int64)])
                self.vels = np.hstack([self.vels, np.zeros((len(self.near), grow), dtype=np.int64)])
        return slot

    def add(self, agent: Agent, ids: Sequence[int] | NDArray[np.int64], upto: int) -> None:
        pl = self._planner
        steps = min(upto, len(ids) - 1, len(self.near))
        if steps <= 0:
            return
        arr = np.asarray(ids, dtype=np.int64)
        slot = self._slot(agent)  # first: it may grow (replace) the column arrays
        reserve_path(self.near, arr, steps, pl._ny_p, pl._nbhd_off, pl._nbhd_base, pl._mask_arr, pl._free_arr,
                     self.cells, self.vels, slot)

    def remove(self, agent: Agent, ids: Sequence[int] | NDArray[np.int64], upto: int) -> None:
        slot = self._slots.get(agent)
        steps = min(upto, len(ids) - 1, len(self.near))
        if slot is None or steps <= 0:
            return
        pl = self._planner
        release_path(self.near, steps, slot, self.cells, self.vels, pl._nbhd_off, pl._free_arr, pl._ny_p,
                     pl.reach - 1, pl._mask_arr, pl._full_mask)

    def allow(self, t: int, cid: int) -> int:
        return int(self.near[t, cid]) if t < len(self.near) else self._planner._full_mask


class PathPlanner:
    """WHCA* over a ``NavGrid``. Pure and deterministic (no clock, no randomness but ``seed``).

    ``window``: steps planned per search (reference: 20). ``commit_steps``: steps executed
    before the next replan (the prefix that is guaranteed conflict-free; default 1 step =
    9 frames, about the reference's 10-frame replan interval). ``step_time``: seconds per step.
    ``max_expansions``: search budget per agent and call; beyond it the agent waits.
    ``backend``: ``"numba"`` (default) runs the reservation folding and the space-time search
    compiled (``sim.paths.astar_kernel``); ``"python"`` runs the same algorithm in pure Python. Both
    return the same plans.
    """

    def __init__(
        self,
        grid: NavGrid,
        window: int = 20,
        commit_steps: int = 1,
        walking_speed: float = 1.0,
        step_time: float | None = None,
        max_expansions: int = 4000,
        fallback: bool = True,
        seed: int = 0,
        repair_passes: int = 3,
        backend: Backend = "numba",
    ) -> None:
        if backend not in BACKENDS:
            raise PlanningError(f"backend must be one of {BACKENDS}, got {backend!r}")
        if window < 1:
            raise PlanningError(f"window must be >= 1 step, got {window}")
        if not 1 <= commit_steps <= window:
            raise PlanningError(f"commit_steps must be in [1, window={window}], got {commit_steps}")
        if not walking_speed > 0:
            raise PlanningError(f"walking_speed must be > 0 m/s, got {walking_speed}")
        self.grid = grid
        self.window = int(window)
        self.commit_steps = int(commit_steps)
        self.step_time = float(step_time if step_time is not None else grid.cell_size / walking_speed)
        self.max_expansions = int(max_expansions)
        self.fallback = bool(fallback)
        self.repair_passes = int(repair_passes)
        self.seed = int(seed)
        self.backend = backend
        self.min_distance = 2.0 * grid.body_radius  # metres between centres
        d_cells = self.min_distance / grid.cell_size
        self.reach = int(math.ceil(d_cells + 2.0 - _EPS))  # Chebyshev distance that can conflict
        self._pad = self.reach
        nx, ny = grid.shape
        self._nx_p, self._ny_p = nx + 2 * self._pad, ny + 2 * self._pad
        self._build_neighbours()
        self._build_clearance_table(d_cells)
        self._build_move_masks()
        self._build_dense_tables()
        self._heuristics: dict[int, list[float]] = {}  # list views of some rows of _h_table
        # goal distances, one row per goal (see _heuristic_row): the compiled pass reads them by row
        self._h_table: NDArray[np.float64] | None = None
        self._h_rows: dict[int, int] = {}  # goal id -> row, oldest first
        self._h_pinned: NDArray[np.int64] = np.zeros(0, dtype=np.int64)  # per row: the pass that last read it
        self._h_epoch = 0
        self._components: dict[int, tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]] = {}
        self._h_capacity = max(513, (256 << 20) // (8 * self._nx_p * self._ny_p))
        self._removed_memo: dict[tuple[bytes, bytes], dict[int, frozenset[int]]] = {}
        self._ring: NDArray[np.int64] | None = None  # goal_distances' bucket scratch, made on first use
        self._detour_memo: dict[tuple[int, bytes], NDArray[np.float64]] = {}  # see detour_distances
        self._detour_graph_memo: tuple[bytes, NDArray[np.float64]] | None = None  # see _detour_graph
        # the last stack of the agents' own distances a dense pass read, and the arrays stacked
        self._extra_memo: tuple[list[NDArray[np.float64]], NDArray[np.float64]] | None = None

    # ----- ids -----------------------------------------------------------------------------
    def cell_id(self, cell: Cell) -> int:
        return (cell[0] + self._pad) * self._ny_p + cell[1] + self._pad

    def id_cell(self, cid: int) -> Cell:
        return (cid // self._ny_p - self._pad, cid % self._ny_p - self._pad)

    def _build_neighbours(self) -> None:
        g = self.grid
        nyp = self._ny_p
        self._nbrs: dict[int, list[_Neighbour]] = {}
        for i, j in np.argwhere(g.free):
            cid = self.cell_id((int(i), int(j)))
            out: list[_Neighbour] = [(cid, 1.0, 0, 0, 0)]
            for k, (dx, dy) in enumerate(MOVES):
                if g.moves[i, j, k]:
                    out.append((cid + dx * nyp + dy, math.hypot(dx, dy), dx, dy, 5 * dx + dy))
            self._nbrs[cid] = out
        rr = self.reach - 1
        side = 2 * rr + 1
        self._nbhd_bases = [
            (di * nyp + dj, ((di + rr) * side + (dj + rr)) * 25) for di in range(-rr, rr + 1) for dj in range(-rr, rr + 1)
        ]
        self._near_cells_memo: dict[int, list[tuple[int, int]]] | None = None

    @property
    def _near_cells(self) -> dict[int, list[tuple[int, int]]]:
        """For an agent at cell a: the free cells within reach and the table base of a seen from
        them (built on first use: only the pure-Python backend reads it)."""
        if self._near_cells_memo is None:
            nbrs = self._nbrs
            self._near_cells_memo = {
                a: [(a - off, base) for off, base in self._nbhd_bases if (a - off) in nbrs] for a in nbrs
            }
        return self._near_cells_memo

    def _build_clearance_table(self, d_cells: float) -> None:
        """safe[(di, dj, wx, wy)]: other at offset (di, dj), relative velocity (wx, wy) in cells/step."""
        rr = self.reach - 1
        self._safe: list[bool] = []
        for di in range(-rr, rr + 1):
            for dj in range(-rr, rr + 1):
                for wx in range(-2, 3):
                    for wy in range(-2, 3):
                        start = math.hypot(di, dj)
                        closest = _segment_min_norm(di, dj, wx, wy)
                        self._safe.append(closest >= min(d_cells, start) - 1e-7)

    def _build_move_masks(self) -> None:
        """Search tables: per cell the moves as (next id, cost, move bit); per clearance-table
        base (offset and the other's velocity) the bit mask of our moves it allows."""
        self._full_mask = sum(1 << (5 * dx + dy + 6) for dx in (-1, 0, 1) for dy in (-1, 0, 1))
        self._snbrs: dict[int, list[_Move]] = {
            cid: [(nb[0], nb[1], 1 << (nb[4] + 6)) for nb in lst] for cid, lst in self._nbrs.items()
        }
        safe = self._safe
        self._mask_of: list[int] = []
        for base in range(len(safe)):
            mask = 0
            for dx in (-1, 0, 1):
                for dy in (-1, 0, 1):
                    k = base - (5 * dx + dy)
                    if 0 <= k < len(safe) and k // 25 == base // 25 and safe[k]:
                        mask |= 1 << (5 * dx + dy + 6)
            self._mask_of.append(mask)
        # shared by the planners of one grid (the masks depend only on the grid's cells and radius)
        self._near_mask_memo: dict[int, list[tuple[int, int]]] = self.grid.near_mask_memo

    def _build_dense_tables(self) -> None:
        """The search tables as arrays for the compiled kernels (``sim.paths.astar_kernel``)."""
        n = self._nx_p * self._ny_p
        self._nb_id = np.full((n, 9), -1, dtype=np.int64)
        self._nb_cost = np.zeros((n, 9), dtype=np.float64)
        self._nb_bit = np.zeros((n, 9), dtype=np.int64)
        self._free_arr = np.zeros(n, dtype=np.bool_)
        for cid, lst in self._snbrs.items():
            self._free_arr[cid] = True
            for m, (nid, cost, bit) in enumerate(lst):
                self._nb_id[cid, m], self._nb_cost[cid, m], self._nb_bit[cid, m] = nid, cost, bit
        self._nbhd_off = np.array([off for off, _ in self._nbhd_bases], dtype=np.int64)
        self._nbhd_base = np.array([base for _, base in self._nbhd_bases], dtype=np.int64)
        self._mask_arr = np.array(self._mask_of, dtype=np.int64)
        self._all_allowed = np.full(n, self._full_mask, dtype=np.int64)
        self._cell_bits = np.bitwise_or.reduce(self._nb_bit, axis=1)  # the moves a cell has
        # the bit of the opposite move (v -> u for the entry u -> v): bit 1 << (c + 6) <-> 1 << (6 - c)
        code = np.log2(np.maximum(self._nb_bit, 1)).round().astype(np.int64)
        self._nb_rev_bit = np.where(self._nb_bit > 0, np.left_shift(1, 12 - code), 0).astype(np.int64)
        self._removed_bits_memo: dict[tuple[bytes, bytes], tuple[NDArray[np.int64], NDArray[np.int64]]] = {}
        self._scratch: tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]] | None = None
        self._expanded = np.zeros(max(1, self.max_expansions), dtype=np.int64)  # the search's expanded keys
        open_size = self._nb_id.shape[1] * max(1, self.max_expansions) + 1  # pushes: the start, then <= 9 per expansion
        self._open = (np.zeros(open_size), np.zeros(open_size), np.zeros(open_size, dtype=np.int64))  # the search's heap
        self._token = 0
        self._near_scratch: NDArray[np.int64] | None = None  # see _pass_scratch
        self._dirty_scratch = np.zeros(0, dtype=np.bool_)

    def _search_scratch(self, window: int) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
        size = (window + 1) * self._nx_p * self._ny_p
        if self._scratch is None or len(self._scratch[0]) < size:
            self._scratch = (np.zeros(size), np.zeros(size, dtype=np.int64), np.zeros(size, dtype=np.int64))
            self._token = 0
        return self._scratch

    def _pass_scratch(self, w_max: int) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
        """Memory for ``dense_pass``'s reservation table and changed entries, kept between passes."""
        stride = self._nx_p * self._ny_p
        if self._near_scratch is None or len(self._near_scratch) < w_max:
            self._near_scratch = np.empty((w_max, stride), dtype=np.int64)
            self._dirty_scratch = np.empty(w_max * stride, dtype=np.bool_)
        return self._near_scratch, self._dirty_scratch

    def _static_allow_of(
        self, statics: Sequence[NDArray[np.float64]], segments: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]]
    ) -> NDArray[np.int64]:
        """``_static_allow(overrides)`` for the overrides ``_static_overrides(statics, segments)``
        would build, folded directly from the memoised removed moves of each body (arrays)."""
        segs = [(np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)) for p, q in segments]
        segs += [(np.asarray(p, dtype=np.float64), np.asarray(p, dtype=np.float64)) for p in statics]
        if not segs:
            return self._all_allowed
        parts = [self._removed_bits(p, q) for p, q in segs]
        cids = np.concatenate([c for c, _ in parts])
        bits = np.concatenate([b for _, b in parts])
        removed = np.zeros(len(self._all_allowed), dtype=np.int64)
        np.bitwise_or.at(removed, cids, bits)
        out = self._all_allowed.copy()
        touched = np.unique(cids)
        out[touched] = self._cell_bits[touched] & ~removed[touched]
        return out

    def _removed_bits(self, p: NDArray[np.float64], q: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """``_removed_moves(p, q)`` as (cell ids, bit mask of the removed moves per cell), memoised."""
        key = (p.tobytes(), q.tobytes())
        hit = self._removed_bits_memo.get(key)
        if hit is None:
            per = self._removed_moves(p, q)
            cids = np.fromiter(per, dtype=np.int64, count=len(per))
            bits = np.array([sum(1 << (self._nbrs[cid][k][4] + 6) for k in ks) for cid, ks in per.items()],
                            dtype=np.int64).reshape(-1)
            if len(self._removed_bits_memo) > 4096:
                self._removed_bits_memo.clear()
            hit = self._removed_bits_memo[key] = (cids, bits)
        return hit

    def _static_allow(self, overrides: Mapping[int, list[_Move]]) -> NDArray[np.int64]:
        """Per padded cell, the bit mask of the moves left by ``overrides`` (all elsewhere)."""
        if not overrides:
            return self._all_allowed
        out = self._all_allowed.copy()
        for cid, lst in overrides.items():
            mask = 0
            for nb in lst:
                mask |= nb[2]
            out[cid] = mask
        return out

    def _near_masks(self, a: int, vel: int) -> list[tuple[int, int]]:
        """(cell, mask) for the cells near an agent leaving cell id ``a`` with velocity code
        ``vel``, skipping cells where it allows every move (memoised)."""
        key = a * 25 + vel
        out = self._near_mask_memo.get(key)
        if out is None:
            full, mask_of = self._full_mask, self._mask_of
            out = [(cell, m) for cell, base in self._near_cells[a] if (m := mask_of[base + vel]) != full]
            self._near_mask_memo[key] = out
        return out

    # ----- heuristic -----------------------------------------------------------------------------
    def heuristic(self, goal: Cell) -> list[float]:
        """Exact static distances (cells) to ``goal`` indexed by padded cell id (inf: unreachable)."""
        gid = self.cell_id(goal)
        h = self._heuristics.get(gid)
        if h is None:  # the list view (pure-Python code) of the cached array, made on first use
            h = self._heuristic_array(goal).tolist()
            self._heuristics[gid] = h
        return h

    def _heuristic_array(self, goal: Cell) -> NDArray[np.float64]:
        """``heuristic(goal)`` as a float array (the compiled search's view): a row of the
        goal-distance cache (``_heuristic_row``). The row is this goal's until the cache evicts
        it: read it before asking for other goals' distances, or copy it."""
        table_row: NDArray[np.float64] = self._h_table_row(self._heuristic_row(self.cell_id(goal)))
        return table_row

    def _h_table_row(self, row: int) -> NDArray[np.float64]:
        assert self._h_table is not None
        out: NDArray[np.float64] = self._h_table[row]
        return out

    def _heuristic_row(self, gid: int) -> int:
        """The row of ``_h_table`` holding the distances to goal id ``gid``: ``goal_distances``
        on the move table, the floats ``scipy.sparse.csgraph.dijkstra`` gives on the same graph
        (``tests/test_astar_kernel.py``), computed on first use and cached.

        The cache holds at least 512 goals and as many more as fit in about 256 MB (a crowd
        of N walkers has up to N goals; a goal evicted while still in use costs a Dijkstra
        over the grid per replan); the oldest goal goes first, except that a row read in the
        current pass (``_h_epoch``) is never evicted (the table grows instead), so a pass can
        look up all its rows before it runs. The table is allocated at its full size on first
        use (memory pages are only taken as rows are written)."""
        row = self._h_rows.get(gid)
        if row is None:
            row = self._free_heuristic_row()
            if self._ring is None:
                self._ring = np.zeros((3, self._nb_id.shape[0] * self._nb_id.shape[1] + 1), dtype=np.int64)
            assert self._h_table is not None
            self._h_table[row] = goal_distances(gid, self._nb_id, self._nb_cost, self._ring)
            self._h_rows[gid] = row
        self._h_pinned[row] = self._h_epoch
        return row

    def _free_heuristic_row(self) -> int:
        """A row for a new goal: an unused one, else the oldest goal's (dropped from the cache)
        that the current pass has not read, else a new one (the table grows)."""
        n = self._nb_id.shape[0]
        if self._h_table is None:
            self._h_table = np.empty((self._h_capacity, n))
            self._h_pinned = np.full(self._h_capacity, -1, dtype=np.int64)
        used = len(self._h_rows)  # rows 0 .. used - 1 hold goals
        if used < self._h_capacity:
            return used
        for gid, row in self._h_rows.items():
            if self._h_pinned[row] != self._h_epoch:
                del self._h_rows[gid]
                self._heuristics.pop(gid, None)
                return row
        if used == len(self._h_table):  # every cached goal is read by this pass: rare
            grow = max(16, len(self._h_table) // 4)
            self._h_table = np.concatenate([self._h_table, np.empty((grow, n))])
            self._h_pinned = np.concatenate([self._h_pinned, np.full(grow, -1, dtype=np.int64)])
        return used

    def detour_distances(self, goal: Cell, static_allow: NDArray[np.int64]) -> NDArray[np.float64]:
        """Distances (cells) to ``goal`` per padded cell id along the moves ``static_allow``
        leaves (the moves stationary bodies do not block; inf: no such path). Memoised per goal
        and ``static_allow``."""
        return self._detour_field(self.cell_id(goal), self._detour_graph(static_allow))

    def _detour_graph(self, static_allow: NDArray[np.int64]) -> tuple[bytes, NDArray[np.float64]]:
        """(digest of ``static_allow``, the move costs ``goal_distances`` walks for it: inf for
        the moves it blocks). One per planning call, shared by its detour walkers (the digest
        and the costs take about as long as a Dijkstra each on a large grid); the last one is kept."""
        digest = hashlib.blake2b(static_allow.tobytes(), digest_size=16).digest()
        hit = self._detour_graph_memo
        if hit is None or hit[0] != digest:
            # Dijkstra from the goal: the entry u -> v stands for the walker's move v -> u
            into = np.where(self._nb_id >= 0, self._nb_id, 0)
            ok = (static_allow[into] & self._nb_rev_bit) != 0
            hit = self._detour_graph_memo = (digest, np.where(ok, self._nb_cost, np.inf))
        return hit

    def _detour_field(self, gid: int, graph: tuple[bytes, NDArray[np.float64]]) -> NDArray[np.float64]:
        """``detour_distances`` to goal id ``gid`` on ``graph`` (``_detour_graph``), memoised."""
        key = (gid, graph[0])
        hit = self._detour_memo.get(key)
        if hit is None:
            if self._ring is None:
                self._ring = np.zeros((3, self._nb_id.shape[0] * self._nb_id.shape[1] + 1), dtype=np.int64)
            if len(self._detour_memo) >= 256:
                self._detour_memo.clear()
            hit = goal_distances(gid, self._nb_id, graph[1], self._ring)
            hit.flags.writeable = False  # shared by the memo, the pass stacks and callers
            self._detour_memo[key] = hit
        return hit

    def distance(self, start: Cell, goal: Cell) -> float:
        """Shortest static path length from ``start`` to ``goal`` in metres (inf: unreachable)."""
        return float(self._heuristic_array(goal)[self.cell_id(start)]) * self.grid.cell_size

    # ----- static obstacles ------------------------------------------------------------------------
    def _static_overrides(
        self, statics: Sequence[NDArray[np.float64]], segments: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]] = ()
    ) -> dict[int, list[_Neighbour]]:
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
        nbrs = self._nbrs
        return {cid: [nb for k, nb in enumerate(nbrs[cid]) if k not in ks] for cid, ks in removed.items()}

    def _removed_moves(self, p: NDArray[np.float64], q: NDArray[np.float64]) -> dict[int, frozenset[int]]:
        """For one static point / segment (p, q): cell id -> indices into ``_nbrs[cell]`` of the
        moves that break the clearance rule against it (memoised per exact (p, q)).

        Only cells within ``reach`` of the segment can lose a move; the test per move is the one
        of ``_static_overrides`` (closest approach >= ``min(2r, distance at the move's start)``).
        """
        key = (p.tobytes(), q.tobytes())
        hit = self._removed_memo.get(key)
        if hit is not None:
            return hit
        g = self.grid
        cs = g.cell_size
        reach_m = self.min_distance + 2.0 * cs
        rr = int(math.ceil(reach_m / cs)) + 1
        (i0, j0), (i1, j1) = g.cell_of(p), g.cell_of(q)
        cand = sorted(
            self.cell_id((i, j))
            for i in range(min(i0, i1) - rr, max(i0, i1) + rr + 1)
            for j in range(min(j0, j1) - rr, max(j0, j1) + rr + 1)
            if g.is_free(i, j)
        )
        out: dict[int, frozenset[int]] = {}
        if cand:
            centres = np.array([g.center_of(*self.id_cell(cid)) for cid in cand])
            start = segment_distance(centres, centres, np.broadcast_to(p, centres.shape), np.broadcast_to(q, centres.shape))
            limit = np.minimum(self.min_distance, start) - 1e-7
            row_cell, row_k, dxy = [], [], []
            for r, cid in enumerate(cand):
                for k, nb in enumerate(self._nbrs[cid]):
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

    # ----- planning ------------------------------------------------------------------------------------
    def plan(
        self,
        starts: Mapping[Agent, Cell],
        goals: Mapping[Agent, Cell | None],
        static_obstacles: Sequence[NDArray[np.float64] | tuple[float, float]] = (),
        t0: int = 0,
        order: Sequence[Agent] | None = None,
        static_segments: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]] = (),
        hints: Mapping[Agent, tuple[Sequence[Cell], Cell]] | None = None,
        detour: Collection[Agent] = (),
    ) -> PlanResult:
        """Plan ``window`` steps for every agent in ``starts``.

        ``goals[a]`` None (or missing) means "stay": the agent keeps its cell unless it must
        make way. ``static_obstacles``: xy centres of stationary characters (metres).
        ``order``: priority order (first plans first); default is a permutation seeded by
        ``seed`` and ``t0``. ``static_segments``: (p, q) pairs in metres, bodies sweeping that
        segment (off-grid legs; see ``_static_overrides``). Every agent's wait is reserved for
        the committed steps, so no plan steps into a body that has not planned yet; the
        fallback pass re-plans with the failed agents first and a doubled window for them.

        ``hints[a] = (path, goal)``: the rest of ``a``'s previous plan (starting on its start
        cell) made for the same used goal. In the plain passes such a path is kept instead of
        searching when every step of it still passes this call's checks (reservations of the
        agents planned before, static obstacles); it is extended to the full window greedily
        along the static distance. A kept path is feasible, so the clearance guarantee is the
        same; it may be longer than a new search would find, which is why callers give hints
        only every other replan (``CrowdNavigator``).

        ``detour``: agents whose search is guided by the distance around the stationary bodies
        (``detour_distances``) instead of the static distance, when that distance is finite;
        they keep no hint. ``PlanResult.detour`` gives their remaining distance.
        """
        agents = list(starts)
        self._h_epoch += 1  # goal distances read by an earlier call may be evicted (see _heuristic_row)
        for a in agents:
            s = starts[a]
            if not self.grid.is_free(*s):
                raise PlanningError(f"agent {a!r} starts in cell {s}, which is blocked or outside the grid")
        if order is None:
            rng = np.random.default_rng([self.seed, int(t0)])
            order = [agents[k] for k in rng.permutation(len(agents))]
        else:
            missing = set(agents) - set(order)
            order = [a for a in order if a in starts] + [a for a in agents if a in missing]
        statics = [np.asarray(p, dtype=np.float64) for p in static_obstacles]
        overrides: dict[int, list[_Move]] = {}
        if self.backend == "numba":  # the compiled passes read the moves left as one mask per cell
            static_allow = self._static_allow_of(statics, static_segments)
        else:
            kept = self._static_overrides(statics, static_segments)
            overrides = {cid: [(nb[0], nb[1], 1 << (nb[4] + 6)) for nb in lst] for cid, lst in kept.items()}
            static_allow = self._static_allow(overrides)
        used_goals = self._usable_goals(agents, starts, goals, static_allow)
        heuristics: dict[Agent, NDArray[np.float64]] = {}
        graph = self._detour_graph(static_allow) if any(a in starts for a in detour) else None
        for a in detour:
            if a in starts and graph is not None:
                h = self._detour_field(self.cell_id(used_goals[a]), graph)
                if h[self.cell_id(starts[a])] < math.inf:
                    heuristics[a] = h
        # Pass 1: plain WHCA*. An agent whose search fails was cornered by the first steps of
        # agents planned before it; its wait is then reserved for the committed steps and the
        # call planned again (lazy wait reservation: only agents that need it hold their
        # place, the others may still be pushed), up to ``repair_passes`` times. A pass is safe
        # when every failed agent had its wait reserved. Last resort: everyone's wait reserved,
        # failed agents first with a doubled window (always safe).
        usable = self._hint_ids({
            a: path for a, (path, goal) in (hints or {}).items()
            if (a in starts and a not in heuristics and path and tuple(path[0]) == tuple(starts[a])
                and tuple(goal) == tuple(used_goals[a]))
        })
        reserved: frozenset[Agent] = frozenset()
        result, record = self._run_pass(order, starts, used_goals, overrides, frozenset(), reserved, usable, static_allow,
                                        heuristics)
        fallback = set(result.failed)
        expansions = result.expansions
        for _ in range(self.repair_passes):
            if result.failed <= reserved:
                break
            # same order, hints and window as the pass before: agents whose search reads only
            # reservations that did not change take that pass's result (``_dense_pass``)
            before, reserved = reserved, reserved | result.failed
            result, record = self._run_pass(order, starts, used_goals, overrides, frozenset(), reserved, usable,
                                            static_allow, heuristics,
                                            previous=None if record is None else (record, before))
            fallback |= result.failed
            expansions += result.expansions
        if not result.failed <= reserved:
            order2 = failed_first(order, result.failed) if self.fallback else list(order)
            ext = result.failed if self.fallback else frozenset()
            result, record = self._run_pass(order2, starts, used_goals, overrides, ext, frozenset(order), {}, static_allow,
                                       heuristics)
            expansions += result.expansions
        self._extra_memo = None  # the passes of this call are done: do not hold its fields
        return PlanResult(
            paths=result.paths if record is None else self._record_paths(record),
            failed=result.failed,
            fallback=frozenset(fallback),
            goals=used_goals,
            expansions=expansions,
            reused=result.reused,
            detour={a: float(h[self.cell_id(starts[a])]) for a, h in heuristics.items()},
        )

    def _hint_ids(self, paths: Mapping[Agent, Sequence[Cell]]) -> dict[Agent, NDArray[np.int64]]:
        """The padded ids of each path's first window + 1 cells (all paths converted at once)."""
        if not paths:
            return {}
        w = self.window + 1
        lens = [min(len(p), w) for p in paths.values()]
        flat = np.array([c for p in paths.values() for c in p[:w]], dtype=np.int64).reshape(-1, 2)
        ids = (flat[:, 0] + self._pad) * self._ny_p + flat[:, 1] + self._pad
        return dict(zip(paths, np.split(ids, np.cumsum(lens)[:-1]), strict=True))

    def _usable_goals(self, agents: Sequence[Agent], starts: Mapping[Agent, Cell], goals: Mapping[Agent, Cell | None],
                      static_allow: NDArray[np.int64]) -> dict[Agent, Cell]:
        """``_usable_goal`` of every agent: the goals that are usable as they are are found with
        one look-up of the goal-distance table for all; the others go one by one."""
        out: list[Cell | None] = []
        check: list[tuple[int, Cell]] = []  # goals on free cells: usable when reachable and free to wait on
        free, (nx, ny) = self.grid.free, self.grid.shape
        for k, a in enumerate(agents):
            g = goals.get(a)
            if g is None:
                out.append(starts[a])
                continue
            out.append(None)
            if 0 <= g[0] < nx and 0 <= g[1] < ny and free[g[0], g[1]]:
                check.append((k, g))
        if check:
            cid = self.cell_id
            gids = [cid(g) for _, g in check]
            rows = [self._heuristic_row(g) for g in gids]
            assert self._h_table is not None
            reach = self._h_table[rows, [cid(starts[agents[k]]) for k, _ in check]] < math.inf
            ok = reach & ((static_allow[gids] & _WAIT_BIT) != 0)
            for (k, g), good in zip(check, ok.tolist(), strict=True):
                if good:
                    out[k] = g
        return {a: self._usable_goal(starts[a], goals.get(a), static_allow) if g is None else g
                for a, g in zip(agents, out, strict=True)}

    def _usable_goal(self, start: Cell, goal: Cell | None, static_allow: NDArray[np.int64]) -> Cell:
        """``goal`` when it is reachable from ``start`` and a body may wait on it (``static_allow``:
        the moves stationary bodies leave, per padded cell); else the nearest such cell."""
        if goal is None:
            return start
        if self.grid.is_free(*goal):
            h = self._heuristic_array(goal)
            if h[self.cell_id(start)] < math.inf and static_allow[self.cell_id(goal)] & _WAIT_BIT:
                return goal
        # Nearest cell (to the requested goal) that is reachable from the start and not taken.
        cells, centers, ids = self._component_cells(int(self.grid.component[start]))
        order = np.argsort(np.sum((centers - self.grid.center_of(*goal)) ** 2, axis=1), kind="stable")
        waits = np.flatnonzero(static_allow[ids[order]] & _WAIT_BIT)
        if len(waits):
            k = order[waits[0]]
            return (int(cells[k, 0]), int(cells[k, 1]))
        return start

    def _component_cells(self, comp: int) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]:
        """The cells of grid component ``comp`` (row-major), their centres and padded ids (memoised)."""
        hit = self._components.get(comp)
        if hit is None:
            cells = np.argwhere(self.grid.component == comp)
            ids = (cells[:, 0] + self._pad) * self._ny_p + cells[:, 1] + self._pad
            hit = self._components[comp] = (cells, self.grid.centers(cells), ids)
        return hit

    def _run_pass(
        self,
        order: Sequence[Agent],
        starts: Mapping[Agent, Cell],
        goals: Mapping[Agent, Cell],
        overrides: Mapping[int, list[_Move]],
        extended: frozenset[Agent],
        reserve_waits: frozenset[Agent],
        hints: Mapping[Agent, NDArray[np.int64]],
        static_allow: NDArray[np.int64],
        heuristics: Mapping[Agent, NDArray[np.float64]],
        previous: tuple[_PassRecord, frozenset[Agent]] | None = None,
    ) -> tuple[PlanResult, _PassRecord | None]:
        """One planning pass on this planner's backend; the dense pass also returns what each
        agent's search read (for the next repair pass, see ``_dense_pass``). ``heuristics``:
        per agent, the distances that replace its goal's static distance (see ``plan``)."""
        if self.backend == "numba":  # the cells of the paths: only for the last pass (see plan)
            return self._dense_pass(order, starts, goals, extended, reserve_waits, hints, static_allow, previous,
                                    heuristics, cells=False)
        lists = {a: np.asarray(h).tolist() for a, h in hints.items()}
        return self._pass(order, starts, goals, overrides, extended, reserve_waits, heuristics, lists), None

    def _pass(
        self,
        order: Sequence[Agent],
        starts: Mapping[Agent, Cell],
        goals: Mapping[Agent, Cell],
        overrides: Mapping[int, list[_Move]],
        extended: frozenset[Agent],
        reserve_waits: frozenset[Agent],
        heuristics: Mapping[Agent, NDArray[np.float64]],
        hints: Mapping[Agent, list[int]] | None = None,
    ) -> PlanResult:
        """One prioritized pass (pure-Python backend): every agent in ``order`` keeps its hint or
        searches against the reservations of those before it (and the reserved waits)."""
        w_max = self.window * (2 if extended else 1)
        res = _Reservations(w_max, self)
        waits = {a: [self.cell_id(starts[a])] * (self.commit_steps + 1) for a in order}
        for a in order:
            if a in reserve_waits:
                res.add(a, waits[a], self.commit_steps)
        paths: dict[Agent, list[Cell]] = {}
        failed: set[Agent] = set()
        reused: set[Agent] = set()
        total = 0
        for a in order:
            if a in reserve_waits:
                res.remove(a, waits[a], self.commit_steps)
            window = self.window * 2 if a in extended else self.window
            hint = hints.get(a) if hints and a not in extended else None
            ids = self._kept_path(hint, goals[a], window, res, overrides) if hint else None
            if ids is not None:
                reused.add(a)
            else:
                h = heuristics.get(a)
                ids, n = self._search(a, self.cell_id(starts[a]), goals[a], window, res, overrides,
                                      None if h is None else h.tolist())
                total += n
            if ids is None:  # wait: safe for the committed steps, which is all it claims
                failed.add(a)
                ids = waits[a]
            res.add(a, ids, len(res.near))
            paths[a] = self._cells_of(np.asarray(ids, dtype=np.int64))
        return PlanResult(paths=paths, failed=frozenset(failed), fallback=frozenset(), goals=dict(goals), expansions=total,
                          reused=frozenset(reused))

    def _cells_of(self, ids: NDArray[np.int64]) -> list[Cell]:
        """The cells of the first window + 1 padded ids."""
        nyp, pad = self._ny_p, self._pad
        return [(c // nyp - pad, c % nyp - pad) for c in ids[: self.window + 1].tolist()]

    def _dense_pass(
        self,
        order: Sequence[Agent],
        starts: Mapping[Agent, Cell],
        goals: Mapping[Agent, Cell],
        extended: frozenset[Agent],
        reserve_waits: frozenset[Agent],
        hints: Mapping[Agent, Sequence[int] | NDArray[np.int64]],
        static_allow: NDArray[np.int64],
        previous: tuple[_PassRecord, frozenset[Agent]] | None = None,
        heuristics: Mapping[Agent, NDArray[np.float64]] | None = None,
        cells: bool = True,
    ) -> tuple[PlanResult, _PassRecord]:
        """``_pass`` run by the compiled ``astar_kernel.dense_pass`` (same result), recording
        each agent's outcome. ``cells`` off: ``PlanResult.paths`` is left empty (the record
        has the paths; ``_record_paths`` turns them into cells).

        ``previous``: the record of the pass before (same hints and window) and the waits it
        reserved. A search (or kept-path check) is a function of the reservation entries it
        reads, so an agent whose previous reads all fall outside the entries that may differ
        between the two passes (near the newly reserved waits, and near every move that an
        agent planned earlier in this pass made differently) gets its previous outcome without
        searching. Conservative, hence exact: the same plans.
        """
        n = len(order)
        w_max = self.window * (2 if extended else 1)
        cid = self.cell_id
        self._h_epoch += 1  # the heuristic rows read below stay in the cache until the pass ran
        start_ids = np.fromiter((cid(starts[a]) for a in order), dtype=np.int64, count=n)
        goal_ids = np.fromiter((cid(goals[a]) for a in order), dtype=np.int64, count=n)
        h_kept = np.fromiter((self._heuristic_row(g) for g in goal_ids.tolist()), dtype=np.int64, count=n)
        h_search = h_kept.copy()
        extra: list[NDArray[np.float64]] = []  # the agents' own distances (``heuristics``), by -1 - row
        windows = np.full(n, self.window, dtype=np.int64)
        reserve = np.zeros(n, dtype=np.bool_)
        hint_arr = np.zeros((n, self.window + 1), dtype=np.int64)
        hint_len = np.zeros(n, dtype=np.int64)
        for k, a in enumerate(order):
            if a in reserve_waits:
                reserve[k] = True
            if a in extended:
                windows[k] = 2 * self.window
            else:
                hint = hints.get(a)
                if hint is not None and len(hint):
                    m = min(len(hint), self.window + 1)
                    hint_arr[k, :m] = hint[:m]
                    hint_len[k] = m
            h = heuristics.get(a) if heuristics else None
            if h is not None:
                extra.append(h)
                h_search[k] = -len(extra)
        h_extra = self._extra_stack(extra)
        if previous is not None:
            rec, before = previous
            row = {a: k for k, a in enumerate(rec.order)}
            prev_idx = np.fromiter((row.get(a, -1) for a in order), dtype=np.int64, count=n)
            prev_reserve = np.fromiter((a in before for a in order), dtype=np.bool_, count=n)
            prev: tuple[NDArray[Any], ...] = (rec.ids, rec.ids_len, rec.reads, rec.off, rec.expansions, rec.reused,
                                              rec.failed)
        else:
            prev_idx = np.full(n, -1, dtype=np.int64)
            prev_reserve = np.zeros(n, dtype=np.bool_)
            prev = _NO_RECORD
        g_best, stamp, parent = self._search_scratch(w_max)
        heap_f, heap_h, heap_k = self._open
        near, dirty = self._pass_scratch(w_max)
        p_ids, p_len, p_reads, p_off, p_exp, p_reused, p_failed = prev
        assert self._h_table is not None or n == 0
        table = self._h_table if self._h_table is not None else np.zeros((1, len(self._nb_id)))
        ids, ids_len, reads, off, exps, reused, failed, taken, self._token = dense_pass(
            start_ids, goal_ids, windows, reserve, hint_arr, hint_len, table, h_kept, h_search, h_extra,
            self._nb_id, self._nb_cost, self._nb_bit, static_allow, self._full_mask, self.max_expansions,
            self.commit_steps, w_max, self._ny_p, self._nbhd_off, self._nbhd_base, self._mask_arr, self._free_arr,
            self.reach - 1, g_best, stamp, parent, self._token, self._expanded, heap_f, heap_h, heap_k,
            prev_idx, prev_reserve, p_ids, p_len, p_reads, p_off, p_exp, p_reused, p_failed, near, dirty,
        )
        record = _PassRecord(tuple(order), ids, ids_len, reads, off, exps, reused, failed, taken)
        result = PlanResult(
            paths=self._record_paths(record) if cells else {},
            failed=frozenset(order[k] for k in np.flatnonzero(failed).tolist()), fallback=frozenset(),
            goals=dict(goals), expansions=int(exps.sum()),
            reused=frozenset(order[k] for k in np.flatnonzero(reused).tolist()),
        )
        return result, record

    def _extra_stack(self, extra: list[NDArray[np.float64]]) -> NDArray[np.float64]:
        """``extra`` stacked, one row per array (one zero row for none). The passes of one call
        read the same arrays (in the same order but for the fallback pass): the stack is kept
        for the call, with the arrays themselves (so that they compare by identity), and reused
        while the arrays are the same objects (read-only); ``plan`` drops it when it returns."""
        if not extra:
            return np.zeros((1, len(self._nb_id)))
        hit = self._extra_memo
        if hit is None or len(hit[0]) != len(extra) or any(x is not y for x, y in zip(hit[0], extra, strict=True)):
            hit = self._extra_memo = (list(extra), np.stack(extra))
        return hit[1]

    def _record_paths(self, record: _PassRecord) -> dict[Agent, list[Cell]]:
        """The cells of each path's first window + 1 ids in a pass record (``PlanResult.paths``)."""
        shown = record.ids[:, : self.window + 1]
        ci = (shown // self._ny_p - self._pad).tolist()
        cj = (shown % self._ny_p - self._pad).tolist()
        lens = np.minimum(record.ids_len, self.window + 1).tolist()
        return {a: list(zip(ci[k][: lens[k]], cj[k][: lens[k]], strict=True)) for k, a in enumerate(record.order)}

    def _kept_path(
        self, hint: list[int], goal: Cell, window: int, res: _Reservations | _DenseReservations,
        overrides: Mapping[int, list[_Move]],
    ) -> list[int] | None:
        """``hint`` (padded ids from the start) checked step by step against ``res`` and the
        static obstacles, then extended to ``window`` steps, each extra step the allowed move
        with the least (cost + static distance, distance, cell id); None when a step fails."""
        h = self.heuristic(goal)
        gid = self.cell_id(goal)
        nbrs = self._snbrs
        path = hint[: window + 1]
        for t in range(len(path) - 1):
            cid, nid = path[t], path[t + 1]
            moves = overrides.get(cid)
            if moves is None:
                moves = nbrs[cid]
            allow = res.allow(t, cid)
            if not any(m[0] == nid and allow & m[2] for m in moves) or h[nid] == math.inf:
                return None
        path = list(path)
        while len(path) < window + 1:
            t = len(path) - 1
            cid = path[-1]
            moves = overrides.get(cid)
            if moves is None:
                moves = nbrs[cid]
            allow = res.allow(t, cid)
            best = None
            for nid, cost, bit in moves:
                if not allow & bit or h[nid] == math.inf:
                    continue
                key = ((0.0 if (cid == gid and nid == cid) else cost) + h[nid], h[nid], nid)
                if best is None or key < best:
                    best = key
            if best is None:
                return None
            path.append(best[2])
        return path

    def _search(
        self,
        agent: Agent,
        start: int,
        goal: Cell,
        window: int,
        res: _Reservations,
        overrides: Mapping[int, list[_Move]],
        h: list[float] | None = None,
    ) -> tuple[list[int] | None, int]:
        """Space-time A* from ``start`` for ``window`` steps; returns padded ids (window + 1) or None.
        ``h``: distances to use instead of the goal's static distance."""
        if h is None:
            h = self.heuristic(goal)
        gid = self.cell_id(goal)
        nbrs = self._snbrs
        full = self._full_mask
        near = res.near
        n_steps = len(near)
        stride = self._nx_p * self._ny_p
        max_exp = self.max_expansions
        inf = math.inf
        heappop, heappush = heapq.heappop, heapq.heappush
        h0 = h[start]
        heap: list[tuple[float, float, int, int]] = [(h0, h0, 0, start)]
        g_best: dict[int, float] = {start: 0.0}  # key: t * stride + cell id
        parent: dict[int, int] = {}
        expansions = 0
        while heap:
            f, hc, t, cid = heappop(heap)
            key = t * stride + cid
            g = f - hc
            if g > g_best.get(key, inf) + 1e-9:
                continue
            if t == window:
                path = [cid]
                while key in parent:
                    prev = parent[key]
                    t -= 1
                    key = t * stride + prev
                    path.append(prev)
                path.reverse()
                return path, expansions
            expansions += 1
            if expansions > max_exp:
                return None, expansions
            allow = near[t].get(cid, full) if t < n_steps else full
            moves = overrides.get(cid)
            if moves is None:
                moves = nbrs[cid]
            nt = t + 1
            nbase = nt * stride
            at_goal = cid == gid
            for nid, cost, bit in moves:
                if not allow & bit:
                    continue
                ng = g if (at_goal and nid == cid) else g + cost
                nkey = nbase + nid
                if ng < g_best.get(nkey, inf) - 1e-9:
                    hn = h[nid]
                    if hn == inf:
                        continue
                    g_best[nkey] = ng
                    parent[nkey] = cid
                    heappush(heap, (ng + hn, hn, nt, nid))
        return None, expansions


# ----- continuous positions and checks ------------------------------------------------------------
def _segment_min_norm(px: float, py: float, wx: float, wy: float) -> float:
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

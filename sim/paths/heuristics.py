"""The planner's heuristics: exact distances (cells) to a goal on the move tables, per padded
cell id (inf: unreachable), computed by the compiled Dijkstra :func:`goal_distances`.

Two kinds: the static distance to a goal (the moves of the grid), cached one row per goal in a
table the compiled passes read by row; and the *detour* distance (the moves some stationary
bodies leave, ``storyteller.sim.paths.static_bodies``), memoised per goal and set of bodies, which guides
walkers around a blockage the static distance leads into (``PathPlanner.plan(detour=...)``).

Deterministic: a cached row holds the same floats as a new computation; the cache only decides
how often a Dijkstra runs, never what a plan is (``tests/sim/paths/test_astar_kernel.py`` plans with a
tiny cache and a large one and compares).
"""

from __future__ import annotations

import hashlib

import numpy as np
from numba import njit
from numpy.typing import NDArray

from storyteller.sim.paths.move_tables import MoveTables

DetourGraph = tuple[bytes, NDArray[np.float64]]

_INF = np.inf


class GoalDistances:
    """The goal-distance cache and the detour distances of one planner's ``tables``.

    The cache holds at least 512 goals and as many more as fit in about 256 MB (a crowd of N
    walkers has up to N goals; a goal evicted while still in use costs a Dijkstra over the grid
    per replan); the oldest goal goes first, except that a row read in the current pass
    (``epoch``, advanced by ``next_epoch``) is never evicted (the table grows instead), so a
    pass can look up all its rows before it runs. The table is allocated at its full size on
    first use (memory pages are only taken as rows are written)."""

    def __init__(self, tables: MoveTables) -> None:
        self.tables = tables
        self._lists: dict[int, list[float]] = {}  # list views of some rows of ``table``
        # goal distances, one row per goal (see ``row``): the compiled pass reads them by row
        self.table: NDArray[np.float64] | None = None
        self.rows: dict[int, int] = {}  # goal id -> row, oldest first
        self._pinned: NDArray[np.int64] = np.zeros(0, dtype=np.int64)  # per row: the pass that last read it
        self.epoch = 0
        self.capacity = max(513, (256 << 20) // (8 * tables.nx_p * tables.ny_p))
        self._ring: NDArray[np.int64] | None = None  # goal_distances' bucket scratch, made on first use
        self._detour_memo: dict[tuple[int, bytes], NDArray[np.float64]] = {}  # see detour_field
        self._detour_graph_memo: DetourGraph | None = None  # see detour_graph

    def next_epoch(self) -> None:
        """Start a new pass: rows read before it may be evicted from now on."""
        self.epoch += 1

    def as_list(self, gid: int) -> list[float]:
        """``array(gid)`` as a list (the pure-Python backend's view), made on first use."""
        h = self._lists.get(gid)
        if h is None:
            h = self.array(gid).tolist()
            self._lists[gid] = h
        return h

    def array(self, gid: int) -> NDArray[np.float64]:
        """The static distances to goal id ``gid`` (the compiled search's view): a row of the
        goal-distance cache (``row``). The row is this goal's until the cache evicts it: read it
        before asking for other goals' distances, or copy it."""
        row = self.row(gid)
        assert self.table is not None
        out: NDArray[np.float64] = self.table[row]
        return out

    def row(self, gid: int) -> int:
        """The row of ``table`` holding the distances to goal id ``gid``: ``goal_distances`` on
        the move table, the floats ``scipy.sparse.csgraph.dijkstra`` gives on the same graph
        (``tests/sim/paths/test_astar_kernel.py``), computed on first use and cached."""
        row = self.rows.get(gid)
        if row is None:
            row = self._free_row()
            assert self.table is not None
            self.table[row] = goal_distances(gid, self.tables.nb_id, self.tables.nb_cost, self._scratch())
            self.rows[gid] = row
        self._pinned[row] = self.epoch
        return row

    def _scratch(self) -> NDArray[np.int64]:
        if self._ring is None:
            nb_id = self.tables.nb_id
            self._ring = np.zeros((3, nb_id.shape[0] * nb_id.shape[1] + 1), dtype=np.int64)
        return self._ring

    def _free_row(self) -> int:
        """A row for a new goal: an unused one, else the oldest goal's (dropped from the cache)
        that the current pass has not read, else a new one (the table grows)."""
        n = self.tables.nb_id.shape[0]
        if self.table is None:
            self.table = np.empty((self.capacity, n))
            self._pinned = np.full(self.capacity, -1, dtype=np.int64)
        used = len(self.rows)  # rows 0 .. used - 1 hold goals
        if used < self.capacity:
            return used
        for gid, row in self.rows.items():
            if self._pinned[row] != self.epoch:
                del self.rows[gid]
                self._lists.pop(gid, None)
                return row
        if used == len(self.table):  # every cached goal is read by this pass: rare
            grow = max(16, len(self.table) // 4)
            self.table = np.concatenate([self.table, np.empty((grow, n))])
            self._pinned = np.concatenate([self._pinned, np.full(grow, -1, dtype=np.int64)])
        return used

    def detour_graph(self, static_allow: NDArray[np.int64]) -> DetourGraph:
        """(digest of ``static_allow``, the move costs ``goal_distances`` walks for it: inf for
        the moves it blocks). One per planning call, shared by its detour walkers (the digest
        and the costs take about as long as a Dijkstra each on a large grid); the last one is kept."""
        digest = hashlib.blake2b(static_allow.tobytes(), digest_size=16).digest()
        hit = self._detour_graph_memo
        if hit is None or hit[0] != digest:
            tables = self.tables
            # Dijkstra from the goal: the entry u -> v stands for the walker's move v -> u
            into = np.where(tables.nb_id >= 0, tables.nb_id, 0)
            ok = (static_allow[into] & tables.nb_rev_bit) != 0
            hit = self._detour_graph_memo = (digest, np.where(ok, tables.nb_cost, np.inf))
        return hit

    def detour_field(self, gid: int, graph: DetourGraph) -> NDArray[np.float64]:
        """The distances to goal id ``gid`` along the moves of ``graph`` (``detour_graph``),
        memoised per goal and graph."""
        key = (gid, graph[0])
        hit = self._detour_memo.get(key)
        if hit is None:
            ring = self._scratch()
            if len(self._detour_memo) >= 256:
                self._detour_memo.clear()
            hit = goal_distances(gid, self.tables.nb_id, graph[1], ring)
            hit.flags.writeable = False  # shared by the memo, the pass stacks and callers
            self._detour_memo[key] = hit
        return hit


@njit(cache=True, nogil=True)
def goal_distances(goal: int, nb_id: NDArray[np.int64], nb_cost: NDArray[np.float64],
                   ring: NDArray[np.int64]) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """Shortest distances (cells) from padded cell ``goal`` along the moves of ``nb_id`` /
    ``nb_cost`` (the first column, the wait, is skipped), one per padded cell; inf where no
    path reaches. Every move costs 1 or sqrt(2).

    Dijkstra with a bucket queue of width 1: a cell enters bucket ``floor(d)`` (again when its
    distance improves; stale entries are skipped). A move adds 1 or sqrt(2), so a cell of
    bucket b lands in bucket b + 1 or b + 2: no cell of a bucket improves another of the same
    bucket, so all of them are final when it is reached and are scanned in any order (a
    label-setting Dijkstra: the same floats as any other). Three
    buckets are live at a time: ``ring`` (3, >= 8 * cells + 1) holds them, scratch."""
    n = nb_id.shape[0]
    cols = nb_id.shape[1]
    dist = np.full(n, _INF)
    done = np.zeros(n, dtype=np.bool_)
    size = np.zeros(3, dtype=np.int64)
    dist[goal] = 0.0
    ring[0, 0] = goal
    size[0] = 1
    b = 0
    while size[0] + size[1] + size[2] > 0:
        slot = b % 3
        for e in range(size[slot]):  # entries come from buckets b - 1, b - 2 only: fixed now
            u = ring[slot, e]
            if done[u]:
                continue
            done[u] = True
            d = dist[u]
            for m in range(1, cols):
                v = nb_id[u, m]
                if v < 0:
                    break
                nd = d + nb_cost[u, m]
                if nd < dist[v]:
                    dist[v] = nd
                    k = int(nd) % 3
                    ring[k, size[k]] = v
                    size[k] += 1
        size[slot] = 0
        b += 1
    return dist

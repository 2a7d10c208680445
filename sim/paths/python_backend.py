"""The planner's pure-Python backend (``PathPlanner(grid, backend="python")``): one prioritized
pass, the kept-path check and the space-time A* in plain Python over the list views of the move
tables. It takes the same decisions as the compiled pass ``astar_kernel.dense_pass`` (the
default backend), so it is the readable statement of the algorithm and the oracle the compiled
one is checked against (``tests/sim/paths/test_astar_kernel.py``); ``benchmark/bench_paths.py`` and
``benchmark/bench_world.py`` time the compiled search against it, which is why it is product
code and not test support.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.paths.move_tables import Move
from storyteller.sim.paths.passes import Passes
from storyteller.sim.paths.plan_types import Agent, Cell
from storyteller.sim.paths.reservations import Reservations


class PythonPasses(Passes):
    """Planning passes in pure Python (the settings: :class:`sim.paths.passes.Passes`)."""

    def run_pass(
        self,
        order: Sequence[Agent],
        starts: Mapping[Agent, Cell],
        goals: Mapping[Agent, Cell],
        overrides: Mapping[int, list[Move]],
        extended: frozenset[Agent],
        reserve_waits: frozenset[Agent],
        heuristics: Mapping[Agent, NDArray[np.float64]],
        hints: Mapping[Agent, list[int]] | None = None,
    ) -> tuple[dict[Agent, list[Cell]], set[Agent], set[Agent], int]:
        """One prioritized pass: every agent in ``order`` keeps its hint or searches against the
        reservations of those before it (and the reserved waits). Returns the paths, the agents
        whose search failed, those whose hint was kept, and the expansions."""
        cell_id = self.tables.cell_id
        w_max = self.window * (2 if extended else 1)
        res = Reservations(w_max, self.tables)
        waits = {a: [cell_id(starts[a])] * (self.commit_steps + 1) for a in order}
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
            ids = self.kept_path(hint, goals[a], window, res, overrides) if hint else None
            if ids is not None:
                reused.add(a)
            else:
                h = heuristics.get(a)
                ids, n = self.search(cell_id(starts[a]), goals[a], window, res, overrides,
                                     None if h is None else h.tolist())
                total += n
            if ids is None:  # wait: safe for the committed steps, which is all it claims
                failed.add(a)
                ids = waits[a]
            res.add(a, ids, len(res.near))
            paths[a] = self._cells_of(np.asarray(ids, dtype=np.int64))
        return paths, failed, reused, total

    def _cells_of(self, ids: NDArray[np.int64]) -> list[Cell]:
        """The cells of the first window + 1 padded ids."""
        nyp, pad = self.tables.ny_p, self.tables.pad
        return [(c // nyp - pad, c % nyp - pad) for c in ids[: self.window + 1].tolist()]

    def kept_path(
        self, hint: list[int], goal: Cell, window: int, res: Reservations, overrides: Mapping[int, list[Move]],
    ) -> list[int] | None:
        """``hint`` (padded ids from the start) checked step by step against ``res`` and the
        static obstacles, then extended to ``window`` steps, each extra step the allowed move
        with the least (cost + static distance, distance, cell id); None when a step fails."""
        gid = self.tables.cell_id(goal)
        h = self.distances.as_list(gid)
        nbrs = self.tables.snbrs
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

    def search(
        self,
        start: int,
        goal: Cell,
        window: int,
        res: Reservations,
        overrides: Mapping[int, list[Move]],
        h: list[float] | None = None,
    ) -> tuple[list[int] | None, int]:
        """Space-time A* from ``start`` for ``window`` steps; returns padded ids (window + 1) or None.
        ``h``: distances to use instead of the goal's static distance."""
        tables = self.tables
        gid = tables.cell_id(goal)
        if h is None:
            h = self.distances.as_list(gid)
        nbrs = tables.snbrs
        full = tables.full_mask
        near = res.near
        n_steps = len(near)
        stride = tables.nx_p * tables.ny_p
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

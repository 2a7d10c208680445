"""The planner's compiled backend (the default, ``PathPlanner(grid, backend="numba")``): one
prioritized pass over all agents is one call of ``astar_kernel.dense_pass`` on the move tables,
the goal-distance table and memory kept from call to call. It takes the same decisions as the
pure-Python pass (``storyteller.sim.paths.python_backend``; ``tests/sim/paths/test_astar_kernel.py`` compares them
plan for plan), and records what each agent's search read, so that a repair pass takes over
the outcome of every agent whose reads did not change.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.paths.astar_kernel import dense_pass
from storyteller.sim.paths.heuristics import GoalDistances
from storyteller.sim.paths.move_tables import MoveTables
from storyteller.sim.paths.passes import Passes
from storyteller.sim.paths.plan_types import Agent, Cell


@dataclass(frozen=True)
class PassRecord:
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
NO_RECORD: tuple[NDArray[Any], ...] = (
    np.zeros((1, 1), dtype=np.int64), np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64),
    np.zeros(2, dtype=np.int64), np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.bool_), np.zeros(1, dtype=np.bool_),
)


class _DenseScratch:
    """Memory the compiled pass reuses from call to call (only its sizes matter): the search's
    per-(step, cell) best costs, stamps and parents (``token``: the stamp of the last search),
    its expanded keys and heap, and the pass's reservation table and changed entries."""

    def __init__(self, tables: MoveTables, max_expansions: int) -> None:
        self.stride = tables.nx_p * tables.ny_p
        self.search: tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]] | None = None
        self.token = 0
        self.expanded = np.zeros(max(1, max_expansions), dtype=np.int64)  # the search's expanded keys
        open_size = tables.nb_id.shape[1] * max(1, max_expansions) + 1  # pushes: the start, then <= 9 per expansion
        self.open = (np.zeros(open_size), np.zeros(open_size), np.zeros(open_size, dtype=np.int64))  # the search's heap
        self.near: NDArray[np.int64] | None = None
        self.dirty = np.zeros(0, dtype=np.bool_)

    def search_arrays(self, window: int) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
        size = (window + 1) * self.stride
        if self.search is None or len(self.search[0]) < size:
            self.search = (np.zeros(size), np.zeros(size, dtype=np.int64), np.zeros(size, dtype=np.int64))
            self.token = 0
        return self.search

    def pass_arrays(self, w_max: int) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
        """Memory for ``dense_pass``'s reservation table and changed entries, kept between passes."""
        if self.near is None or len(self.near) < w_max:
            self.near = np.empty((w_max, self.stride), dtype=np.int64)
            self.dirty = np.empty(w_max * self.stride, dtype=np.bool_)
        return self.near, self.dirty


class CompiledPasses(Passes):
    """Planning passes by the compiled kernel (the settings: :class:`sim.paths.passes.Passes`)."""

    def __init__(self, tables: MoveTables, distances: GoalDistances, window: int, commit_steps: int,
                 max_expansions: int) -> None:
        super().__init__(tables, distances, window, commit_steps, max_expansions)
        self.reach = tables.reach
        self._scratch = _DenseScratch(tables, max_expansions)
        # the last stack of the agents' own distances a dense pass read, and the arrays stacked
        self._extra_memo: tuple[list[NDArray[np.float64]], NDArray[np.float64]] | None = None

    def end_call(self) -> None:
        """The passes of a planning call are done: do not hold its distance fields."""
        self._extra_memo = None

    def run_pass(
        self,
        order: Sequence[Agent],
        starts: Mapping[Agent, Cell],
        goals: Mapping[Agent, Cell],
        extended: frozenset[Agent],
        reserve_waits: frozenset[Agent],
        hints: Mapping[Agent, Sequence[int] | NDArray[np.int64]],
        static_allow: NDArray[np.int64],
        previous: tuple[PassRecord, frozenset[Agent]] | None = None,
        heuristics: Mapping[Agent, NDArray[np.float64]] | None = None,
    ) -> PassRecord:
        """The pass of ``PythonPasses.run_pass`` run by the compiled ``astar_kernel.dense_pass``
        (same decisions), recording each agent's outcome (``record_paths`` gives the cells).

        ``previous``: the record of the pass before (same hints and window) and the waits it
        reserved. A search (or kept-path check) is a function of the reservation entries it
        reads, so an agent whose previous reads all fall outside the entries that may differ
        between the two passes (near the newly reserved waits, and near every move that an
        agent planned earlier in this pass made differently) gets its previous outcome without
        searching. Conservative, hence exact: the same plans.
        """
        n = len(order)
        w_max = self.window * (2 if extended else 1)
        cid = self.tables.cell_id
        self.distances.next_epoch()  # the heuristic rows read below stay in the cache until the pass ran
        start_ids = np.fromiter((cid(starts[a]) for a in order), dtype=np.int64, count=n)
        goal_ids = np.fromiter((cid(goals[a]) for a in order), dtype=np.int64, count=n)
        h_kept = np.fromiter((self.distances.row(g) for g in goal_ids.tolist()), dtype=np.int64, count=n)
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
            prev = NO_RECORD
        sc, tb = self._scratch, self.tables
        g_best, stamp, parent = sc.search_arrays(w_max)
        heap_f, heap_h, heap_k = sc.open
        near, dirty = sc.pass_arrays(w_max)
        p_ids, p_len, p_reads, p_off, p_exp, p_reused, p_failed = prev
        table = self.distances.table
        assert table is not None or n == 0
        if table is None:
            table = np.zeros((1, len(tb.nb_id)))
        ids, ids_len, reads, off, exps, reused, failed, taken, sc.token = dense_pass(
            start_ids, goal_ids, windows, reserve, hint_arr, hint_len, table, h_kept, h_search, h_extra,
            tb.nb_id, tb.nb_cost, tb.nb_bit, static_allow, tb.full_mask, self.max_expansions,
            self.commit_steps, w_max, tb.ny_p, tb.nbhd_off, tb.nbhd_base, tb.mask_arr, tb.free_arr,
            self.reach - 1, g_best, stamp, parent, sc.token, sc.expanded, heap_f, heap_h, heap_k,
            prev_idx, prev_reserve, p_ids, p_len, p_reads, p_off, p_exp, p_reused, p_failed, near, dirty,
        )
        return PassRecord(tuple(order), ids, ids_len, reads, off, exps, reused, failed, taken)

    def _extra_stack(self, extra: list[NDArray[np.float64]]) -> NDArray[np.float64]:
        """``extra`` stacked, one row per array (one zero row for none). The passes of one call
        read the same arrays (in the same order but for the fallback pass): the stack is kept
        for the call, with the arrays themselves (so that they compare by identity), and reused
        while the arrays are the same objects (read-only); ``plan`` drops it when it returns."""
        if not extra:
            return np.zeros((1, len(self.tables.nb_id)))
        hit = self._extra_memo
        if hit is None or len(hit[0]) != len(extra) or any(x is not y for x, y in zip(hit[0], extra, strict=True)):
            hit = self._extra_memo = (list(extra), np.stack(extra))
        return hit[1]

    def record_paths(self, record: PassRecord) -> dict[Agent, list[Cell]]:
        """The cells of each path's first window + 1 ids in a pass record (``PlanResult.paths``)."""
        shown = record.ids[:, : self.window + 1]
        nyp, pad = self.tables.ny_p, self.tables.pad
        ci = (shown // nyp - pad).tolist()
        cj = (shown % nyp - pad).tolist()
        lens = np.minimum(record.ids_len, self.window + 1).tolist()
        return {a: list(zip(ci[k][: lens[k]], cj[k][: lens[k]], strict=True)) for k, a in enumerate(record.order)}


"""Compiled inner loops of the windowed cooperative A* (``storyteller.sim.paths.cooperative_astar``).

The planner keeps its rules in Python (priorities, repair passes, fallbacks, clearance
tables); these numba kernels run its hot loops on dense arrays:

- ``reserve_step`` / ``reserve_path``: fold one agent's move during one step (or the moves
  of a whole path) into the reservation masks of the cells near it (the per-cell bit masks of
  the moves that stay clear of it); ``release_step`` takes one agent's move out again,
  ``release_path`` all its moves (from the per-step table of reserved moves, one column per
  agent, that ``reserve_path`` fills);
- ``space_time_search``: the space-time A* of one agent over ``window`` steps;
- ``kept_path``: the check and greedy extension of a previous plan (``PythonPasses.kept_path`` in ``storyteller.sim.paths.python_backend``);
- ``dense_pass``: one prioritized planning pass over all agents with the kernels above (the
  numba backend's ``PathPlanner._dense_pass``: waits reserved up front, kept hints, searches,
  the repair pass's reuse of unchanged outcomes), so a pass costs one call, not several per agent.

They take the same decisions as the pure-Python code (same float operations, the same pop
order as its heap of ``(f, h, t, cell)`` tuples, the same tie-breaking), which
``tests/sim/paths/test_astar_kernel.py`` checks plan for plan. Indices are the planner's padded cell ids;
``stride`` is the number of padded cells. The kernels are compiled on first use and cached
on disk (``cache=True``), so only the first process on a machine pays the compile time.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = [
    "dense_pass", "kept_path", "release_path", "release_step", "reserve_path", "reserve_step", "space_time_search",
]

_INF = np.inf


@njit(cache=True, nogil=True)
def reserve_step(near_t: NDArray[np.int64], cell: int, vel: int, offsets: NDArray[np.int64],
                 bases: NDArray[np.int64], mask_of: NDArray[np.int64],
                 free: NDArray[np.bool_]) -> None:  # pragma: no cover - compiled
    """``near_t[c] &= mask_of[base + vel]`` for the free cells ``c = cell - offset`` around an
    agent leaving ``cell`` with velocity code ``vel`` (``offsets``/``bases``: the clearance
    neighbourhood, see ``PathPlanner._nbhd_bases``)."""
    for k in range(offsets.shape[0]):
        c = cell - offsets[k]
        if free[c]:
            near_t[c] &= mask_of[bases[k] + vel]


@njit(cache=True, nogil=True)
def release_step(near_t: NDArray[np.int64], cell: int, offsets: NDArray[np.int64],
                 free: NDArray[np.bool_], cells: NDArray[np.int64], vels: NDArray[np.int64],
                 nyp: int, reach: int, mask_of: NDArray[np.int64],
                 full: int) -> None:  # pragma: no cover
    """Undo one agent's reservation at ``cell`` during a step: the masks of the free cells
    around it are folded again from the agents still reserved in that step (``cells``,
    ``vels``; a negative cell is an empty slot), so only the neighbourhood of the released
    agent is recomputed."""
    side = 2 * reach + 1
    for k in range(offsets.shape[0]):
        c = cell - offsets[k]
        if not free[c]:
            continue
        ci, cj = c // nyp, c % nyp
        val = full
        for b in range(cells.shape[0]):
            if cells[b] < 0:
                continue
            di = cells[b] // nyp - ci
            dj = cells[b] % nyp - cj
            if -reach <= di <= reach and -reach <= dj <= reach:
                val &= mask_of[((di + reach) * side + (dj + reach)) * 25 + vels[b]]
        near_t[c] = val


@njit(cache=True, nogil=True)
def reserve_path(near: NDArray[np.int64], ids: NDArray[np.int64], steps: int, nyp: int,
                 offsets: NDArray[np.int64], bases: NDArray[np.int64], mask_of: NDArray[np.int64],
                 free: NDArray[np.bool_], cells: NDArray[np.int64], vels: NDArray[np.int64],
                 slot: int) -> None:  # pragma: no cover - compiled
    """Fold the first ``steps`` moves of a path (padded ids) into ``near`` (one row per step)
    and record each move in column ``slot`` of ``cells`` (the cell left) and ``vels`` (the
    velocity code ``(dx + 2) * 5 + (dy + 2)``), both (steps, agents)."""
    for t in range(steps):
        a = ids[t]
        d = ids[t + 1] - a
        dx = 0
        if abs(d) > 1:
            dx = int(np.round(d / nyp))
        dy = d - dx * nyp
        vel = (dx + 2) * 5 + (dy + 2)
        cells[t, slot] = a
        vels[t, slot] = vel
        reserve_step(near[t], a, vel, offsets, bases, mask_of, free)


@njit(cache=True, nogil=True)
def release_path(near: NDArray[np.int64], steps: int, slot: int, cells: NDArray[np.int64],
                 vels: NDArray[np.int64], offsets: NDArray[np.int64], free: NDArray[np.bool_],
                 nyp: int, reach: int, mask_of: NDArray[np.int64], full: int) -> None:  # pragma: no cover
    """Take the moves of column ``slot`` out of the first ``steps`` rows of ``near`` (steps
    where the slot holds no move are left alone) and empty the column."""
    for t in range(steps):
        gone = cells[t, slot]
        if gone < 0:
            continue
        cells[t, slot] = -1
        release_step(near[t], gone, offsets, free, cells[t], vels[t], nyp, reach, mask_of, full)


@njit(cache=True, nogil=True)
def kept_path(hint: NDArray[np.int64], goal: int, window: int, h: NDArray[np.float64],
              nb_id: NDArray[np.int64], nb_cost: NDArray[np.float64], nb_bit: NDArray[np.int64],
              static_allow: NDArray[np.int64], near: NDArray[np.int64],
              full: int) -> tuple[NDArray[np.int64], int, bool]:  # pragma: no cover - compiled
    """``hint`` (padded ids from the start) checked step by step against the reservations
    ``near`` and ``static_allow``, then extended to ``window`` steps, each extra step the
    allowed move with the least (cost + h, h, cell id), waiting on ``goal`` free. Returns
    ``(path, s, ok)``: ``ok`` when every step passed (then ``path`` holds the window + 1 ids,
    the result of ``PythonPasses.kept_path``; else that is None), and the number of steps
    ``s`` read: ``near`` is read at ``(t, path[t])`` for t < s only."""
    n_steps = near.shape[0]
    path = np.empty(window + 1, dtype=np.int64)
    m = min(hint.shape[0], window + 1)
    for t in range(m):
        path[t] = hint[t]
    for t in range(m - 1):
        cid = path[t]
        nid = path[t + 1]
        allow = (near[t, cid] if t < n_steps else full) & static_allow[cid]
        ok = False
        for k in range(nb_id.shape[1]):
            x = nb_id[cid, k]
            if x < 0:
                break
            if x == nid and (allow & nb_bit[cid, k]) != 0:
                ok = True
                break
        if not ok or h[nid] == _INF:
            return path, t + 1, False
    for t in range(m - 1, window):
        cid = path[t]
        allow = (near[t, cid] if t < n_steps else full) & static_allow[cid]
        best_f = _INF
        best_h = _INF
        best_id = -1
        for k in range(nb_id.shape[1]):
            nid = nb_id[cid, k]
            if nid < 0:
                break
            hn = h[nid]
            if (allow & nb_bit[cid, k]) == 0 or hn == _INF:
                continue
            f = (0.0 if (cid == goal and nid == cid) else nb_cost[cid, k]) + hn
            if best_id < 0 or f < best_f or (f == best_f and (hn < best_h or (hn == best_h and nid < best_id))):
                best_f, best_h, best_id = f, hn, nid
        if best_id < 0:
            return path, t + 1, False
        path[t + 1] = best_id
    return path, window, True


@njit(cache=True, nogil=True, inline="always")
def _before(f: float, h: float, k: int, f2: float, h2: float, k2: int) -> bool:  # pragma: no cover - compiled
    """(f, h, k) < (f2, h2, k2), lexicographically."""
    return f < f2 or (f == f2 and (h < h2 or (h == h2 and k < k2)))


@njit(cache=True, nogil=True, inline="always")
def _heap_push(hf: NDArray[np.float64], hh: NDArray[np.float64], hk: NDArray[np.int64], size: int,
               f: float, h: float, k: int) -> int:  # pragma: no cover - compiled
    """Add (f, h, k) to the binary min-heap held in the first ``size`` entries; the new size."""
    i = size
    while i > 0:
        p = (i - 1) >> 1
        if not _before(f, h, k, hf[p], hh[p], hk[p]):
            break
        hf[i], hh[i], hk[i] = hf[p], hh[p], hk[p]
        i = p
    hf[i], hh[i], hk[i] = f, h, k
    return size + 1


@njit(cache=True, nogil=True, inline="always")
def _heap_pop_into(hf: NDArray[np.float64], hh: NDArray[np.float64], hk: NDArray[np.int64],
                   size: int) -> None:  # pragma: no cover - compiled
    """Remove the root of a heap of ``size`` > 0 entries (the caller read it first)."""
    last = size - 1
    f, h, k = hf[last], hh[last], hk[last]
    i = 0
    while True:
        c = 2 * i + 1
        if c >= last:
            break
        if c + 1 < last and _before(hf[c + 1], hh[c + 1], hk[c + 1], hf[c], hh[c], hk[c]):
            c += 1
        if not _before(hf[c], hh[c], hk[c], f, h, k):
            break
        hf[i], hh[i], hk[i] = hf[c], hh[c], hk[c]
        i = c
    hf[i], hh[i], hk[i] = f, h, k


@njit(cache=True, nogil=True, inline="always")
def _window_path(parent: NDArray[np.int64], key: int, cid: int, window: int,
                 stride: int) -> NDArray[np.int64]:  # pragma: no cover - compiled
    """The padded ids of the window + 1 cells of the path that ends at node ``key`` (cell ``cid``
    at step ``window``), read back through ``parent``."""
    path = np.empty(window + 1, dtype=np.int64)
    path[window] = cid
    k = key
    for tt in range(window, 0, -1):
        prev = parent[k]
        path[tt - 1] = prev
        k = (tt - 1) * stride + prev
    return path


@njit(cache=True, nogil=True)
def space_time_search(
    start: int, goal: int, window: int, h: NDArray[np.float64], nb_id: NDArray[np.int64],
    nb_cost: NDArray[np.float64], nb_bit: NDArray[np.int64], static_allow: NDArray[np.int64],
    near: NDArray[np.int64], full: int, max_expansions: int,
    g_best: NDArray[np.float64], stamp: NDArray[np.int64], parent: NDArray[np.int64], token: int,
    expanded: NDArray[np.int64], heap_f: NDArray[np.float64], heap_h: NDArray[np.float64],
    heap_k: NDArray[np.int64],
) -> tuple[NDArray[np.int64], int]:  # pragma: no cover - compiled
    """Space-time A* from padded cell ``start`` for ``window`` steps.

    ``h``: static distance to the goal per cell (inf: unreachable). ``nb_id/nb_cost/nb_bit``
    (cells, 9): the moves of each cell (wait first; id -1 ends the row), their cost and move
    bit. ``static_allow`` (cells,): bit mask of the moves stationary bodies leave. ``near``
    (steps, cells): per step, the moves the reserved agents leave (steps beyond: all).
    ``g_best/stamp/parent``: scratch of size (window + 1) * cells, valid where
    ``stamp == token`` (so nothing is cleared between searches). ``expanded`` (>=
    ``max_expansions``): filled with the key ``t * cells + cell`` of each expanded node in
    order, the only entries of ``near`` the search reads (so a search whose expanded entries
    are unchanged in another table returns the same result there).
    ``heap_f/heap_h/heap_k`` (>= ``nb_id.shape[1] * max_expansions + 1``): the open list, a
    binary heap of (f, h, key) in parallel arrays. Nodes leave it in the order of the Python
    search's ``heapq`` of (f, h, t, cell) tuples: key = t * cells + cell orders as (t, cell),
    and no two entries are equal (a node is pushed again only with a smaller g), so any
    correct heap pops the same sequence.
    Returns (padded ids of the window + 1 cells, expansions), or (empty, expansions) when the
    budget runs out or no path exists. Waiting on the goal is free.
    """
    stride = nb_id.shape[0]
    n_steps = near.shape[0]
    cols = nb_id.shape[1]
    h0 = h[start]
    size = _heap_push(heap_f, heap_h, heap_k, 0, h0, h0, start)
    g_best[start] = 0.0
    stamp[start] = token
    expansions = 0
    while size > 0:
        f, hc, key = heap_f[0], heap_h[0], heap_k[0]
        _heap_pop_into(heap_f, heap_h, heap_k, size)
        size -= 1
        t = key // stride
        cid = key - t * stride
        g = f - hc
        best = g_best[key] if stamp[key] == token else _INF
        if g > best + 1e-9:
            continue
        if t == window:
            return _window_path(parent, key, cid, window, stride), expansions
        expansions += 1
        if expansions > max_expansions:
            return np.empty(0, dtype=np.int64), expansions
        expanded[expansions - 1] = key
        allow = near[t, cid] if t < n_steps else full
        allow &= static_allow[cid]
        nt = t + 1
        nbase = nt * stride
        at_goal = cid == goal
        for m in range(cols):
            nid = nb_id[cid, m]
            if nid < 0:
                break
            if (allow & nb_bit[cid, m]) == 0:
                continue
            ng = g if (at_goal and nid == cid) else g + nb_cost[cid, m]
            nkey = nbase + nid
            best = g_best[nkey] if stamp[nkey] == token else _INF
            if ng < best - 1e-9:
                hn = h[nid]
                if hn == _INF:
                    continue
                g_best[nkey] = ng
                stamp[nkey] = token
                parent[nkey] = cid
                size = _heap_push(heap_f, heap_h, heap_k, size, ng + hn, hn, nkey)
    return np.empty(0, dtype=np.int64), expansions


@njit(cache=True, nogil=True)
def _mark_moves(dirty: NDArray[np.bool_], ids: NDArray[np.int64], steps: int, stride: int,
                offsets: NDArray[np.int64]) -> None:  # pragma: no cover - compiled
    """Flag the reservation entries ``t * stride + cell`` near the first ``steps`` moves of ``ids``."""
    for t in range(min(steps, ids.shape[0] - 1)):
        base = t * stride + ids[t]
        for k in range(offsets.shape[0]):
            dirty[base - offsets[k]] = True


@njit(cache=True, nogil=True)
def _mark_changes(dirty: NDArray[np.bool_], old: NDArray[np.int64], new: NDArray[np.int64], w_max: int, stride: int,
                  offsets: NDArray[np.int64]) -> None:  # pragma: no cover - compiled
    """Flag the entries near the moves (within ``w_max`` steps) that differ between two
    reserved paths (both paths' cells: one reservation left, the other came)."""
    n_old, n_new = min(w_max, old.shape[0] - 1), min(w_max, new.shape[0] - 1)
    for t in range(max(n_old, n_new)):
        if t < n_old and t < n_new and old[t] == new[t] and old[t + 1] == new[t + 1]:
            continue
        if t < n_old:
            base = t * stride + old[t]
            for k in range(offsets.shape[0]):
                dirty[base - offsets[k]] = True
        if t < n_new:
            base = t * stride + new[t]
            for k in range(offsets.shape[0]):
                dirty[base - offsets[k]] = True


@njit(cache=True, nogil=True)
def _grown(buf: NDArray[np.int64], need: int) -> NDArray[np.int64]:  # pragma: no cover - compiled
    """``buf``, or a copy with room for at least ``need`` entries (doubling)."""
    if need <= buf.shape[0]:
        return buf
    out = np.empty(max(need, 2 * buf.shape[0]), dtype=np.int64)
    out[: buf.shape[0]] = buf
    return out


@njit(cache=True, nogil=True)
def dense_pass(
    starts: NDArray[np.int64], goals: NDArray[np.int64], windows: NDArray[np.int64], reserve: NDArray[np.bool_],
    hints: NDArray[np.int64], hint_len: NDArray[np.int64], h_table: NDArray[np.float64], h_kept: NDArray[np.int64],
    h_search: NDArray[np.int64], h_extra: NDArray[np.float64],
    nb_id: NDArray[np.int64], nb_cost: NDArray[np.float64], nb_bit: NDArray[np.int64], static_allow: NDArray[np.int64],
    full: int, max_expansions: int, commit: int, w_max: int,
    nyp: int, offsets: NDArray[np.int64], bases: NDArray[np.int64], mask_of: NDArray[np.int64], free: NDArray[np.bool_],
    reach: int,
    g_best: NDArray[np.float64], stamp: NDArray[np.int64], parent: NDArray[np.int64], token: int,
    expanded: NDArray[np.int64], heap_f: NDArray[np.float64], heap_h: NDArray[np.float64], heap_k: NDArray[np.int64],
    prev_idx: NDArray[np.int64], prev_reserve: NDArray[np.bool_], prev_ids: NDArray[np.int64], prev_len: NDArray[np.int64],
    prev_reads: NDArray[np.int64], prev_off: NDArray[np.int64], prev_exp: NDArray[np.int64], prev_reused: NDArray[np.bool_],
    prev_failed: NDArray[np.bool_], near_scratch: NDArray[np.int64], dirty_scratch: NDArray[np.bool_],
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64],
           NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_], int]:  # pragma: no cover - compiled
    """One prioritized pass of A agents, in priority order (row a: the a-th agent to plan).

    Per agent: padded start and goal ids, search ``windows``, ``reserve`` (its wait is
    reserved for the ``commit`` first steps until its turn), its hint (``hints[a, :hint_len[a]]``,
    none when 0) and heuristics: ``h_table[h_kept[a]]`` (the static distance to its goal, for the
    kept-path check) and the search's distances ``h_table[h_search[a]]``, or
    ``h_extra[-1 - h_search[a]]`` when negative. The reservation table has ``w_max`` steps; the
    other arguments are the planner's tables (see ``reserve_path``, ``release_path``,
    ``kept_path``, ``space_time_search``; ``token``: the last search token used).

    ``prev_*``: the outcomes of the pass before (same hints and windows), agent ``a``'s at row
    ``prev_idx[a]`` (-1: none; all -1 without a pass before), with that pass's reserved waits
    ``prev_reserve`` (in this pass's rows). An agent whose previous reads (entries of the
    reservation table) all lie outside the entries that may differ between the passes (near
    the waits reserved in one pass only, and near every move an agent planned before it made
    differently) takes its previous outcome without searching: the same plans.

    Returns per agent the reserved ids (``ids[a, :ids_len[a]]``: the path, or the wait of a
    failed search), the reservation entries read (``reads[off[a]:off[a + 1]]``), expansions,
    whether the hint was kept, whether the search failed, whether the previous outcome was
    taken; and the last search token used. ``near_scratch`` (>= ``w_max`` rows of ``stride``) and
    ``dirty_scratch`` (>= ``w_max * stride``): memory for the reservation table and the
    entries that changed since the pass before (overwritten)."""
    n_agents = starts.shape[0]
    stride = nb_id.shape[0]
    near = near_scratch[:w_max]
    near[:, :] = full
    cells = np.full((w_max, max(1, n_agents)), -1, dtype=np.int64)
    vels = np.zeros((w_max, max(1, n_agents)), dtype=np.int64)
    wait = np.empty(commit + 1, dtype=np.int64)
    wait_steps = min(commit, w_max)
    for a in range(n_agents):  # every reserved wait first (a agent's slot is its row)
        if reserve[a] and wait_steps > 0:
            wait[:] = starts[a]
            reserve_path(near, wait, wait_steps, nyp, offsets, bases, mask_of, free, cells, vels, a)
    use_prev = False
    for a in range(n_agents):
        if prev_idx[a] >= 0:
            use_prev = True
    dirty = dirty_scratch[: w_max * stride if use_prev else 0]
    dirty[:] = False
    if use_prev:
        for a in range(n_agents):
            if reserve[a] != prev_reserve[a]:
                wait[:] = starts[a]
                _mark_moves(dirty, wait, commit, stride, offsets)
    width = max(w_max, commit) + 1
    ids = np.zeros((n_agents, width), dtype=np.int64)
    ids_len = np.zeros(n_agents, dtype=np.int64)
    off = np.zeros(n_agents + 1, dtype=np.int64)
    exps = np.zeros(n_agents, dtype=np.int64)
    reused = np.zeros(n_agents, dtype=np.bool_)
    failed = np.zeros(n_agents, dtype=np.bool_)
    taken = np.zeros(n_agents, dtype=np.bool_)
    reads = np.empty(max(16, n_agents * (w_max + 1)), dtype=np.int64)
    size = 0
    for a in range(n_agents):
        if reserve[a] and wait_steps > 0:
            release_path(near, wait_steps, a, cells, vels, offsets, free, nyp, reach, mask_of, full)
        p = prev_idx[a]
        take = False
        if p >= 0:
            take = True
            for r in range(prev_off[p], prev_off[p + 1]):
                if dirty[prev_reads[r]]:
                    take = False
                    break
        if take:
            n = prev_len[p]
            ids[a, :n] = prev_ids[p, :n]
            ids_len[a] = n
            k0, k1 = prev_off[p], prev_off[p + 1]
            reads = _grown(reads, size + k1 - k0)
            reads[size: size + k1 - k0] = prev_reads[k0:k1]
            size += k1 - k0
            exps[a], reused[a], failed[a], taken[a] = prev_exp[p], prev_reused[p], prev_failed[p], True
        else:
            window = windows[a]
            kept = False
            if hint_len[a] > 0:
                path, steps, ok = kept_path(hints[a, : hint_len[a]], goals[a], window, h_table[h_kept[a]], nb_id,
                                            nb_cost, nb_bit, static_allow, near, full)
                reads = _grown(reads, size + steps)
                for t in range(steps):
                    reads[size + t] = t * stride + path[t]
                size += steps
                if ok:
                    kept = True
                    ids[a, : window + 1] = path
                    ids_len[a] = window + 1
                    reused[a] = True
            if not kept:
                h = h_table[h_search[a]] if h_search[a] >= 0 else h_extra[-1 - h_search[a]]
                token += 1
                path, n = space_time_search(starts[a], goals[a], window, h, nb_id, nb_cost, nb_bit, static_allow, near,
                                            full, max_expansions, g_best, stamp, parent, token, expanded,
                                            heap_f, heap_h, heap_k)
                m = min(n, max_expansions)
                reads = _grown(reads, size + m)
                reads[size: size + m] = expanded[:m]
                size += m
                exps[a] = n
                if path.shape[0] > 0:
                    ids[a, : path.shape[0]] = path
                    ids_len[a] = path.shape[0]
                else:  # wait: safe for the committed steps, which is all it claims
                    ids[a, : commit + 1] = starts[a]
                    ids_len[a] = commit + 1
                    failed[a] = True
            if p >= 0:
                _mark_changes(dirty, prev_ids[p, : prev_len[p]], ids[a, : ids_len[a]], w_max, stride, offsets)
        off[a + 1] = size
        steps = min(w_max, ids_len[a] - 1)
        if steps > 0:
            reserve_path(near, ids[a, : ids_len[a]], steps, nyp, offsets, bases, mask_of, free, cells, vels, a)
    return ids, ids_len, reads[:size].copy(), off, exps, reused, failed, taken, token

"""The compiled reservation folding (``astar_kernel.reserve_path`` / ``release_path``) wrapped
as a table with ``add`` / ``remove`` / ``allow``, to compare it entry for entry with the
pure-Python ``storyteller.sim.paths.reservations.Reservations`` (only the tests use it: the compiled pass
``astar_kernel.dense_pass`` folds its table itself)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.paths.astar_kernel import release_path, reserve_path
from storyteller.sim.paths.move_tables import MoveTables
from storyteller.sim.paths.plan_types import Agent


class DenseReservations:
    """The same reservations as ``Reservations`` on a dense (steps, cells) mask array, folded
    by the compiled ``reserve_path`` and ``release_path`` (the ``numba`` backend). The moves
    are kept per step in one column per agent (``cells``: the cell left, -1 for none;
    ``vels``: the velocity code), so that adding a path is one compiled call."""

    def __init__(self, n_steps: int, tables: MoveTables, agents: int = 16) -> None:
        self._tables = tables
        self.near = np.full((n_steps, tables.nx_p * tables.ny_p), tables.full_mask, dtype=np.int64)
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
        tb = self._tables
        steps = min(upto, len(ids) - 1, len(self.near))
        if steps <= 0:
            return
        arr = np.asarray(ids, dtype=np.int64)
        slot = self._slot(agent)  # first: it may grow (replace) the column arrays
        reserve_path(self.near, arr, steps, tb.ny_p, tb.nbhd_off, tb.nbhd_base, tb.mask_arr, tb.free_arr,
                     self.cells, self.vels, slot)

    def remove(self, agent: Agent, ids: Sequence[int] | NDArray[np.int64], upto: int) -> None:
        slot = self._slots.get(agent)
        steps = min(upto, len(ids) - 1, len(self.near))
        if slot is None or steps <= 0:
            return
        tb = self._tables
        release_path(self.near, steps, slot, self.cells, self.vels, tb.nbhd_off, tb.free_arr, tb.ny_p,
                     tb.reach - 1, tb.mask_arr, tb.full_mask)

    def allow(self, t: int, cid: int) -> int:
        return int(self.near[t, cid]) if t < len(self.near) else self._tables.full_mask

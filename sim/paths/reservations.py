"""The reservation table of a planning pass: per step t (relative to the plan start), for every
cell near an agent planned before, the moves those agents still allow there (the clearance
rule tabulated in ``storyteller.sim.paths.move_tables``), so that a search looks up one int per expansion.

``Reservations`` is the table as dicts (the pure-Python backend, ``storyteller.sim.paths.python_backend``);
the compiled pass (``astar_kernel.dense_pass``) folds the same table as a dense (steps, cells)
array with ``reserve_path`` / ``release_path``, equal entry for entry
(``tests/sim/paths/test_astar_kernel.py`` with ``tests/support/dense_reservations.py``). Removing an
agent gives exactly the table that never had it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.paths.move_tables import MoveTables
from storyteller.sim.paths.plan_types import Agent


class Reservations:
    """``near[t][cell]`` is a bit mask: bit ``m + 6`` is set when the move with code
    ``m = 5 * dx + dy`` from ``cell`` keeps clear of every agent reserved during step t (cells
    where every move is allowed are absent). ``moves[t]`` keeps each agent's (cell id,
    velocity code) at step t so that ``remove`` can rebuild the masks of a step.
    """

    def __init__(self, n_steps: int, tables: MoveTables) -> None:
        self.near: list[dict[int, int]] = [{} for _ in range(n_steps)]
        self.moves: list[dict[Agent, tuple[int, int]]] = [{} for _ in range(n_steps)]
        self._tables = tables

    def add(self, agent: Agent, ids: Sequence[int] | NDArray[np.int64], upto: int) -> None:
        nyp = self._tables.ny_p
        masks = self._tables.near_masks
        full = self._tables.full_mask
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
        masks = self._tables.near_masks
        full = self._tables.full_mask
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
        return self.near[t].get(cid, self._tables.full_mask) if t < len(self.near) else self._tables.full_mask

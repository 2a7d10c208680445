"""The goal a walker can use: the requested cell when it is reachable from the walker's start
and a body may wait on it (the stationary bodies leave it the wait move), else the nearest such
cell of the start's grid component (by distance to the requested goal, ties in row-major
order), else the start. ``PlanResult.goals`` reports the goal used.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.paths.heuristics import GoalDistances
from storyteller.sim.paths.move_tables import WAIT_BIT, MoveTables
from storyteller.sim.paths.nav_grid import NavGrid
from storyteller.sim.paths.plan_types import Agent, Cell


class UsableGoals:
    """Usable goals on ``grid`` (``tables``: its move tables; ``distances``: the static goal
    distances that say what is reachable)."""

    def __init__(self, grid: NavGrid, tables: MoveTables, distances: GoalDistances) -> None:
        self.grid = grid
        self.tables = tables
        self.distances = distances
        self._components: dict[int, tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]] = {}

    def usable_goals(self, agents: Sequence[Agent], starts: Mapping[Agent, Cell], goals: Mapping[Agent, Cell | None],
                      static_allow: NDArray[np.int64]) -> dict[Agent, Cell]:
        """``usable_goal`` of every agent: the goals that are usable as they are are found with
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
            cid = self.tables.cell_id
            gids = [cid(g) for _, g in check]
            rows = [self.distances.row(g) for g in gids]
            assert self.distances.table is not None
            reach = self.distances.table[rows, [cid(starts[agents[k]]) for k, _ in check]] < math.inf
            ok = reach & ((static_allow[gids] & WAIT_BIT) != 0)
            for (k, g), good in zip(check, ok.tolist(), strict=True):
                if good:
                    out[k] = g
        return {a: self.usable_goal(starts[a], goals.get(a), static_allow) if g is None else g
                for a, g in zip(agents, out, strict=True)}

    def usable_goal(self, start: Cell, goal: Cell | None, static_allow: NDArray[np.int64]) -> Cell:
        """``goal`` when it is reachable from ``start`` and a body may wait on it (``static_allow``:
        the moves stationary bodies leave, per padded cell); else the nearest such cell."""
        if goal is None:
            return start
        if self.grid.is_free(*goal):
            h = self.distances.array(self.tables.cell_id(goal))
            if h[self.tables.cell_id(start)] < math.inf and static_allow[self.tables.cell_id(goal)] & WAIT_BIT:
                return goal
        # Nearest cell (to the requested goal) that is reachable from the start and not taken.
        cells, centers, ids = self._component_cells(int(self.grid.component[start]))
        order = np.argsort(np.sum((centers - self.grid.center_of(*goal)) ** 2, axis=1), kind="stable")
        waits = np.flatnonzero(static_allow[ids[order]] & WAIT_BIT)
        if len(waits):
            k = order[waits[0]]
            return (int(cells[k, 0]), int(cells[k, 1]))
        return start

    def _component_cells(self, comp: int) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]:
        """The cells of grid component ``comp`` (row-major), their centres and padded ids (memoised)."""
        hit = self._components.get(comp)
        if hit is None:
            cells = np.argwhere(self.grid.component == comp)
            pad, nyp = self.tables.pad, self.tables.ny_p
            ids = (cells[:, 0] + pad) * nyp + cells[:, 1] + pad
            hit = self._components[comp] = (cells, self.grid.centers(cells), ids)
        return hit

"""The path planner's vocabulary, shared by its parts (``storyteller.sim.paths.cooperative_astar`` and the
modules it is built from): grid cells, agents, the backends and the planner's input error."""

from __future__ import annotations

from collections.abc import Hashable
from typing import Literal, get_args

Cell = tuple[int, int]
Agent = Hashable
Backend = Literal["numba", "python"]
BACKENDS: tuple[Backend, ...] = get_args(Backend)


class PlanningError(ValueError):
    """Bad planner input (unknown cell, blocked start...)."""

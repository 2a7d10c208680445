"""What both backends of the planner's passes hold (``storyteller.sim.paths.python_backend.PythonPasses``
and ``storyteller.sim.paths.compiled_backend.CompiledPasses``): the move tables, the static goal distances,
and the window, commit steps and expansion cap of ``PathPlanner``. The two take the same
decisions from the same settings; this is the one place those settings are kept."""

from __future__ import annotations

from storyteller.sim.paths.heuristics import GoalDistances
from storyteller.sim.paths.move_tables import MoveTables


class Passes:
    """Planning passes on ``tables`` with the static distances of ``distances``; ``window``,
    ``commit_steps`` and ``max_expansions`` as in ``PathPlanner``."""

    def __init__(self, tables: MoveTables, distances: GoalDistances, window: int, commit_steps: int,
                 max_expansions: int) -> None:
        self.tables = tables
        self.distances = distances
        self.window = window
        self.commit_steps = commit_steps
        self.max_expansions = max_expansions

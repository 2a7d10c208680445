"""The world's view of ``CrowdNavigator``: walkers, stationary bodies, arrivals, planned futures.

A thin wrapper with string agent names. It adds two things the navigator does not do itself:

- several stationary discs per character (a seated body spans the approach cell and the
  seat): extra keys ``(name, k)``, released together;
- ``can_freeze``: whether a walker may turn into a stationary body now. The plan made at this
  step boundary is conflict-free for its first (committed) step; a walker whose own plan
  waits during that step can stop for good without invalidating anybody's committed move
  (the next replan then sees it as an obstacle). A walker planned to move (for instance to
  make way for a passer-by) must not be frozen yet.

Positions are metres (xy).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sim.cooperative_astar import Cell, PathPlanner
from sim.nav_grid import NavGrid
from sim.path_following import CrowdNavigator


class WorldNavigator:
    """Thin wrapper over one ``CrowdNavigator``."""

    def __init__(self, grid: NavGrid, planner: PathPlanner, fps: int, seed: int) -> None:
        self.nav = CrowdNavigator(grid, planner=planner, fps=fps, seed=seed)
        self._arrivals_seen = 0
        self._extra: dict[str, int] = {}

    @property
    def grid(self) -> NavGrid:
        return self.nav.grid

    @property
    def planner(self) -> PathPlanner:
        return self.nav.planner

    @property
    def step_frames(self) -> int:
        return self.nav.step_frames

    def at_boundary(self) -> bool:
        """Whether the next ``tick`` starts a planning step (walkers may join only then)."""
        return self.nav.frame % self.nav.step_frames == 0

    # ----- membership ---------------------------------------------------------------------------
    def add_walker(self, name: str, cell: Cell, goal: Cell | None = None) -> None:
        self.release(name)
        self.nav.add_walker(name, cell, goal)

    def set_goal(self, name: str, goal: Cell | None) -> None:
        self.nav.set_goal(name, goal)

    def goal_of(self, name: str) -> Cell | None:
        return self.nav.goal_of(name)

    def make_stationary(self, name: str, points: Sequence[np.ndarray]) -> None:
        """``name`` stops walking; its body covers discs centred on ``points`` (>= 1)."""
        self.release(name)
        self.nav.set_stationary(name, np.asarray(points[0], dtype=float))
        for k, p in enumerate(points[1:], start=1):
            self.nav.set_stationary((name, k), np.asarray(p, dtype=float))
        self._extra[name] = len(points) - 1

    def release(self, name: str) -> None:
        """Forget ``name``'s stationary discs (no-op for walkers)."""
        self.nav.release(name)
        for k in range(1, self._extra.pop(name, 0) + 1):
            self.nav.release((name, k))

    def is_walker(self, name: str) -> bool:
        return self.nav.is_walker(name)

    def cell(self, name: str) -> Cell:
        return self.nav.cell(name)

    def can_freeze(self, name: str) -> bool:
        """Whether the walker's current plan keeps it in place for the committed step (call
        right after a boundary ``tick``)."""
        here = self.nav.position(name)
        there = self.nav.future(name, (self.nav.step_frames,))[0]
        return bool(np.allclose(here, there, atol=1e-9))

    # ----- time ----------------------------------------------------------------------------------
    def tick(self) -> dict[str, np.ndarray]:
        """Walker positions at this frame (then the navigator's clock advances)."""
        return self.nav.tick()  # type: ignore[return-value]

    def new_arrivals(self) -> list[str]:
        """Walkers that reached their goal cell since the last call, in order."""
        out = [a for _, a in self.nav.arrivals[self._arrivals_seen :]]
        self._arrivals_seen = len(self.nav.arrivals)
        return out  # type: ignore[return-value]

    def used_goal(self, name: str) -> Cell | None:
        """The goal the last plan actually used (the nearest free cell when the asked one was taken)."""
        res = self.nav.last_result
        return None if res is None else res.goals.get(name)

    def future(self, name: str, frames: Sequence[int]) -> np.ndarray:
        """Planned positions (len(frames), 2) ``frames`` after the last produced frame."""
        return self.nav.future(name, frames)

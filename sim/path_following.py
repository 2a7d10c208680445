"""Frame-by-frame following of cooperative plans: where every walking character is, each frame.

``CrowdNavigator`` owns the walkers of a scene. Each frame (``tick``) it returns every walker's
root position (xy, metres) on its planned path; at step boundaries it updates cells and
arrivals and, every ``commit_steps`` steps, replans everyone with ``PathPlanner.plan`` in the
order given by ``PriorityKeeper``. Stationary characters (idle, sitting, interacting) are
registered with ``set_stationary`` and are obstacles, never moved.

Because positions are exactly the planner's piecewise-linear paths, the planner's clearance
rule holds for these positions at every frame: walkers stay ``2 * body_radius`` apart and
bodies never touch a blocking footprint. Pure: the clock is the frame counter.
"""

from __future__ import annotations

from collections.abc import Hashable

import numpy as np

from sim.cooperative_astar import Cell, PathPlanner, PlanningError, PlanResult, position_at
from sim.nav_grid import NavGrid
from sim.path_fallback import PriorityKeeper

Agent = Hashable


class CrowdNavigator:
    """Walkers on a ``NavGrid`` at ``fps`` frames per second, planned by WHCA*."""

    def __init__(
        self,
        grid: NavGrid,
        planner: PathPlanner | None = None,
        fps: int = 30,
        seed: int = 0,
        stall_steps: int = 6,
    ) -> None:
        self.grid = grid
        self.planner = planner or PathPlanner(grid, seed=seed)
        self.fps = int(fps)
        step_frames = self.planner.step_time * self.fps
        if abs(step_frames - round(step_frames)) > 1e-6 or round(step_frames) < 1:
            raise PlanningError(
                f"step_time {self.planner.step_time} s is not a whole number of frames at {fps} fps"
            )
        self.step_frames = round(step_frames)
        self.keeper = PriorityKeeper(seed=seed, stall_steps=stall_steps)
        self.frame = 0
        self._cells: dict[Agent, Cell] = {}
        self._goals: dict[Agent, Cell | None] = {}
        self._paths: dict[Agent, list[Cell]] = {}
        self._plan_frame = 0
        self._static: dict[Agent, np.ndarray] = {}
        self.arrivals: list[tuple[int, Agent]] = []
        self.last_result: PlanResult | None = None
        self.replans = 0
        self.failures = 0  # agents left waiting because no safe plan was found
        self.fallbacks = 0  # agents whose plain WHCA* search failed (planned by the fallback)
        self._needs_plan = True

    # ----- membership -------------------------------------------------------------------------
    @property
    def walkers(self) -> list[Agent]:
        return list(self._cells)

    def add_walker(self, agent: Agent, cell: Cell, goal: Cell | None = None) -> None:
        """A walker standing on ``cell`` (must be free). Takes effect at once (call at a step boundary)."""
        if agent in self._cells or agent in self._static:
            raise PlanningError(f"agent {agent!r} is already registered")
        if not self.grid.is_free(*cell):
            raise PlanningError(f"cell {cell} is blocked or outside the grid")
        self._cells[agent] = (int(cell[0]), int(cell[1]))
        self._goals[agent] = goal
        self._paths[agent] = [self._cells[agent]]
        self._needs_plan = True

    def set_goal(self, agent: Agent, goal: Cell | None) -> None:
        """New goal cell (None: stay). Used from the next replan."""
        if agent not in self._cells:
            raise PlanningError(f"unknown walker {agent!r}")
        self._goals[agent] = None if goal is None else (int(goal[0]), int(goal[1]))
        self.keeper.reset(agent)
        self._needs_plan = True

    def goal_of(self, agent: Agent) -> Cell | None:
        return self._goals[agent]

    def set_stationary(self, agent: Agent, xy: np.ndarray | tuple[float, float]) -> None:
        """A character that does not walk (idle, sitting, interacting) at ``xy``: an obstacle."""
        self._cells.pop(agent, None)
        self._goals.pop(agent, None)
        self._paths.pop(agent, None)
        self._static[agent] = np.asarray(xy, dtype=float)
        self._needs_plan = True

    # ----- time ------------------------------------------------------------------------------------
    def tick(self) -> dict[Agent, np.ndarray]:
        """Walker positions (xy, metres) at the current frame; then the clock advances one frame."""
        if self.frame % self.step_frames == 0:
            self._step_boundary()
        t = (self.frame - self._plan_frame) / self.fps
        out = {
            a: position_at(self._paths[a], t, self.grid, self.planner.step_time) for a in self._cells
        }
        self.frame += 1
        return out

    def _step_boundary(self) -> None:
        k = (self.frame - self._plan_frame) // self.step_frames
        for a, path in self._paths.items():
            self._cells[a] = path[min(k, len(path) - 1)]
        for a in self._cells:
            goal = self._goals[a]
            if goal is not None and self._cells[a] == goal:
                self.arrivals.append((self.frame, a))
                self._goals[a] = None
                self.keeper.reset(a)
        if k > 0:
            dist = {
                a: self.planner.distance(self._cells[a], g) for a, g in self._goals.items() if g is not None
            }
            failed = self.last_result.failed if self.last_result is not None else frozenset()
            self.keeper.observe(dist, failed, steps=k)
        if k >= self.planner.commit_steps or k == 0 or self._needs_plan:
            self._replan()

    def _replan(self) -> None:
        walking = [a for a in self._cells if self._goals[a] is not None]
        arrived = [a for a in self._cells if self._goals[a] is None]
        order = self.keeper.order(walking, arrived)
        step = self.frame // self.step_frames
        result = self.planner.plan(
            dict(self._cells), dict(self._goals), list(self._static.values()), t0=step, order=order
        )
        self._paths = {a: list(p) for a, p in result.paths.items()}
        self._plan_frame = self.frame
        self.last_result = result
        self.replans += 1
        self.failures += len(result.failed)
        self.fallbacks += len(result.fallback)
        self._needs_plan = False

"""Frame-by-frame following of cooperative plans: where every walking character is, each frame.

``CrowdNavigator`` owns the walkers of a scene. Each frame (``tick``) it returns every walker's
root position (xy, metres); ``headings`` holds the direction of travel (radians, yaw about +z,
0 = +x; kept while standing). At step boundaries it updates cells and arrivals and, every
``commit_steps`` steps, replans everyone with ``PathPlanner.plan`` in the order given by
``PriorityKeeper``. Stationary characters (idle, sitting, interacting) are registered with
``set_stationary`` and are obstacles, never moved.

Exact off-grid points (``storyteller.sim.paths.off_grid``). A goal may carry ``final_xy`` (``set_goal(agent,
cell, final_xy=...)``): the walker ends with a straight *leg* from the cell centre to that point,
started only when every other body is ``2 * body_radius`` from the whole segment.

Detours. A walker that made no progress towards its goal for ``detour_after`` steps (default
``2 * stall_steps``, 3.6 s) is planned around the stationary bodies from then on (``PathPlanner.plan(detour=...)``)
until it arrives or gets a new goal: a member waiting on its exact target in a one-cell
corridor is an obstacle the static distance does not know, and without the detour the walker
behind it would wait for good. ``detour_distance`` gives its remaining distance on that route.

Because positions are exactly the planner's piecewise-linear paths plus these legs, the
clearance rule holds for these positions at every frame: walkers stay ``2 * body_radius``
apart (and their legs, while both move) and bodies never touch a blocking footprint. Pure:
the clock is the frame counter.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.paths.cooperative_astar import (
    Cell,
    PathPlanner,
    PlanningError,
    PlanResult,
    segment_distance,
)
from storyteller.sim.paths.fallback import PriorityKeeper
from storyteller.sim.paths.nav_grid import NavGrid
from storyteller.sim.paths.off_grid import Leg, target_problem
from storyteller.sim.paths.tracks import PlanTracks, gather_rows, is_movement

Agent = Hashable


class CrowdNavigator:
    """Walkers on a ``NavGrid`` at ``fps`` frames per second, planned by WHCA*.

    ``reuse_plans`` (default on): let a walker keep the rest of its previous plan, when it still
    passes every check of the new replan, instead of searching again, at most every other
    replan (about half the search work). It solves corridor swaps that ping-pong when every
    replan searches anew (the priorities flip as the pushed walker stalls), and in the 50-walker
    Office crowd more targets are reached (118 against 111 of 173, 107 against 82 with
    off-grid targets). Kept paths may hug furniture more closely; the world's leg IK keeps the
    feet out of it (``sim.body.foot_ik``).
    """

    def __init__(
        self,
        grid: NavGrid,
        planner: PathPlanner | None = None,
        fps: int = 30,
        seed: int = 0,
        stall_steps: int = 6,
        reuse_plans: bool = True,
        detour_after: int | None = None,
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
        self.speed = grid.cell_size / self.planner.step_time  # metres per second on a straight move
        self.keeper = PriorityKeeper(seed=seed, stall_steps=stall_steps)
        self.reuse_plans = bool(reuse_plans)
        self.detour_after = int(2 * stall_steps if detour_after is None else detour_after)
        self._detour: set[Agent] = set()  # walkers planned around the stationary bodies (see the module docstring)
        self.frame = 0
        self._cells: dict[Agent, Cell] = {}
        self._goals: dict[Agent, Cell | None] = {}
        self._paths: dict[Agent, list[Cell]] = {}
        # per-frame positions on every walker's path of _paths, rebuilt after each replan
        self._tracks = PlanTracks(grid.origin, grid.cell_size, self.step_frames, self.fps, self.planner.step_time)
        # (frame, offsets, agents, samples) of the last tick's look ahead (see tick, futures)
        self._ahead: tuple[int, tuple[int, ...], tuple[Agent, ...], NDArray[np.float64]] | None = None
        self._reorder: tuple[tuple[Agent, ...], tuple[Agent, ...], NDArray[np.int64] | None] | None = None  # see futures
        self._plan_frame = 0
        self._static: dict[Agent, NDArray[np.float64]] = {}
        self._final: dict[Agent, NDArray[np.float64]] = {}  # exact target of the current goal
        self._parked: dict[Agent, NDArray[np.float64]] = {}  # walkers standing off the grid, at this point
        self._legs: dict[Agent, Leg] = {}
        self.arrivals: list[tuple[int, Agent]] = []
        self.headings: dict[Agent, float] = {}
        self._last_xy: dict[Agent, NDArray[np.float64]] = {}
        self._last_agents: tuple[Agent, ...] = ()  # the agents of _last_xy, and their rows
        self._last_arr: NDArray[np.float64] = np.zeros((0, 2))
        self.last_result: PlanResult | None = None
        self.replans = 0
        self.failures = 0  # agents left waiting because no safe plan was found
        self.fallbacks = 0  # agents whose plain WHCA* search failed (planned by the fallback)
        self.leg_waits = 0  # step boundaries at which a leg could not start (a body too close)
        self._needs_plan = True

    # ----- membership -------------------------------------------------------------------------
    @property
    def walkers(self) -> list[Agent]:
        return list(self._cells)

    def add_walker(
        self,
        agent: Agent,
        cell: Cell,
        goal: Cell | None = None,
        start_xy: NDArray[np.float64] | tuple[float, float] | None = None,
        final_xy: NDArray[np.float64] | tuple[float, float] | None = None,
    ) -> None:
        """A walker standing on ``cell`` (must be free). Takes effect at once (call at a step boundary).

        ``start_xy``: the walker actually stands at this exact point (metres) off the grid; it
        first walks straight to ``cell``'s centre (the segment must be clear of furniture).
        ``final_xy``: exact target for ``goal`` (see ``set_goal``).
        """
        if agent in self._cells or agent in self._static:
            raise PlanningError(f"agent {agent!r} is already registered")
        cell = (int(cell[0]), int(cell[1]))
        if not self.grid.is_free(*cell):
            raise PlanningError(f"cell {cell} is blocked or outside the grid")
        start = None
        if start_xy is not None:
            start = np.asarray(start_xy, dtype=np.float64)
            why = self.target_problem(cell, start)
            if why is not None:
                raise PlanningError(f"agent {agent!r} cannot start at {tuple(start)}: {why}")
        if goal is not None and final_xy is not None:
            self._check_target(agent, goal, final_xy)
        self._cells[agent] = cell
        self._goals[agent] = None
        self._paths[agent] = [cell]
        self._tracks.clear()
        self._ahead = None
        if start is not None and float(np.linalg.norm(start - self.grid.center_of(*cell))) > 1e-9:
            self._parked[agent] = start
        self.set_goal(agent, goal, final_xy=final_xy)

    def set_goal(
        self, agent: Agent, goal: Cell | None, final_xy: NDArray[np.float64] | tuple[float, float] | None = None
    ) -> None:
        """New goal cell (None: stay). Used from the next replan.

        ``final_xy`` (metres): the exact point to end at. After reaching ``goal`` the walker
        walks straight from the cell centre to it; it is reported in ``arrivals`` once it stands
        there (``position`` gives the point). Raises ``PlanningError`` when a body cannot stand
        at ``final_xy`` or walk straight to it from ``goal`` (``NavGrid.entry_cell`` finds a
        good goal cell for a point). A walker parked off the grid first walks back to its cell.
        """
        if agent not in self._cells:
            raise PlanningError(f"unknown walker {agent!r}")
        if goal is not None and final_xy is not None:
            final = self._check_target(agent, goal, final_xy)
            self._final[agent] = final
        else:
            self._final.pop(agent, None)
        self._goals[agent] = None if goal is None else (int(goal[0]), int(goal[1]))
        self.keeper.reset(agent)
        self._detour.discard(agent)
        self._needs_plan = True

    def target_problem(self, goal: Cell, xy: NDArray[np.float64] | tuple[float, float]) -> str | None:
        """Why a body cannot end at ``xy`` coming straight from ``goal``'s centre (None: it can;
        ``storyteller.sim.paths.off_grid.target_problem``)."""
        return target_problem(self.grid, goal, xy)

    def _check_target(self, agent: Agent, goal: Cell, xy: NDArray[np.float64] | tuple[float, float]) -> NDArray[np.float64]:
        why = self.target_problem(goal, xy)
        if why is not None:
            raise PlanningError(f"agent {agent!r}: {why}")
        return np.asarray(xy, dtype=np.float64).copy()

    def goal_of(self, agent: Agent) -> Cell | None:
        return self._goals[agent]

    def final_of(self, agent: Agent) -> NDArray[np.float64] | None:
        """The exact target of the agent's current goal (None: the goal cell's centre)."""
        f = self._final.get(agent)
        return None if f is None else f.copy()

    def set_stationary(self, agent: Agent, xy: NDArray[np.float64] | tuple[float, float]) -> None:
        """A character that does not walk (idle, sitting, interacting) at ``xy``: an obstacle."""
        self._cells.pop(agent, None)
        self._goals.pop(agent, None)
        self._paths.pop(agent, None)
        self._tracks.forget(agent)  # the other rows stay valid
        self._ahead = None
        self._final.pop(agent, None)
        self._parked.pop(agent, None)
        self._legs.pop(agent, None)
        self._detour.discard(agent)
        self._static[agent] = np.asarray(xy, dtype=np.float64)
        self._needs_plan = True

    def release(self, agent: Agent) -> None:
        """Forget a stationary character (no-op for walkers and unknown agents)."""
        if self._static.pop(agent, None) is not None:
            self._needs_plan = True

    def is_walker(self, agent: Agent) -> bool:
        return agent in self._cells

    def crowded_by_still_bodies(self, cell: Cell) -> bool:
        """Whether a body standing still (stationary, or a walker parked on an exact point) is
        closer than the planner's minimum distance to ``cell``'s centre: no walker can end there
        until it leaves."""
        centre = self.grid.center_of(int(cell[0]), int(cell[1]))
        still = [*self._static.values(), *self._parked.values()]
        if not still:
            return False
        d = np.linalg.norm(np.asarray(still) - centre, axis=1)
        return bool(np.any(d < self.planner.min_distance - 1e-9))

    def cell(self, agent: Agent) -> Cell:
        """The walker's current cell (its entry cell while off the grid)."""
        return self._cells[agent]

    def detour_distance(self, agent: Agent) -> float | None:
        """Metres left to the walker's goal around the stationary bodies, when the last plan
        routed it so (see the module docstring); else None."""
        res = self.last_result
        d = None if res is None or agent not in self._detour else res.detour.get(agent)
        return None if d is None else d * self.grid.cell_size

    def is_off_grid(self, agent: Agent) -> bool:
        """Whether the walker stands at, or walks to or from, an exact point off its cell centre."""
        return agent in self._parked or agent in self._legs

    # ----- positions ---------------------------------------------------------------------------
    def _xy_at(self, agent: Agent, frame: int) -> NDArray[np.float64]:
        leg = self._legs.get(agent)
        if leg is not None:
            return leg.at(frame)
        parked = self._parked.get(agent)
        if parked is not None:
            return parked.copy()
        track = self._tracks.track(self._paths, agent)
        d = min(max(frame - self._plan_frame, 0), len(track) - 1)
        here: NDArray[np.float64] = track[d]
        return here.copy()

    def position(self, agent: Agent) -> NDArray[np.float64]:
        """Where the walker is at the last produced frame (before the first tick: now), metres."""
        return self._xy_at(agent, max(self.frame - 1, 0))

    def heading(self, agent: Agent) -> float:
        """Direction of travel at the last produced frame (radians about +z, 0 = +x)."""
        return self.headings.get(agent, 0.0)

    def future(self, agent: Agent, frames: Sequence[int]) -> NDArray[np.float64]:
        """Planned positions (len(frames), 2) ``frames`` after the last produced frame, metres.

        Follows the current plan (and leg); beyond it the walker stays where the plan ends."""
        base = self.frame - 1
        if agent not in self._legs and agent not in self._parked:
            track = self._tracks.track(self._paths, agent)
            off, last = base - self._plan_frame, len(track) - 1
            return track[[min(max(int(k) + off, 0), last) for k in frames]]
        return np.stack([self._xy_at(agent, base + int(k)) for k in frames])

    def futures(self, agents: Sequence[Agent], frames: Sequence[int]) -> NDArray[np.float64]:
        """``future`` of several walkers at once: (len(agents), len(frames), 2), metres."""
        if not agents:
            return np.zeros((0, len(frames), 2))
        hit = self._ahead
        if hit is not None and hit[0] == self.frame and hit[1] == tuple(int(k) for k in frames):
            ticked, samples = hit[2], hit[3]  # sampled by this frame's tick: the same floats
            key = tuple(agents)
            if key == ticked:
                return samples[:, 1:].copy()
            order = self._reorder
            if order is None or order[0] != ticked or order[1] != key:
                row = {a: i for i, a in enumerate(ticked)}
                idx = np.array([row[a] for a in key], dtype=np.int64) if all(a in row for a in key) else None
                order = self._reorder = (ticked, key, idx)
            if order[2] is not None:
                return samples[order[2], 1:]
        return self._sample(tuple(agents), self.frame - 1, frames)

    # ----- time ------------------------------------------------------------------------------------
    def tick(self, ahead: Sequence[int] = ()) -> dict[Agent, NDArray[np.float64]]:
        """Walker positions (xy, metres) at the current frame; then the clock advances one frame.

        ``ahead``: frame offsets at which to sample every walker's plan in the same pass, so
        that ``futures(agents, ahead)`` until the next change is read from that sample."""
        if self.frame % self.step_frames == 0:
            self._step_boundary()
        agents = tuple(self._cells)
        ahead = tuple(int(k) for k in ahead)
        samples = self._sample(agents, self.frame, (0, *ahead))  # (W, 1 + len(ahead), 2), fresh
        xy = samples[:, 0]
        out = dict(zip(agents, xy, strict=True))  # rows of the fresh sample
        headings = self.headings
        if agents == self._last_agents:  # the usual case: the same walkers as last frame
            for a, (d0, d1) in zip(agents, (xy - self._last_arr).tolist(), strict=True):
                dd = d0 * d0 + d1 * d1  # is_movement inlined for the clear cases
                if dd > 2e-12 or (dd >= 0.5e-12 and is_movement(d0, d1)):
                    headings[a] = math.atan2(d1, d0)
        else:
            for a, p in out.items():
                prev = self._last_xy.get(a)
                if prev is not None:
                    d = p - prev
                    if is_movement(float(d[0]), float(d[1])):
                        headings[a] = math.atan2(float(d[1]), float(d[0]))
                elif a not in headings:
                    headings[a] = 0.0
        self._last_xy, self._last_agents, self._last_arr = out, agents, xy
        self.frame += 1
        self._ahead = (self.frame, ahead, agents, samples) if ahead else None
        return out

    def _sample(self, agents: tuple[Agent, ...], frame: int, offsets: Sequence[int]) -> NDArray[np.float64]:
        """``_xy_at(a, frame + k)`` for every agent and offset, as one new array
        (len(agents), len(offsets), 2)."""
        if not agents or not offsets:
            return np.zeros((len(agents), len(offsets), 2))
        stack, starts = self._tracks.rows_of(self._paths, agents)
        out = gather_rows(stack, starts, frame - self._plan_frame, tuple(int(k) for k in offsets))
        if self._legs or self._parked:
            for i, a in enumerate(agents):
                if a in self._legs or a in self._parked:
                    out[i] = [self._xy_at(a, frame + int(k)) for k in offsets]
        return out

    def _step_boundary(self) -> None:
        k = (self.frame - self._plan_frame) // self.step_frames
        for a, path in self._paths.items():
            self._cells[a] = path[min(k, len(path) - 1)]
        self._finish_legs()
        for a in self._cells:
            goal = self._goals[a]
            if goal is not None and self._cells[a] == goal and a not in self._final and a not in self._parked:
                self.arrivals.append((self.frame, a))
                self._goals[a] = None
                self.keeper.reset(a)
                self._detour.discard(a)
        self._start_legs()
        if k > 0:
            dist = {
                a: self.planner.distance(self._cells[a], g)
                for a, g in self._goals.items()
                if g is not None and a not in self._legs and a not in self._parked
            }
            # Cornered agents (their plain WHCA* search failed) get a boost at once (PriorityKeeper).
            res = self.last_result
            failed = res.failed if res is not None else frozenset()
            repaired = res.fallback - res.failed if res is not None else frozenset()
            self.keeper.observe(dist, failed, steps=k, repaired=repaired)
            self._detour.update(a for a in dist if self.keeper.stalled_steps(a) >= self.detour_after)
        if k >= self.planner.commit_steps or k == 0 or self._needs_plan:
            self._replan()

    def _finish_legs(self) -> None:
        for a, leg in list(self._legs.items()):
            if self.frame < leg.frame + leg.frames:
                continue
            del self._legs[a]
            self._needs_plan = True
            if leg.inbound:  # standing on the exact target: arrived
                self._parked[a] = leg.b.copy()
                self._final.pop(a, None)
                self._goals[a] = None
                self.arrivals.append((self.frame, a))
                self.keeper.reset(a)
                self._detour.discard(a)
            # outbound: back on the cell centre, a normal walker again

    def _start_legs(self) -> None:
        """Start the legs that are due and clear: off-grid walkers with a goal leave their point,
        walkers on a goal cell with an exact target walk to it (in a fixed order)."""
        for a in list(self._cells):
            if a in self._legs:
                continue
            goal = self._goals[a]
            parked = self._parked.get(a)
            if parked is None and (goal is None or self._cells[a] != goal or a not in self._final):
                continue  # a plain walker: no leg to start
            cell_xy = self.grid.center_of(*self._cells[a])
            if parked is not None:
                final = self._final.get(a)
                if goal is None or (goal == self._cells[a] and final is not None and close_xy(final, parked, atol=1e-8)):
                    if goal is not None:  # already standing on the new exact target
                        del self._parked[a]
                        self._legs[a] = Leg(parked, parked, self.frame, 1, True)
                    continue
                seg = (parked, cell_xy)
                inbound = False
            elif goal is not None and self._cells[a] == goal and a in self._final:
                seg = (cell_xy, self._final[a])
                inbound = True
            else:
                continue
            if not self._leg_clear(a, *seg):
                self.leg_waits += 1
                continue
            length = float(np.linalg.norm(seg[1] - seg[0]))
            frames = max(1, math.ceil(length / self.speed * self.fps - 1e-9))
            self._parked.pop(a, None)
            self._legs[a] = Leg(seg[0].copy(), seg[1].copy(), self.frame, frames, inbound)
            self._needs_plan = True

    def _leg_clear(self, agent: Agent, p: NDArray[np.float64], q: NDArray[np.float64]) -> bool:
        """Every other body is >= 2r from the segment p-q now (all walkers are on cell centres)."""
        ps, qs = [], []
        for b in self._cells:
            if b == agent:
                continue
            leg = self._legs.get(b)
            if leg is not None:
                ps.append(leg.at(self.frame))
                qs.append(leg.b)
            else:
                xy = self._parked.get(b)
                xy = self.grid.center_of(*self._cells[b]) if xy is None else xy
                ps.append(xy)
                qs.append(xy)
        for xy in self._static.values():
            ps.append(xy)
            qs.append(xy)
        if not ps:
            return True
        n = len(ps)
        d = segment_distance(np.broadcast_to(p, (n, 2)), np.broadcast_to(q, (n, 2)), np.array(ps), np.array(qs))
        return bool(np.all(d >= self.planner.min_distance - 1e-9))

    def _hints(self, planned: list[Agent]) -> dict[Agent, tuple[list[Cell], Cell]]:
        """Previous plans the planner may keep (see ``PathPlanner.plan``): the rest of each full
        plan made for a goal it still has, for agents that searched at the last replan (so an
        agent searches at least every other replan and a kept plan is at most one replan old)."""
        res = self.last_result
        if not self.reuse_plans or res is None:
            return {}
        k = (self.frame - self._plan_frame) // self.step_frames
        out = {}
        for a in planned:
            path = self._paths.get(a)
            goal = res.goals.get(a)
            if (path is None or goal is None or a in res.reused or a in res.failed or a in res.fallback
                    or len(path) != self.planner.window + 1 or self._goals[a] is None or k >= len(path)
                    or path[k] != self._cells[a]):
                continue
            out[a] = (path[k:], goal)
        return out

    def _replan(self) -> None:
        off = set(self._legs) | set(self._parked)
        planned = [a for a in self._cells if a not in off]
        walking = [a for a in planned if self._goals[a] is not None]
        arrived = [a for a in planned if self._goals[a] is None]
        order = self.keeper.order(walking, arrived)
        step = self.frame // self.step_frames
        statics = list(self._static.values()) + [self._parked[a] for a in self._parked]
        segments = [(leg.at(self.frame), leg.b) for leg in self._legs.values()]
        result = self.planner.plan(
            {a: self._cells[a] for a in planned},
            {a: self._goals[a] for a in planned},
            statics,
            t0=step,
            order=order,
            static_segments=segments,
            hints=self._hints(planned),
            detour=sorted(self._detour & set(planned), key=planned.index),
        )
        self._paths = {a: list(p) for a, p in result.paths.items()}
        self._tracks.clear()
        self._ahead = None
        for a in off:
            self._paths[a] = [self._cells[a]]
        self._plan_frame = self.frame
        self.last_result = result
        self.replans += 1
        self.failures += len(result.failed)
        self.fallbacks += len(result.fallback)
        self._needs_plan = False


def close_xy(a: NDArray[np.float64], b: NDArray[np.float64], atol: float = 1e-9) -> bool:
    """``np.allclose(a, b, atol=atol)`` (rtol 1e-5) for two xy points, on plain floats."""
    a0, a1, b0, b1 = float(a[0]), float(a[1]), float(b[0]), float(b[1])
    if not (math.isfinite(a0) and math.isfinite(a1) and math.isfinite(b0) and math.isfinite(b1)):
        return bool(np.allclose(a, b, atol=atol))
    return abs(a0 - b0) <= atol + 1e-5 * abs(b0) and abs(a1 - b1) <= atol + 1e-5 * abs(b1)

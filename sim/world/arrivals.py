"""Arrivals and stalls of the world's walkers, checked at planning-step boundaries.

Functions of a ``WalkingWorld`` (the parts of ``storyteller.sim.world.step.World`` they read and change).
The rules they keep:

- a walker counts as arrived once it stands where its walk ends (``on_target``: its goal cell's
  centre, or its exact off-grid point within ``OFF_GRID_EPS``); it then waits there for the
  event's other members (``arrive``);
- a walker stalled beside a taken goal cell, on its goal cell while others crowd its exact
  point, or near enough to its target for long enough stops where it stands, on a cell centre,
  with a typed ``TargetFallback`` (``goal_cell_taken``, ``target_occupied``, ``stopped_near``)
  -- unless its action works on an object it would not reach from there: then it walks to the
  free point within reach nearest to it (``out_of_reach``, at most ``max_replans`` times) or
  keeps waiting for room (``stop_short``);
- a walker that got no closer for ``stuck_after_s`` seconds fails its event as ``stuck``.

Deterministic: characters are visited in the world's order; no randomness, no clock.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Protocol

import numpy as np

from storyteller.sim.paths.cooperative_astar import PathPlanner
from storyteller.sim.world.event_book import (
    EventRules,
    EventWorld,
    StepReport,
    fail_event,
    final_of,
    reach_object,
    still_bodies,
    taken_points,
)
from storyteller.sim.world.facing import surface_distance
from storyteller.sim.world.navigation import OFF_GRID_EPS
from storyteller.sim.world.phases import CharacterState, StandTarget, TargetFallback


class WalkRules(EventRules, Protocol):
    """The settings the arrival and stall checks read (``sim.world.step.WorldConfig`` has them)."""

    @property
    def stuck_after_s(self) -> float: ...

    @property
    def near_enough_m(self) -> float: ...

    @property
    def near_patience_s(self) -> float: ...

    @property
    def exact_patience_s(self) -> float: ...

    @property
    def max_replans(self) -> int: ...


class WalkingWorld(EventWorld, Protocol):
    """The parts of a world that the arrival and stall checks read and change."""

    @property
    def config(self) -> WalkRules: ...

    planner: PathPlanner


def arrive(w: WalkingWorld, c: CharacterState, fallback: TargetFallback | None = None) -> None:
    """``c`` reached its goal (the exact target when it has one): wait there for the
    event's other members. ``fallback``: it stopped on a cell centre instead
    (``goal_cell_taken``: the neighbour of a taken goal cell; ``target_occupied``: its goal
    cell, the walk onto the exact point being blocked by others).

    A waiting character stays a walker without a goal: on a cell centre it steps aside for
    passers-by (its partners included) and walks back afterwards; on an exact point it is
    an obstacle the others walk around.
    """
    nav = w.navigator
    cell = nav.cell(c.name)
    c.goal_cell = cell
    c.anchor_cell = cell
    c.anchor_xy = nav.position(c.name).copy() if nav.is_off_grid(c.name) else w.grid.center_of(*cell)
    if fallback is not None and c.target is not None:
        if fallback == "goal_cell_taken":
            msg = f"cell {c.target.cell} was taken; {c.name} stopped on the neighbouring cell {cell}"
        elif fallback == "stopped_near":
            gap = float(np.linalg.norm(c.anchor_xy - np.asarray(c.target.xy)))
            msg = (f"{c.name} got no closer than {gap:.2f} m to ({c.target.xy[0]:.2f}, {c.target.xy[1]:.2f}) "
                   f"for {w.config.near_patience_s:g} s; it stopped on the centre of cell {cell}")
        else:
            msg = (f"others stayed too close to ({c.target.xy[0]:.2f}, {c.target.xy[1]:.2f}) for "
                   f"{w.config.exact_patience_s:g} s; {c.name} stopped on the centre of cell {cell}")
        c.target = StandTarget(cell, (float(c.anchor_xy[0]), float(c.anchor_xy[1])), False, fallback, msg)
    c.best_distance, c.stalled_frames = 0.0, 0
    if nav.goal_of(c.name) is not None:
        nav.set_goal(c.name, None)
    c.waiting = True
    c.enter("idle")

def stop_short(w: WalkingWorld, c: CharacterState, fallback: TargetFallback) -> bool:
    """A stall rule would stop the walker ``c`` on its cell's centre (``fallback``): it does,
    unless its action works on an object it would not reach from there. Then it walks to the
    free point within reach nearest to it, clear of the others' bodies and targets
    (``out_of_reach``; at most ``WorldConfig.max_replans`` times), or, with none, keeps
    waiting for room: False, its stall count goes on (it fails as stuck if nothing frees up)."""
    a = c.assignment
    obj = None if a is None else reach_object(w, a)
    if obj is None:
        arrive(w, c, fallback)
        return True
    nav, g = w.navigator, w.grid
    cell = nav.cell(c.name)
    comp = int(g.component[cell])
    here = g.center_of(*cell)
    if w.targets.reaches(obj, comp, here):
        arrive(w, c, fallback)
        return True
    if c.replans >= w.config.max_replans:
        return False
    avoid = [*taken_points(w, (c.name,)), *still_bodies(w, (c.name,))]
    near = w.targets.within_reach(obj, comp, nav.position(c.name), avoid)
    if near is None:
        return False
    c.replans += 1
    gap = surface_distance(obj, here)
    c.target = replace(near, message=(
        f"{c.name} would have stopped {gap:.2f} m from {obj.name}, out of reach ({fallback}); "
        f"it walks to ({near.xy[0]:.2f}, {near.xy[1]:.2f}) instead"))
    c.goal_cell = near.cell
    c.best_distance, c.stalled_frames, c.rerouted = math.inf, 0, False
    nav.set_goal(c.name, near.cell, final_xy=final_of(near))
    return True

def on_target(w: WalkingWorld, c: CharacterState) -> bool:
    """Whether the walker ``c`` stands where its current assignment's walk ends."""
    nav = w.navigator
    if c.goal_cell is None or nav.cell(c.name) != c.goal_cell:
        return False
    final = final_of(c.target)
    if final is None:
        return not nav.is_off_grid(c.name)
    return bool(np.linalg.norm(nav.position(c.name) - final) <= OFF_GRID_EPS)


def walker_checks(w: WalkingWorld, out: StepReport) -> None:
    """Arrivals, near-arrivals at a substitute goal or at the centre of a goal cell whose exact
    point stays crowded, and stuck walkers (at step boundaries)."""
    nav = w.navigator
    for name in nav.new_arrivals():
        c = w.characters[name]
        if c.phase != "approaching":
            continue
        if on_target(w, c):
            arrive(w, c)
        else:  # the arrival belongs to an older goal: head for the current one
            nav.set_goal(name, c.goal_cell, final_xy=final_of(c.target))
    limit = int(w.config.stuck_after_s * w.config.fps)
    patience = int(w.config.exact_patience_s * w.config.fps)
    near_patience = int(w.config.near_patience_s * w.config.fps)
    for c in w.characters.values():
        if not c.walker or c.goal_cell is None or not (c.phase == "approaching" or c.waiting):
            continue
        cell = nav.cell(c.name)
        if c.waiting:
            if cell == c.goal_cell:
                c.best_distance, c.stalled_frames = 0.0, 0
                continue
            if nav.goal_of(c.name) is None:  # made way for someone: walk back
                nav.set_goal(c.name, c.goal_cell)  # (only walkers waiting on a cell centre step aside)
        used = nav.used_goal(c.name)
        if c.phase == "approaching" and used is not None and used != c.goal_cell and cell == used and max(
            abs(used[0] - c.goal_cell[0]), abs(used[1] - c.goal_cell[1])
        ) <= 1 and stop_short(w, c, "goal_cell_taken"):
            continue  # the neighbour the planner chose will do
        if (c.phase == "approaching" and cell != c.goal_cell and c.stalled_frames >= patience
                and max(abs(cell[0] - c.goal_cell[0]), abs(cell[1] - c.goal_cell[1])) <= 1
                and not nav.is_off_grid(c.name) and nav.crowded_by_still_bodies(c.goal_cell)
                and nav.can_freeze(c.name) and stop_short(w, c, "goal_cell_taken")):
            continue  # a still body keeps everyone off that cell: stop beside it
        around = nav.detour_distance(c.name)  # planned around stationary bodies: progress counts on that route
        if around is not None and not c.rerouted:
            c.best_distance = math.inf
        c.rerouted = around is not None
        d = w.planner.distance(cell, c.goal_cell) if around is None else around
        if d < c.best_distance - 1e-9:
            c.best_distance, c.stalled_frames = d, 0
        else:
            c.stalled_frames += nav.step_frames
        if (c.phase == "approaching" and c.target is not None and c.target.off_grid and cell == c.goal_cell
                and not nav.is_off_grid(c.name) and c.stalled_frames >= patience and nav.can_freeze(c.name)
                and stop_short(w, c, "target_occupied")):
            continue  # the cell centre is clear; the point is not
        if (c.phase == "approaching" and c.stalled_frames >= near_patience and c.assignment is not None
                and c.assignment.seat is None and c.target is not None and not nav.is_off_grid(c.name)
                and float(np.linalg.norm(nav.position(c.name) - np.asarray(c.target.xy))) <= w.config.near_enough_m
                and nav.can_freeze(c.name) and stop_short(w, c, "stopped_near")):
            continue  # close enough to stand in: act here rather than fail as stuck
        if c.stalled_frames > limit and c.event_id is not None:
            fail_event(w, c.event_id, c.name, "stuck",
                       f"{c.name} made no progress towards its target for "
                       f"{w.config.stuck_after_s:.0f} s", out)

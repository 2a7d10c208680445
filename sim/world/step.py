"""The world step: characters, events, cooperative walking and motion, one frame at a time.

``step(world, commands, dt) -> (world, StepOutput)`` applies the planner's commands
(``sim.world.events``), advances every character by one frame (``dt`` = 1 / fps, 30 fps),
appends a pose per character to the world's track buffers and reports completed / looping /
failed events and the characters available to the narrator. The world is advanced in place
and returned; ``World.snapshot()`` / ``World.restore(snapshot)`` copy its state (plain data:
dataclasses, dicts and numpy arrays) for replays and tests.

Who moves a character's root (pelvis ground point, metres):

- walkers (``approaching``; ``idle`` standing characters, including those waiting at their
  target for the event's other members, who step aside for passers-by and walk back) are on
  the ``CrowdNavigator``'s position exactly, so its clearance rule (centres >= 2 body radii
  apart, bodies off every blocking footprint) holds for the synthesized pelvis;
- everyone else is a stationary obstacle for the navigator: characters transitioning in or
  out, acting, seated, or standing still after an action until the next planning step. A
  seated body registers discs along its sit-down path (approach point to seat point, at least
  three, <= 0.4 m apart: ``seat_discs``) while it sits down, sits and stands up; they keep
  walkers 2 body radii from both ends and at least ~0.45 m from the segment between them.

Walkers join the navigator only at planning-step boundaries (every ``step_frames`` frames,
9 at 0.3 m cells and 1 m/s): a character that finished standing up waits in place until then.

Events: every member walks to the EXACT point the planner gave (``StandTarget``): its target
when standing, the seat's approach point (``NavGrid.approach_point``, cached) when sitting. It
walks the grid to the point's entry cell, then straight onto the point, and counts as arrived
once it stands there. A point a body cannot stand on or walk straight to falls back to the
nearest cell centre; ``CharacterState.target.fallback`` keeps the typed reason
(``TargetFallback``). Whoever arrives first waits; when all stand on their points at a
planning-step boundary, all start their transition in on the same frame.
An event completes when every member has finished its action (or, acting a looping action,
was interrupted or released); it becomes *looping* when every member is done or acting a
looping action. Characters of looping events are available, and a new assignment interrupts
them via their transition out. Unreachable targets and walkers that make no progress for
``stuck_after_s`` seconds fail the event with a typed ``EventFailure``.

Deterministic: the only randomness is the navigator's seeded priority order; no clock.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from sim.body.foot_ik import FootSolver, FootState
from sim.body.skeleton import NUM_JOINTS
from sim.motion.action_labels import action_spec, database_key
from sim.paths.cooperative_astar import Cell, PathPlanner
from sim.paths.following import close_xy
from sim.paths.nav_grid import NavGrid, build_nav_grid
from sim.paths.tracks import walker_headings
from sim.scene.model import Scene
from sim.world.character_track import CharacterTrack
from sim.world.events import (
    AssignEvent,
    Assignment,
    EventFailure,
    FailureReason,
    ReleaseCharacters,
    StepOutput,
)
from sim.world.motion_layer import FUTURE_FRAMES, MotionLayer, MotionQuery, compose_poses
from sim.world.navigation import OFF_GRID_EPS, StandTargets, WorldNavigator
from sim.world.phases import (
    INFINITE,
    CharacterState,
    StandTarget,
    TargetFallback,
    available,
    interaction_frames,
    phase_motion,
    smoothstep,
    transition_in_frames,
    transition_out_frames,
    wrap_angle,
)
from sim.world.tracks import TrackBuffers

OBJECT_REACH = 0.55  # metres from the standing root to the object acted on (motion target)
EventStatus = Literal["ongoing", "looping", "completed", "failed"]


class WorldError(ValueError):
    """Bad world input (setup or step arguments); one sentence naming what is wrong."""


@dataclass(frozen=True)
class WorldConfig:
    """fps: frames per second; seed: navigator priority seed; walk_turn_rate: rad/s a walker's
    heading may turn (faster turns swing the planted feet around the root: sliding);
    heading_lookahead: frames ahead on the plan that a walker turns to face (looking past the
    grid's zigzags); stuck_after_s: seconds without getting closer before a walker fails;
    max_target_offset: metres between a target and the nearest reachable cell centre beyond
    which the target counts as unreachable; exact_patience_s: seconds a walker on its goal cell
    waits for room to step onto its exact target before it settles for the cell centre
    (``target_occupied``); initial_capacity: frames pre-allocated per track; foot_ik: run the
    leg IK (``sim.body.foot_ik.FootSolver``) on every frame's poses: feet kept out of floor-standing
    furniture and pinned while in contact (characters sitting, sitting down or standing up are
    left as animated)."""

    fps: int = 30
    seed: int = 0
    walk_turn_rate: float = 2.0
    heading_lookahead: int = 20
    stuck_after_s: float = 20.0
    max_target_offset: float = 0.75
    exact_patience_s: float = 3.0
    initial_capacity: int = 512
    foot_ik: bool = True


@dataclass
class EventState:
    """One accepted event: member name -> "active" | "done" | "left"."""

    event: AssignEvent
    members: dict[str, str]
    status: EventStatus = "ongoing"
    started: bool = False


def _unstarted(events: dict[str, EventState]) -> dict[str, None]:
    return {eid: None for eid, ev in events.items() if ev.status == "ongoing" and not ev.started}


@dataclass
class WorldSnapshot:
    """A deep copy of a world's mutable state (restore with ``World.restore``)."""

    frame: int
    characters: dict[str, CharacterState]
    events: dict[str, EventState]
    motion_states: dict[str, Any]
    navigator: WorldNavigator
    buffers: TrackBuffers
    feet: FootState | None = None


class World:
    """All characters of one scene. Build with ``World(scene, characters, motion)``.

    ``characters``: name -> ((x, y) metres, heading radians); each starts standing idle on the
    centre of the free navigation cell nearest to its position. ``motion``: the motion layer
    (e.g. ``sim.motion.matching.MotionMatcher``). ``grid`` / ``planner`` default to
    ``build_nav_grid(scene)`` and ``PathPlanner(grid, seed=config.seed)``.
    """

    def __init__(
        self,
        scene: Scene,
        characters: Mapping[str, tuple[tuple[float, float], float]],
        motion: MotionLayer,
        *,
        grid: NavGrid | None = None,
        planner: PathPlanner | None = None,
        config: WorldConfig | None = None,
    ) -> None:
        self.config = config or WorldConfig()
        if self.config.fps < 1:
            raise WorldError(f"fps must be >= 1, got {self.config.fps}")
        if not characters:
            raise WorldError("a world needs at least one character")
        self.scene = scene
        self.grid = grid if grid is not None else build_nav_grid(scene)
        self.planner = planner if planner is not None else PathPlanner(self.grid, seed=self.config.seed)
        self.motion = motion
        self.dt = 1.0 / self.config.fps
        self.names: tuple[str, ...] = tuple(characters)
        self.frame = 0
        self.navigator = WorldNavigator(self.grid, self.planner, self.config.fps, self.config.seed)
        self.characters: dict[str, CharacterState] = {}
        self.events: dict[str, EventState] = {}
        self._waiting_to_start: dict[str, None] = {}  # ongoing, not yet started events, in ``events`` order
        self.targets = StandTargets(self.grid)
        self.motion_states: dict[str, Any] = {}
        taken: dict[Cell, str] = {}
        for name, (xy, heading) in characters.items():
            if not isinstance(name, str) or not name:
                raise WorldError(f"character names must be non-empty strings, got {name!r}")
            p = np.asarray(xy, dtype=float)
            if p.shape != (2,) or not np.all(np.isfinite(p)) or not math.isfinite(heading):
                raise WorldError(f"character {name!r}: position must be finite (x, y) and heading a finite angle")
            cell = self.grid.nearest_free_cell(p)
            if cell in taken:
                raise WorldError(f"characters {taken[cell]!r} and {name!r} start on the same cell {cell}")
            taken[cell] = name
            centre = self.grid.center_of(*cell)
            self.characters[name] = CharacterState(name=name, xy=centre, heading=float(heading), anchor_xy=centre,
                                                   anchor_cell=cell)
            self.navigator.add_walker(name, cell)
            self.motion_states[name] = motion.initial_state("idle", centre, float(heading))
        self.buffers = TrackBuffers(self.names, max(1, self.config.initial_capacity))
        self.foot_solver = FootSolver.from_scene(scene) if self.config.foot_ik else None
        self.feet: FootState | None = FootSolver.initial_state(len(self.names)) if self.foot_solver else None

    # ----- snapshots ---------------------------------------------------------------------------
    def _shared_memo(self) -> dict[int, Any]:
        nav = self.navigator.nav
        return {id(self.scene): self.scene, id(self.grid): self.grid, id(self.planner): self.planner,
                id(self.motion): self.motion, id(nav.grid): nav.grid, id(nav.planner): nav.planner}

    def snapshot(self) -> WorldSnapshot:
        """A copy of the mutable state; the world can go on stepping afterwards."""
        memo = self._shared_memo()
        return WorldSnapshot(
            frame=self.frame,
            characters=copy.deepcopy(self.characters, memo),
            events=copy.deepcopy(self.events, memo),
            motion_states=copy.deepcopy(self.motion_states, memo),
            navigator=copy.deepcopy(self.navigator, memo),
            buffers=self.buffers.trimmed(),
            feet=copy.deepcopy(self.feet),
        )

    def restore(self, snap: WorldSnapshot) -> World:
        """A new world in the state of ``snap`` (sharing scene, grid, planner and motion layer)."""
        out = copy.copy(self)
        memo = self._shared_memo()
        out.frame = snap.frame
        out.characters = copy.deepcopy(snap.characters, memo)
        out.events = copy.deepcopy(snap.events, memo)
        out._waiting_to_start = _unstarted(out.events)
        out.motion_states = copy.deepcopy(snap.motion_states, memo)
        out.navigator = copy.deepcopy(snap.navigator, memo)
        out.buffers = snap.buffers.trimmed()
        out.feet = copy.deepcopy(snap.feet)
        return out

    # ----- read-outs ------------------------------------------------------------------------------
    def available(self) -> tuple[str, ...]:
        """Characters the narrator may give a new event (see ``character_phases.available``)."""
        out = []
        events = self.events
        for name in self.names:
            c = self.characters[name]
            if c.event_id is None:  # no event: free (available(c, False))
                out.append(name)
                continue
            ev = events.get(c.event_id)
            if available(c, ev is not None and ev.status == "ongoing"):
                out.append(name)
        return tuple(out)

    def tracks(self) -> dict[str, CharacterTrack]:
        """One ``CharacterTrack`` per character with every frame produced so far."""
        b = self.buffers
        if b.length == 0:
            raise WorldError("no frame has been produced yet")
        out = {}
        for k, name in enumerate(self.names):
            labels = tuple(b.label_names[i] for i in b.labels[: b.length, k])
            out[name] = CharacterTrack(
                name=name,
                root_positions=b.pelvis[: b.length, k].copy(),
                local_rotations=b.rotations[: b.length, k].astype(float),
                fps=float(self.config.fps),
                action_labels=labels,
            )
        return out

    def foot_contacts(self) -> dict[str, np.ndarray]:
        """Per character, the motion layer's left/right foot contact flags (frames, 2)."""
        b = self.buffers
        return {name: b.contacts[: b.length, k].copy() for k, name in enumerate(self.names)}

    def event_ids(self) -> dict[str, tuple[str, ...]]:
        """Per character, the event it belonged to at every frame ("" when none)."""
        b = self.buffers
        return {name: tuple(b.label_names[i] for i in b.events[: b.length, k]) for k, name in enumerate(self.names)}

    def positions(self) -> np.ndarray:
        """Current root xy (N, 2) in ``names`` order."""
        return np.array([self.characters[n].xy for n in self.names])

    # ----- commands -----------------------------------------------------------------------------
    def _fail(self, out: _Report, event_id: str, character: str, reason: FailureReason, message: str) -> None:
        out.failures.append(EventFailure(event_id=event_id, character=character, reason=reason, message=message))

    def _target_for(self, c: CharacterState, a: Assignment) -> tuple[StandTarget | None, str]:
        """Where ``a``'s walk ends (see ``StandTargets``), or (None, why not)."""
        g = self.grid
        here = self.navigator.cell(c.name) if self.navigator.is_walker(c.name) else c.anchor_cell
        comp = int(g.component[here]) if g.is_free(*here) else g.main_component
        if a.seat is not None:
            target = self.targets.seated(self.navigator, self.scene.by_name[a.seat], comp)
            if target is None:
                return None, f"{c.name} cannot reach a free cell in front of {a.seat}"
            return target, ""
        p = np.asarray(a.target_xy, dtype=float)
        target = self.targets.standing(self.navigator, p, comp)
        off = math.inf if target is None else float(np.linalg.norm(np.asarray(target.xy) - p))
        if target is None or off > self.config.max_target_offset:
            return None, (f"{c.name} cannot reach ({a.target_xy[0]:.2f}, {a.target_xy[1]:.2f}): the nearest "
                          f"reachable floor is {off:.2f} m away")
        return target, ""

    def _apply_assign(self, cmd: AssignEvent, out: _Report) -> None:
        eid = cmd.event_id
        if eid in self.events and self.events[eid].status in ("ongoing", "looping"):
            raise WorldError(f"event {eid!r} is already running")
        free = set(self.available())
        goals: dict[str, StandTarget] = {}
        problems: list[tuple[str, FailureReason, str]] = []
        for a in cmd.assignments:
            if a.character not in self.characters:
                problems.append((a.character, "unknown_character", f"no character called {a.character!r}"))
                continue
            unknown = [p for p in a.partners if p not in self.characters]
            if unknown:
                problems.append((a.character, "unknown_character", f"unknown partners {unknown}"))
                continue
            if a.seat is not None and a.seat not in self.scene.by_name:
                problems.append((a.character, "unknown_seat", f"no object called {a.seat!r} in the scene"))
                continue
            if a.character not in free:
                problems.append((a.character, "busy", f"{a.character} is busy with event "
                                 f"{self.characters[a.character].event_id!r}"))
                continue
            goal, why = self._target_for(self.characters[a.character], a)
            if goal is None:
                problems.append((a.character, "no_path", why))
                continue
            goals[a.character] = goal
        if problems:
            for name, reason, msg in problems:
                self._fail(out, eid, name, reason, msg)
            self.events[eid] = EventState(cmd, {a.character: "left" for a in cmd.assignments}, status="failed")
            return
        reused = eid in self.events
        self.events[eid] = EventState(cmd, {a.character: "active" for a in cmd.assignments})
        if reused:  # a dict keeps a reused key where it was: so does the start queue
            self._waiting_to_start = _unstarted(self.events)
        else:
            self._waiting_to_start[eid] = None
        for a in cmd.assignments:
            c = self.characters[a.character]
            self._leave_event(c, out)
            c.pending = None
            self._start(c, eid, a, goals[a.character])

    def _apply_release(self, cmd: ReleaseCharacters, out: _Report) -> None:
        for name in cmd.characters:
            c = self.characters.get(name)
            if c is None:
                self._fail(out, "release", name, "unknown_character", f"no character called {name!r}")
                continue
            self._leave_event(c, out)
            c.pending = None
            self._stop(c)

    def _start(self, c: CharacterState, eid: str, a: Assignment, goal: StandTarget) -> None:
        """Give ``c`` its new assignment: walk now, or first leave what it is doing."""
        c.event_id = eid
        c.waiting = False
        if c.phase in ("transition_in", "interacting", "transition_out") or c.seated:
            c.pending = (eid, a, goal)
            if c.phase != "transition_out":
                self._begin_transition_out(c)
            return
        self._take(c, a, goal)
        c.enter("approaching")
        if c.walker:
            self.navigator.set_goal(c.name, goal.cell, final_xy=self._final_of(goal))
        # else: joins the navigator at the next step boundary (see _join_walkers)

    @staticmethod
    def _final_of(target: StandTarget | None) -> np.ndarray | None:
        """The exact end point to give the navigator (None: the goal cell's centre)."""
        return np.asarray(target.xy, dtype=float) if target is not None and target.off_grid else None

    @staticmethod
    def _take(c: CharacterState, a: Assignment, goal: StandTarget) -> None:
        c.assignment, c.goal_cell, c.target = a, goal.cell, goal
        c.action_done = False
        c.best_distance, c.stalled_frames = math.inf, 0

    def _stop(self, c: CharacterState) -> None:
        """End whatever ``c`` does and become idle (standing up first when seated)."""
        was_waiting, c.waiting = c.waiting, False
        if c.phase in ("transition_in", "interacting") or (c.phase == "idle" and c.seated):
            self._begin_transition_out(c)
        elif c.phase == "approaching" or was_waiting:
            c.enter("idle")
            if c.walker:
                self.navigator.set_goal(c.name, None)

    def _begin_transition_out(self, c: CharacterState) -> None:
        if c.phase == "transition_in" and c.assignment is not None and c.assignment.seat is not None:
            c.seated = c.phase_frame > c.turn_frames  # stopped while sitting down: stand up
            c.seat_xy = c.xy.copy()
        c.enter("transition_out", transition_out_frames(c.seated, self.config.fps))
        c.turn_from = c.heading

    def _leave_event(self, c: CharacterState, out: _Report) -> None:
        ev = self.events.get(c.event_id) if c.event_id is not None else None
        if ev is not None and ev.members.get(c.name) in ("active", "done"):
            ev.members[c.name] = "left"
            self._update_event(ev.event.event_id, ev, out)
        c.event_id = None

    # ----- events -------------------------------------------------------------------------------
    def _update_event(self, eid: str, ev: EventState, out: _Report) -> None:
        if ev.status in ("completed", "failed"):
            return
        states = ev.members
        if any(s == "active" for s in states.values()):
            return
        looping = [n for n, s in states.items() if s == "done" and self.characters[n].event_id == eid
                   and self.characters[n].phase == "interacting" and self.characters[n].loops]
        if looping:
            if ev.status != "looping":
                ev.status = "looping"
                out.looping.append(eid)
            return
        ev.status = "completed"
        out.completed.append(eid)
        for n in states:
            if self.characters[n].event_id == eid:
                self.characters[n].event_id = None

    def _fail_event(self, eid: str, character: str, reason: FailureReason, message: str, out: _Report) -> None:
        ev = self.events[eid]
        ev.status = "failed"
        self._fail(out, eid, character, reason, message)
        for n in ev.members:
            c = self.characters[n]
            if c.event_id != eid:
                continue
            c.event_id = None
            if c.phase in ("approaching",) or c.waiting:
                c.waiting = False
                c.assignment = None
                c.enter("idle")
                if c.walker:
                    self.navigator.set_goal(n, None)

    def _arrive(self, c: CharacterState, fallback: TargetFallback | None = None) -> None:
        """``c`` reached its goal (the exact target when it has one): wait there for the
        event's other members. ``fallback``: it stopped on a cell centre instead
        (``goal_cell_taken``: the neighbour of a taken goal cell; ``target_occupied``: its goal
        cell, the walk onto the exact point being blocked by others).

        A waiting character stays a walker without a goal: on a cell centre it steps aside for
        passers-by (its partners included) and walks back afterwards; on an exact point it is
        an obstacle the others walk around.
        """
        nav = self.navigator
        cell = nav.cell(c.name)
        c.goal_cell = cell
        c.anchor_cell = cell
        c.anchor_xy = nav.position(c.name).copy() if nav.is_off_grid(c.name) else self.grid.center_of(*cell)
        if fallback is not None and c.target is not None:
            msg = (f"cell {c.target.cell} was taken; {c.name} stopped on the neighbouring cell {cell}"
                   if fallback == "goal_cell_taken" else
                   f"others stayed too close to ({c.target.xy[0]:.2f}, {c.target.xy[1]:.2f}) for "
                   f"{self.config.exact_patience_s:g} s; {c.name} stopped on the centre of cell {cell}")
            c.target = StandTarget(cell, (float(c.anchor_xy[0]), float(c.anchor_xy[1])), False, fallback, msg)
        c.best_distance, c.stalled_frames = 0.0, 0
        if nav.goal_of(c.name) is not None:
            nav.set_goal(c.name, None)
        c.waiting = True
        c.enter("idle")

    def _on_target(self, c: CharacterState) -> bool:
        """Whether the walker ``c`` stands where its current assignment's walk ends."""
        nav = self.navigator
        if c.goal_cell is None or nav.cell(c.name) != c.goal_cell:
            return False
        final = self._final_of(c.target)
        if final is None:
            return not nav.is_off_grid(c.name)
        return bool(np.linalg.norm(nav.position(c.name) - final) <= OFF_GRID_EPS)

    def _begin_transition_in(self, c: CharacterState) -> None:
        a = c.assignment
        assert a is not None
        c.waiting = False
        c.turn_from = c.heading
        c.turn_frames, total = transition_in_frames(a, c.heading, self.config.fps)
        c.enter("transition_in", total)
        c.xy = c.anchor_xy.copy()
        c.walker = False
        if a.seat is not None:
            c.seat_xy = self.scene.by_name[a.seat].seat_point()
            self.navigator.make_stationary(c.name, seat_discs(c.anchor_xy, c.seat_xy))
        else:
            self.navigator.make_stationary(c.name, [c.anchor_xy])

    # ----- the frame ------------------------------------------------------------------------------
    def _phase_ends(self, out: _Report) -> None:
        fps = self.config.fps
        for c in self.characters.values():
            if not c.phase_over:
                continue
            a = c.assignment
            if c.phase == "transition_in":
                assert a is not None
                c.seated = a.seat is not None
                if c.seated:
                    assert c.seat_xy is not None
                    c.xy = c.seat_xy.copy()
                c.heading = a.facing_angle
                c.enter("interacting", interaction_frames(a, fps))
                if c.loops:
                    self._member_done(c, out)
            elif c.phase == "interacting":
                c.enter("idle")
                self._member_done(c, out)
            elif c.phase == "transition_out":
                if c.seated:
                    c.seated = False
                    c.xy = c.anchor_xy.copy()
                    self.navigator.make_stationary(c.name, [c.anchor_xy])
                c.enter("idle")
                if c.pending is None:
                    c.assignment = None

    def _member_done(self, c: CharacterState, out: _Report) -> None:
        c.action_done = True
        eid = c.event_id
        ev = self.events.get(eid) if eid is not None else None
        if ev is not None and ev.members.get(c.name) == "active":
            ev.members[c.name] = "done"
            self._update_event(eid, ev, out)  # type: ignore[arg-type]

    def _join_walkers(self) -> None:
        """At a step boundary: standing, stationary characters with nothing to wait for walk again."""
        for c in self.characters.values():
            if c.walker or c.seated or c.waiting or c.phase not in ("idle", "approaching"):
                continue
            if c.phase == "idle" and c.pending is not None:
                eid, a, target = c.pending
                c.pending = None
                ev = self.events.get(eid)
                if ev is not None and ev.status == "ongoing" and c.event_id == eid:
                    self._take(c, a, target)
                    c.enter("approaching")
            cell = c.anchor_cell
            off = float(np.linalg.norm(c.anchor_xy - self.grid.center_of(*cell))) > OFF_GRID_EPS
            approaching = c.phase == "approaching"
            self.navigator.add_walker(
                c.name, cell, c.goal_cell if approaching else None,
                start_xy=c.anchor_xy if off else None,
                final_xy=self._final_of(c.target) if approaching else None,
            )
            c.walker = True

    def _walker_checks(self, out: _Report) -> None:
        """Arrivals, near-arrivals at a substitute goal or at the centre of a goal cell whose exact
        point stays crowded, and stuck walkers (at step boundaries)."""
        nav = self.navigator
        for name in nav.new_arrivals():
            c = self.characters[name]
            if c.phase != "approaching":
                continue
            if self._on_target(c):
                self._arrive(c)
            else:  # the arrival belongs to an older goal: head for the current one
                nav.set_goal(name, c.goal_cell, final_xy=self._final_of(c.target))
        limit = int(self.config.stuck_after_s * self.config.fps)
        patience = int(self.config.exact_patience_s * self.config.fps)
        for c in self.characters.values():
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
            ) <= 1:
                self._arrive(c, "goal_cell_taken")  # the neighbour the planner chose will do
                continue
            d = self.planner.distance(cell, c.goal_cell)
            if d < c.best_distance - 1e-9:
                c.best_distance, c.stalled_frames = d, 0
            else:
                c.stalled_frames += nav.step_frames
            if (c.phase == "approaching" and c.target is not None and c.target.off_grid and cell == c.goal_cell
                    and not nav.is_off_grid(c.name) and c.stalled_frames >= patience and nav.can_freeze(c.name)):
                self._arrive(c, "target_occupied")  # the cell centre is clear; the point is not
                continue
            if c.stalled_frames > limit and c.event_id is not None:
                self._fail_event(c.event_id, c.name, "stuck",
                                 f"{c.name} made no progress towards its target for "
                                 f"{self.config.stuck_after_s:.0f} s", out)

    def _start_groups(self, out: _Report) -> None:
        """At a step boundary: events whose members all wait on their cells start together."""
        nav = self.navigator
        queue = self._waiting_to_start
        for eid in list(queue):  # only the events not started yet: a long story has thousands of old ones
            ev = self.events[eid]
            if ev.status != "ongoing" or ev.started:
                del queue[eid]
                continue
            members = [self.characters[n] for n, s in ev.members.items() if s == "active"]
            if members and all(
                m.waiting and m.event_id == eid
                and (not m.walker or (nav.cell(m.name) == m.goal_cell and nav.can_freeze(m.name)
                                      and close_xy(nav.position(m.name), m.anchor_xy)))
                for m in members
            ):
                ev.started = True
                del queue[eid]
                out.started.append(eid)
                for m in members:
                    self._begin_transition_in(m)

    def _advance(self, out: _Report) -> None:
        nav = self.navigator
        boundary = nav.at_boundary()
        self._phase_ends(out)
        if boundary:
            self._join_walkers()
        horizon = (0, *FUTURE_FRAMES, self.config.heading_lookahead)
        nav.tick(horizon)  # walkers' positions this frame and their planned futures (read below)
        if boundary:
            self._walker_checks(out)
            self._start_groups(out)

        names = self.names
        chars = [self.characters[name] for name in names]
        n = len(names)
        dt = self.dt
        max_turn = self.config.walk_turn_rate * dt
        queries: list[MotionQuery] = []
        labels: list[str] = []
        still_feet: list[bool] = []  # sitting, sitting down, standing up: feet as animated
        heading_l: list[float] = []
        root_l: list[np.ndarray] = []
        walkers = [c for c in chars if c.walker]
        walk: dict[int, int] = {}  # id(c) -> the walker's row
        if walkers:  # the walkers' arrays in one go: planned futures, distances, future headings
            # path[:, 0]: the position now (as ticked), 1-3: the planned future, 4: the point
            # the heading turns to
            path = nav.futures([c.name for c in walkers], horizon)
            steps = path[:, 1:4] - path[:, 0:3]  # the three future steps
            wrapped, fut_h, moved = walker_headings(
                np.array([c.xy for c in walkers], dtype=float).reshape(-1, 2), path,
                np.array([c.heading for c in walkers], dtype=float), np.arctan2(steps[..., 1], steps[..., 0]), max_turn)
            h_l, moving_l = wrapped.tolist(), moved.tolist()
            now, future, fut_h = list(path[:, 0]), list(path[:, 1:4]), list(fut_h)
            walk = {id(c): i for i, c in enumerate(walkers)}
        for c in chars:  # in order: a partner's target is the partners' position so far
            i = walk.get(id(c))
            if i is not None:
                c.xy, c.heading = now[i], h_l[i]
                fut_xy, fut_heading, moving = future[i], fut_h[i], moving_l[i]
            else:
                fut_xy = fut_heading = None
                moving = False
                self._stationary_root(c)
            label, seated = phase_motion(c, moving)
            key = _database_key(label, seated)
            restart = key != c.motion_key or c.phase_frame == 0
            c.motion_key = key
            tx, tf, th = self._motion_target(c)
            queries.append(_new_query(
                label=label, seated=seated, root_xy=c.xy, heading=c.heading, future_xy=fut_xy,
                future_heading=fut_heading, target_xy=tx, target_facing=tf, seat_height=th,
                force_search=restart,
            ))
            labels.append(key)
            still_feet.append(seated or label in ("sit_down", "stand_up"))
            heading_l.append(c.heading)
            root_l.append(c.xy)
        heading = np.array(heading_l, dtype=float)
        root = np.array(root_l, dtype=float).reshape(n, 2)
        states = [self.motion_states[name] for name in names]
        step_many = getattr(self.motion, "step_many", None)
        if step_many is not None:  # a layer may batch characters (same result as one by one)
            new_states, poses = step_many(states, queries, dt)
        else:
            pairs = [self.motion.step(s, q, dt) for s, q in zip(states, queries, strict=True)]
            new_states, poses = [p[0] for p in pairs], [p[1] for p in pairs]
        self.motion_states.update(zip(names, new_states, strict=True))
        rots = np.array([p.local_rotations for p in poses], dtype=float).reshape(n, NUM_JOINTS, 3, 3)
        pz = np.array([p.pelvis[2] for p in poses], dtype=float)
        try:  # the usual case: every pose has its (2,) contact flags
            contacts = np.array([p.contacts for p in poses], dtype=bool).reshape(n, 2)
        except (AttributeError, TypeError, ValueError):
            contacts = _contacts_of(poses)
        pelvis, rots = compose_poses(rots, pz, root, heading)
        if self.foot_solver is not None and self.feet is not None:
            rots, self.feet = self.foot_solver.apply(pelvis, rots, contacts, self.feet, active=~np.array(still_feet))
        self.buffers.append(pelvis, rots, labels, contacts, [c.event_id or "" for c in chars])
        for c in chars:
            c.phase_frame += 1

    def _stationary_root(self, c: CharacterState) -> None:
        """Root xy / heading of a character that is not walking, from its phase and timer."""
        a = c.assignment
        if c.phase == "transition_in" and a is not None:
            if c.phase_frame < c.turn_frames:
                u = smoothstep((c.phase_frame + 1) / c.turn_frames)
                c.heading = wrap_angle(c.turn_from + u * wrap_angle(a.facing_angle - c.turn_from))
            else:
                c.heading = a.facing_angle
                if a.seat is not None and c.seat_xy is not None:
                    span = max(1, c.phase_length - c.turn_frames)
                    u = smoothstep((c.phase_frame - c.turn_frames + 1) / span)
                    c.xy = c.anchor_xy + u * (c.seat_xy - c.anchor_xy)
        elif c.phase == "transition_out" and c.seated and c.seat_xy is not None:
            u = smoothstep((c.phase_frame + 1) / max(1, c.phase_length))
            c.xy = c.seat_xy + u * (c.anchor_xy - c.seat_xy)

    def _motion_target(self, c: CharacterState) -> tuple[np.ndarray | None, float | None, float | None]:
        """(target xy, target facing, seat height) of the motion query."""
        a = c.assignment
        if a is None or c.phase == "approaching":
            return None, None, None
        if a.seat is not None and c.seat_xy is not None:
            height = a.seat_height
            if height is None:
                obj = self.scene.by_name[a.seat]
                height = obj.z_min - self.scene.floor_z + obj.sit_offset_vertical
            return c.seat_xy, a.facing_angle, height
        spec = action_spec(a.action)
        if spec.family == "partner" and a.partners:
            pts = np.array([self.characters[p].xy for p in a.partners if p in self.characters])
            centre = pts.mean(axis=0)
            d = c.xy - centre
            return centre, math.atan2(d[1], d[0]), None
        f = np.asarray(a.facing_xy)
        return c.anchor_xy + OBJECT_REACH * f, a.facing_angle + math.pi, None


def _contacts_of(poses: Sequence[Any]) -> np.ndarray:
    """Foot contact flags (N, 2) of poses; a layer without contact flags gives none (False)."""
    n = len(poses)
    flags = [getattr(p, "contacts", None) for p in poses]
    if all(f is not None for f in flags):
        return np.array(flags, dtype=bool).reshape(n, 2)
    contacts = np.zeros((n, 2), dtype=bool)
    for k, f in enumerate(flags):
        if f is not None:
            contacts[k] = f
    return contacts


_QUERY_FIELDS = ("label", "seated", "root_xy", "heading", "future_xy", "future_heading", "target_xy",
                 "target_facing", "seat_height", "force_search")


def _query_factory() -> Callable[..., MotionQuery]:
    """A constructor of ``MotionQuery`` from all its fields (keywords).

    ``MotionQuery`` is a frozen dataclass: its generated ``__init__`` sets each of the ten
    fields through ``object.__setattr__`` (about 3 us per query, 10 queries a frame). As long
    as it stays a plain frozen dataclass (a ``__dict__``, no ``__post_init__``, exactly these
    fields, all set by ``__init__``), filling the instance dict directly builds the same
    object (equal, same ``__dict__``) in a third of the time; otherwise the class itself is
    used.
    """
    plain = (
        dataclasses.is_dataclass(MotionQuery)
        and "__slots__" not in vars(MotionQuery)
        and not hasattr(MotionQuery, "__post_init__")
        and tuple(f.name for f in dataclasses.fields(MotionQuery)) == _QUERY_FIELDS
        and all(f.init for f in dataclasses.fields(MotionQuery))
        and MotionQuery.__new__ is object.__new__
    )
    if not plain:
        return MotionQuery
    new = object.__new__

    def make(**fields: Any) -> MotionQuery:
        q = new(MotionQuery)
        q.__dict__.update(fields)
        return q

    return make


_new_query = _query_factory()
_DATABASE_KEYS: dict[tuple[str, bool], str] = {}


def _database_key(label: str, seated: bool) -> str:
    """``database_key(label, seated)``, memoised (a pure function of its arguments)."""
    key = _DATABASE_KEYS.get((label, seated))
    if key is None:
        key = _DATABASE_KEYS[(label, seated)] = database_key(label, seated)
    return key


SEAT_DISC_SPACING = 0.4  # metres between the discs a seated body registers along its sit-down path


def seat_discs(anchor: np.ndarray, seat: np.ndarray) -> list[np.ndarray]:
    """Disc centres covering the sit-down path from ``anchor`` (standing point) to ``seat``:
    at least three, at most ``SEAT_DISC_SPACING`` apart, so walkers kept 2 body radii from
    every disc stay >= ~0.46 m (at 0.25 m radii) from the whole segment."""
    n = max(3, math.ceil(float(np.linalg.norm(seat - anchor)) / SEAT_DISC_SPACING) + 1)
    return [anchor + u * (seat - anchor) for u in np.linspace(0.0, 1.0, n)]


@dataclass
class _Report:
    completed: list[str] = field(default_factory=list)
    looping: list[str] = field(default_factory=list)
    started: list[str] = field(default_factory=list)
    failures: list[EventFailure] = field(default_factory=list)


def step(world: World, commands: Iterable[AssignEvent | ReleaseCharacters], dt: float) -> tuple[World, StepOutput]:
    """Apply ``commands`` and advance ``world`` by one frame of ``dt`` seconds (must be 1 / fps).

    Returns the same (mutated) world and what happened in the frame. Raises ``WorldError`` for
    a wrong ``dt`` or an event id that is already running; everything else the planner can get
    wrong (unknown names, busy characters, unreachable targets) comes back as failures.
    """
    if not math.isfinite(dt) or abs(dt - world.dt) > 1e-9:
        raise WorldError(f"dt must be 1/{world.config.fps} s = {world.dt:.6f} s, got {dt!r}")
    out = _Report()
    for cmd in commands:
        if isinstance(cmd, AssignEvent):
            world._apply_assign(cmd, out)
        elif isinstance(cmd, ReleaseCharacters):
            world._apply_release(cmd, out)
        else:
            raise WorldError(f"unknown command {type(cmd).__name__}; expected AssignEvent or ReleaseCharacters")
    world._advance(out)
    frame = world.frame
    world.frame += 1
    return world, StepOutput(
        frame=frame,
        completed_events=tuple(out.completed),
        looping_events=tuple(out.looping),
        started_events=tuple(out.started),
        failures=tuple(out.failures),
        available=world.available(),
    )


def run(world: World, frames: int, commands_at: Mapping[int, Sequence[AssignEvent | ReleaseCharacters]] | None = None) -> list[StepOutput]:
    """Step ``frames`` frames, applying ``commands_at[frame]`` before each; returns the outputs."""
    outs = []
    schedule = commands_at or {}
    for _ in range(frames):
        _, o = step(world, schedule.get(world.frame, ()), world.dt)
        outs.append(o)
    return outs


__all__ = ["INFINITE", "EventState", "World", "WorldConfig", "WorldError", "WorldSnapshot", "run", "step"]

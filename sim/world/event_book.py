"""Event bookkeeping of the world step: assigning events, the start queue, group starts,
completion and failure, and who is free.

Functions of an ``EventWorld`` (the parts of ``storyteller.sim.world.step.World`` they read and change:
characters, accepted events, the start queue, the navigator). The rules they keep:

- an assignment is all or nothing: when any member is unknown, busy or cannot reach its
  target, the whole event fails (one ``EventFailure`` per problem) and nobody moves;
- a member busy acting (or seated) first leaves its action through its transition out and
  takes the new assignment once standing (``CharacterState.pending``);
- a standing action that works on an object (``storyteller.sim.world.facing.needs_reach``) ends its walk
  within reach of it: a point the planner gave out of reach is replaced by the free point
  within reach nearest to it (``StandTargets.within_reach``, fallback ``out_of_reach``);
- an event waits in the start queue (``start_queue``, in ``events`` order; a reused id keeps
  its old place, as a dict does) until all its active members wait on their points at a
  planning-step boundary; then all start their transition in on the same frame, each turning
  from where it stands to its partners, else to the object it uses, else to the planner's
  facing (``act_yaw``; seated: the planner's facing, turned on a seat with no back whose
  legroom other furniture takes, ``storyteller.sim.world.legroom``). A seated body registers discs along its
  sit-down path (``seat_discs``);
- an event completes when every member has finished its action (or, acting a looping action,
  left it); it becomes *looping* when every member is done or acting a looping action;
- characters without an event, or in a looping one, are free (``free_characters``).

Deterministic: no randomness, no clock; events are visited in the order they were accepted.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal, Protocol

import numpy as np

from storyteller.sim.motion.action_labels import action_spec
from storyteller.sim.paths.following import close_xy
from storyteller.sim.paths.nav_grid import NavGrid
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.world.errors import WorldError
from storyteller.sim.world.events import (
    AssignEvent,
    Assignment,
    EventFailure,
    FailureReason,
    ReleaseCharacters,
)
from storyteller.sim.world.facing import heading_to_object, heading_to_points, needs_reach, surface_distance
from storyteller.sim.world.legroom import along_way, sit_via, sitting_yaw
from storyteller.sim.world.navigation import StandTargets, WorldNavigator, seat_place
from storyteller.sim.world.partners import spaced
from storyteller.sim.world.phases import (
    CharacterState,
    StandTarget,
    available,
    transition_in_frames,
    transition_out_frames,
    turn_heading,
)

EventStatus = Literal["ongoing", "looping", "completed", "failed"]
MemberStatus = Literal["active", "done", "left"]
"""active: still on the way or acting; done: finished its part; left: gave up or was
reassigned."""


@dataclass
class EventState:
    """One accepted event and the status of each member (by name)."""

    event: AssignEvent
    members: dict[str, MemberStatus]
    status: EventStatus = "ongoing"
    started: bool = False


@dataclass
class StepReport:
    """What happened to events in one frame (collected into ``StepOutput``)."""

    completed: list[str] = field(default_factory=list)
    looping: list[str] = field(default_factory=list)
    started: list[str] = field(default_factory=list)
    failures: list[EventFailure] = field(default_factory=list)


class EventRules(Protocol):
    """The settings event bookkeeping reads (``sim.world.step.WorldConfig`` has them)."""

    @property
    def fps(self) -> int: ...

    @property
    def max_target_offset(self) -> float: ...


class EventWorld(Protocol):
    """The parts of a world that event bookkeeping reads and changes."""

    @property
    def config(self) -> EventRules: ...

    scene: Scene
    grid: NavGrid
    names: tuple[str, ...]
    navigator: WorldNavigator
    targets: StandTargets
    characters: dict[str, CharacterState]
    events: dict[str, EventState]
    start_queue: dict[str, None]


def unstarted(events: dict[str, EventState]) -> dict[str, None]:
    """The start queue of ``events``: the ongoing, not started ones, in order."""
    return {eid: None for eid, ev in events.items() if ev.status == "ongoing" and not ev.started}


SEAT_DISC_SPACING = 0.4  # metres between the discs a seated body registers along its sit-down path


def seat_discs(anchor: np.ndarray, seat: np.ndarray, via: np.ndarray | None = None) -> list[np.ndarray]:
    """Disc centres covering the sit-down path from ``anchor`` (standing point) to ``seat`` (by
    the corner ``via`` when given: ``storyteller.sim.world.legroom.sit_via``): at least three, at most
    ``SEAT_DISC_SPACING`` apart, so walkers kept 2 body radii from every disc stay >= ~0.46 m (at
    0.25 m radii) from the whole path."""
    if via is None:
        n = max(3, math.ceil(float(np.linalg.norm(seat - anchor)) / SEAT_DISC_SPACING) + 1)
        return [anchor + u * (seat - anchor) for u in np.linspace(0.0, 1.0, n)]
    length = float(np.linalg.norm(via - anchor) + np.linalg.norm(seat - via))
    n = max(3, math.ceil(length / SEAT_DISC_SPACING) + 1)
    return [along_way(anchor, via, seat, float(u)) for u in np.linspace(0.0, 1.0, n)]


def _fail(out: StepReport, event_id: str, character: str, reason: FailureReason, message: str) -> None:
    out.failures.append(EventFailure(event_id=event_id, character=character, reason=reason, message=message))


def taken_points(w: EventWorld, skip: Iterable[str]) -> list[tuple[float, float]]:
    """Where the characters not in ``skip`` stand or will stand for their events: the end of
    their walk and the cell centre they step onto it from, and for a seated one the discs of
    its sit-down path (metres)."""
    out: list[tuple[float, float]] = []
    gone = set(skip)
    for o in w.characters.values():
        if o.name in gone or o.event_id is None or o.target is None:
            continue
        out.extend(_body_points(o.target, o.assignment, w))
    return out


def _body_points(target: StandTarget, a: Assignment | None, w: EventWorld) -> list[tuple[float, float]]:
    """A body at ``target`` (its cell centre and its point) and, when ``a`` sits, the discs
    of its way onto the seat."""
    cell = w.grid.center_of(*target.cell)
    out = [(float(cell[0]), float(cell[1])), (float(target.xy[0]), float(target.xy[1]))]
    if a is not None and a.seat is not None and a.seat in w.scene.by_name:
        obj = w.scene.by_name[a.seat]
        seat = np.asarray(seat_place(obj, a.target_xy, w.scene))
        anchor = np.asarray(target.xy, dtype=float)
        via = sit_via(obj, w.scene.objects, anchor, seat)
        out += [(float(p[0]), float(p[1])) for p in seat_discs(anchor, seat, via)[1:]]
    return out


def stand_target_for(w: EventWorld, c: CharacterState, a: Assignment,
                     avoid: Sequence[tuple[float, float]] = ()) -> tuple[StandTarget | None, str]:
    """Where ``a``'s walk ends (see ``StandTargets``), or (None, why not). A seat's approach
    point keeps two body radii from the points of ``avoid`` when it can (others' bodies); so
    does a point within reach that stands in for one out of reach of the object ``a`` works on."""
    g = w.grid
    here = w.navigator.cell(c.name) if w.navigator.is_walker(c.name) else c.anchor_cell
    comp = int(g.component[here]) if g.is_free(*here) else g.main_component
    if a.seat is not None:
        obj = w.scene.by_name[a.seat]
        target = w.targets.seated(w.navigator, obj, comp, seat_place(obj, a.target_xy, w.scene), avoid)
        if target is None:
            return None, f"{c.name} cannot reach a free cell in front of {a.seat}"
        return target, ""
    p = np.asarray(a.target_xy, dtype=float)
    target = w.targets.standing(w.navigator, p, comp)
    off = math.inf if target is None else float(np.linalg.norm(np.asarray(target.xy) - p))
    if target is None or off > w.config.max_target_offset:
        return None, (f"{c.name} cannot reach ({a.target_xy[0]:.2f}, {a.target_xy[1]:.2f}): the nearest "
                      f"reachable floor is {off:.2f} m away")
    used = reach_object(w, a)
    if used is not None and not w.targets.reaches(used, comp, target.xy):
        near = w.targets.within_reach(used, comp, a.target_xy, [*avoid, *still_bodies(w, (c.name,))])
        if near is not None:
            gap = surface_distance(used, target.xy)
            return replace(near, message=(
                f"({target.xy[0]:.2f}, {target.xy[1]:.2f}) is {gap:.2f} m from {used.name}, out of reach; "
                f"{c.name} stands at ({near.xy[0]:.2f}, {near.xy[1]:.2f}) instead")), ""
    return target, ""


def reach_object(w: EventWorld, a: Assignment) -> SceneObject | None:
    """The object a standing assignment works on with its hands (``needs_reach``), else None."""
    if a.seat is not None or a.focus is None or a.focus not in w.scene.by_name or not needs_reach(a.action):
        return None
    return w.scene.by_name[a.focus]


def still_bodies(w: EventWorld, skip: Iterable[str]) -> list[tuple[float, float]]:
    """Where the characters not in ``skip`` that are not walking to a goal stand (metres)."""
    gone = set(skip)
    return [(float(o.xy[0]), float(o.xy[1])) for o in w.characters.values()
            if o.name not in gone and o.phase != "approaching"]


def assign(w: EventWorld, cmd: AssignEvent, out: StepReport) -> None:
    """Accept ``cmd`` (its members start walking or leave what they do) or fail it as a whole;
    a pair doing a partner action is first sent to points at the action's distance
    (``storyteller.sim.world.partners.spaced``). Raises ``WorldError`` when an event with its id is still running."""
    eid = cmd.event_id
    if eid in w.events and w.events[eid].status in ("ongoing", "looping"):
        raise WorldError(f"event {eid!r} is already running")
    cmd = spaced(w.grid, cmd)  # a pair doing a partner action stands at the action's distance
    goals: dict[str, StandTarget] = {}
    problems: list[tuple[str, FailureReason, str]] = []
    # where other bodies will be, for the seats' approach points (members placed so far included)
    taken = taken_points(w, cmd.characters) if any(
        a.seat is not None or (a.focus is not None and a.focus in w.scene.by_name and needs_reach(a.action))
        for a in cmd.assignments) else None
    for a in cmd.assignments:
        if a.character not in w.characters:
            problems.append((a.character, "unknown_character", f"no character called {a.character!r}"))
            continue
        unknown = [p for p in a.partners if p not in w.characters]
        if unknown:
            problems.append((a.character, "unknown_character", f"unknown partners {unknown}"))
            continue
        if a.seat is not None and a.seat not in w.scene.by_name:
            problems.append((a.character, "unknown_seat", f"no object called {a.seat!r} in the scene"))
            continue
        if a.focus is not None and a.focus not in w.scene.by_name:
            problems.append((a.character, "unknown_object", f"no object called {a.focus!r} in the scene"))
            continue
        if not is_free(w, a.character):
            problems.append((a.character, "busy", f"{a.character} is busy with event "
                             f"{w.characters[a.character].event_id!r}"))
            continue
        goal, why = stand_target_for(w, w.characters[a.character], a, [] if taken is None else taken)
        if goal is None:
            problems.append((a.character, "no_path", why))
            continue
        goals[a.character] = goal
        if taken is not None:  # the next members keep clear of this one
            taken.extend(_body_points(goal, a, w))
    if problems:
        for name, reason, msg in problems:
            _fail(out, eid, name, reason, msg)
        w.events[eid] = EventState(cmd, {a.character: "left" for a in cmd.assignments}, status="failed")
        return
    reused = eid in w.events
    w.events[eid] = EventState(cmd, {a.character: "active" for a in cmd.assignments})
    if reused:  # a dict keeps a reused key where it was: so does the start queue
        w.start_queue = unstarted(w.events)
    else:
        w.start_queue[eid] = None
    for a in cmd.assignments:
        c = w.characters[a.character]
        _leave_event(w, c, out)
        c.pending = None
        _start(w, c, eid, a, goals[a.character])


def release(w: EventWorld, cmd: ReleaseCharacters, out: StepReport) -> None:
    """The characters leave their events and stop (standing up first when seated)."""
    for name in cmd.characters:
        c = w.characters.get(name)
        if c is None:
            _fail(out, "release", name, "unknown_character", f"no character called {name!r}")
            continue
        _leave_event(w, c, out)
        c.pending = None
        _stop(w, c)


def _start(w: EventWorld, c: CharacterState, eid: str, a: Assignment, goal: StandTarget) -> None:
    """Give ``c`` its new assignment: walk now, or first leave what it is doing."""
    c.event_id = eid
    c.waiting = False
    if c.phase in ("transition_in", "interacting", "transition_out") or c.seated:
        c.pending = (eid, a, goal)
        if c.phase != "transition_out":
            _begin_transition_out(c, w.config.fps)
        return
    take(c, a, goal)
    c.enter("approaching")
    if c.walker:
        w.navigator.set_goal(c.name, goal.cell, final_xy=final_of(goal))
    # else: joins the navigator at the next step boundary (``World._join_walkers``)


def final_of(target: StandTarget | None) -> np.ndarray | None:
    """The exact end point to give the navigator (None: the goal cell's centre)."""
    return np.asarray(target.xy, dtype=float) if target is not None and target.off_grid else None


def take(c: CharacterState, a: Assignment, goal: StandTarget) -> None:
    """``c`` takes assignment ``a`` with the walk ending on ``goal`` (progress counters reset)."""
    c.assignment, c.goal_cell, c.target = a, goal.cell, goal
    c.action_done = False
    c.best_distance, c.stalled_frames = math.inf, 0
    c.act_yaw, c.replans, c.seat_via = None, 0, None


def _stop(w: EventWorld, c: CharacterState) -> None:
    """End whatever ``c`` does and become idle (standing up first when seated)."""
    was_waiting, c.waiting = c.waiting, False
    if c.phase in ("transition_in", "interacting") or (c.phase == "idle" and c.seated):
        _begin_transition_out(c, w.config.fps)
    elif c.phase == "approaching" or was_waiting:
        c.enter("idle")
        if c.walker:
            w.navigator.set_goal(c.name, None)


def _begin_transition_out(c: CharacterState, fps: int) -> None:
    if c.phase == "transition_in" and c.assignment is not None and c.assignment.seat is not None:
        c.seated = c.phase_frame > c.turn_frames  # stopped while sitting down: stand up
        c.seat_xy = c.xy.copy()
    c.enter("transition_out", transition_out_frames(c.seated, fps))
    c.turn_from = c.heading


def _leave_event(w: EventWorld, c: CharacterState, out: StepReport) -> None:
    ev = w.events.get(c.event_id) if c.event_id is not None else None
    if ev is not None and ev.members.get(c.name) in ("active", "done"):
        ev.members[c.name] = "left"
        _update_event(w, ev.event.event_id, ev, out)
    c.event_id = None


def _update_event(w: EventWorld, eid: str, ev: EventState, out: StepReport) -> None:
    if ev.status in ("completed", "failed"):
        return
    states = ev.members
    if any(s == "active" for s in states.values()):
        return
    looping = [n for n, s in states.items() if s == "done" and w.characters[n].event_id == eid
               and w.characters[n].phase == "interacting" and w.characters[n].loops]
    if looping:
        if ev.status != "looping":
            ev.status = "looping"
            out.looping.append(eid)
        return
    ev.status = "completed"
    out.completed.append(eid)
    for n in states:
        if w.characters[n].event_id == eid:
            w.characters[n].event_id = None


def fail_event(w: EventWorld, eid: str, character: str, reason: FailureReason, message: str, out: StepReport) -> None:
    """Event ``eid`` fails because of ``character``; members still walking or waiting stop."""
    ev = w.events[eid]
    ev.status = "failed"
    _fail(out, eid, character, reason, message)
    for n in ev.members:
        c = w.characters[n]
        if c.event_id != eid:
            continue
        c.event_id = None
        if c.phase in ("approaching",) or c.waiting:
            c.waiting = False
            c.assignment = None
            c.enter("idle")
            if c.walker:
                w.navigator.set_goal(n, None)


def act_yaw(w: EventWorld, c: CharacterState, a: Assignment, stand: dict[str, np.ndarray]) -> float | None:
    """The yaw ``c`` acts with from its standing point ``c.anchor_xy`` (None: the planner's
    facing ``a.facing_xy``): a standing partner action faces the mean of its partners' points
    (``stand``: where members starting now stand; others where they are), else a standing
    action with an object faces the object's nearest footprint point; seated: the planner's
    facing, or turned from it on a seat with no back whose legroom other furniture takes
    (``storyteller.sim.world.legroom.sitting_yaw``)."""
    if a.seat is not None:
        seat = w.scene.by_name.get(a.seat)
        if seat is None:
            return None
        return sitting_yaw(seat, w.scene.objects, seat_place(seat, a.target_xy, w.scene), a.facing_angle, c.anchor_xy)
    if a.partners and action_spec(a.action).family == "partner":
        pts = [stand[p] if p in stand else w.characters[p].xy for p in a.partners if p in w.characters]
        yaw = heading_to_points(c.anchor_xy, np.asarray(pts, dtype=float))
        if yaw is not None:
            return yaw
    if a.focus is not None and a.focus in w.scene.by_name:
        return heading_to_object(w.scene.by_name[a.focus], c.anchor_xy)
    return None


def _begin_transition_in(w: EventWorld, c: CharacterState, yaw: float | None = None) -> None:
    """``c`` starts turning (from where it stands, about its pelvis) to ``yaw`` (None: the
    planner's facing), then sits down when its assignment sits."""
    a = c.assignment
    assert a is not None
    c.waiting = False
    c.turn_from = c.heading
    c.act_yaw = yaw
    c.turn_frames, total = transition_in_frames(a, c.heading, w.config.fps, turn_heading(c))
    c.enter("transition_in", total)
    c.xy = c.anchor_xy.copy()
    c.walker = False
    if a.seat is not None:
        seat = w.scene.by_name[a.seat]
        c.seat_xy = np.asarray(seat_place(seat, a.target_xy, w.scene), dtype=float)
        others = np.array([o.xy for o in w.characters.values() if o.name != c.name], dtype=float).reshape(-1, 2)
        c.seat_via = sit_via(seat, w.scene.objects, c.anchor_xy, c.seat_xy, others)
        w.navigator.make_stationary(c.name, seat_discs(c.anchor_xy, c.seat_xy, c.seat_via))
    else:
        w.navigator.make_stationary(c.name, [c.anchor_xy])


def member_done(w: EventWorld, c: CharacterState, out: StepReport) -> None:
    """``c`` finished its action (or started a looping one): its event may complete or loop."""
    c.action_done = True
    eid = c.event_id
    ev = w.events.get(eid) if eid is not None else None
    if eid is not None and ev is not None and ev.members.get(c.name) == "active":
        ev.members[c.name] = "done"
        _update_event(w, eid, ev, out)


def start_groups(w: EventWorld, out: StepReport) -> None:
    """At a step boundary: events whose members all wait on their cells start together."""
    nav = w.navigator
    queue = w.start_queue
    for eid in list(queue):  # only the events not started yet: a long story has thousands of old ones
        ev = w.events[eid]
        if ev.status != "ongoing" or ev.started:
            del queue[eid]
            continue
        members = [w.characters[n] for n, s in ev.members.items() if s == "active"]
        if members and all(
            m.waiting and m.event_id == eid
            and (not m.walker or (nav.cell(m.name) == m.goal_cell and nav.can_freeze(m.name)
                                  and close_xy(nav.position(m.name), m.anchor_xy)))
            for m in members
        ):
            ev.started = True
            del queue[eid]
            out.started.append(eid)
            stand = {m.name: m.anchor_xy for m in members}
            yaws = [None if m.assignment is None else act_yaw(w, m, m.assignment, stand) for m in members]
            for m, yaw in zip(members, yaws, strict=True):
                _begin_transition_in(w, m, yaw)


def free_characters(w: EventWorld) -> tuple[str, ...]:
    """Characters the narrator may give a new event (see ``storyteller.sim.world.phases.available``)."""
    return tuple(name for name in w.names if is_free(w, name))


def is_free(w: EventWorld, name: str) -> bool:
    """Whether ``name`` is one of ``free_characters(w)`` (one character: O(1), so that accepting
    an event does not visit the whole crowd)."""
    c = w.characters[name]
    if c.event_id is None:  # no event: free (available(c, False))
        return True
    ev = w.events.get(c.event_id)
    return available(c, ev is not None and ev.status == "ongoing")

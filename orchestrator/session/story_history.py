"""The planner's view of the story: the roster, the characters' commitments and the history
window a planning request carries, built from the world and the story's events.

:func:`history_window` is the one place the session cuts the story to
:data:`~storyteller.agents.history.HISTORY_WINDOW` events (the ones before folded into an
:class:`~storyteller.agents.messages.EarlierEvents` summary); :func:`planning_request` puts a step's request
together from it; :func:`apply_step_output` moves the story's events on with what a simulated
frame reports. Pure functions of their inputs: no clock, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

from storyteller.agents.history import HISTORY_WINDOW
from storyteller.agents.instruction_parts import PART_ATTEMPTS
from storyteller.agents.messages import (
    CharacterStatus,
    EarlierEvents,
    HistoryEntry,
    ParsedEvent,
    PlanningFailure,
)
from storyteller.agents.narrator_words import narration
from storyteller.agents.story_text import event_text
from storyteller.orchestrator.session.session_types import Outcome, PlanningRequest, StoryEvent
from storyteller.orchestrator.session.steps_in_flight import Flight
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.events import EventFailure, StepOutput
from storyteller.sim.world.step import World


def world_roster(world: World, events: dict[str, StoryEvent]) -> tuple[CharacterStatus, ...]:
    """The planner's view of every character at the world's current frame."""
    free = set(world.available())
    out = []
    for name in world.names:
        c = world.characters[name]
        a = c.assignment
        event = events.get(c.event_id) if c.event_id is not None else None
        busy = name not in free
        out.append(
            CharacterStatus(
                name=name,
                busy=busy,
                action=a.action if a is not None and c.phase != "idle" else "idle",
                position=(round(float(c.xy[0]), 3), round(float(c.xy[1]), 3)),
                facing=(round(math.cos(c.heading), 3), round(math.sin(c.heading), 3)),
                event_index=event.index if (busy and event is not None) else None,
                seat=a.seat if (a is not None and c.seated) else None,
            )
        )
    return tuple(out)


def world_commitments(world: World) -> tuple[dict[str, tuple[float, float]], dict[str, str]]:
    """Targets of characters with an assignment, and seats taken or about to be taken. A
    character given a new event while it still sits or acts stands up first and keeps the new
    assignment aside (``pending``): that one is where it is heading, and its seat is about to be
    taken (the old seat shows as taken in the roster until the character has left it)."""
    targets: dict[str, tuple[float, float]] = {}
    seats: dict[str, str] = {}
    for name in world.names:
        c = world.characters[name]
        a = c.pending[1] if c.pending is not None else c.assignment
        if a is None or c.event_id is None:
            continue
        targets[name] = (round(a.target_xy[0], 3), round(a.target_xy[1], 3))
        if a.seat is not None:
            seats[a.seat] = name
    return targets, seats


def story_history(
    events: dict[str, StoryEvent], outcomes: Sequence[tuple[int, Outcome]] = ()
) -> tuple[HistoryEntry, ...]:
    """The narrator's history: the latest ``HISTORY_WINDOW`` of the applied events and the steps
    whose event could not be placed (``failed``, like an event that failed in the simulation:
    its part stays open). See :func:`history_window` for the ones before."""
    return history_window(events, outcomes)[0]


_Row = tuple[int, tuple[str, ...], str, str, str]  # index, characters, activity, state, part


def history_window(
    events: dict[str, StoryEvent], outcomes: Sequence[tuple[int, Outcome]] = (), pending: Sequence[HistoryEntry] = (),
    *, since: int = 0,
) -> tuple[tuple[HistoryEntry, ...], EarlierEvents | None]:
    """(the history of :func:`story_history`, with ``pending`` (steps in flight whose event is
    known) among the events; the events before it summarised, None when there are none).

    Events older than the window that were planned for a part of the current instruction
    (index >= ``since``) stay in it: per part, its latest event that was not a failure and up
    to ``PART_ATTEMPTS`` failures, so the instruction's progress (``part_states``) still sees
    a part done or given up hours later. The narrator shows only its latest events; the others
    are counted with the summary. Linear in the story's length with a small constant: entries
    are built for the window and those kept rows only."""
    rows: list[_Row] = [(e.index, e.characters, e.activity, e.state, e.part) for e in events.values()]
    rows += [
        (i, o.event.characters, o.event.activity, "failed", o.part)
        for i, o in outcomes
        if isinstance(o, PlanningFailure) and o.event is not None and o.event.characters
    ]
    rows += [(h.index, h.characters, h.activity, h.state, h.part) for h in pending]
    rows.sort(key=lambda r: r[0])
    cut = max(0, len(rows) - HISTORY_WINDOW)
    kept = _part_rows(rows[:cut], since)
    kept_set = set(kept)
    window = tuple(
        HistoryEntry(index=i, characters=chars, activity=activity, state=state, part=part)
        for i, chars, activity, state, part in (*kept, *rows[cut:])
    )
    return window, EarlierEvents.fold(None, ((r[1], r[2]) for r in rows[:cut] if r not in kept_set))


def _part_rows(rows: Sequence[_Row], since: int) -> list[_Row]:
    """The rows of ``rows`` (oldest first) that the instruction's progress needs: per part of
    the instruction, its latest row that is not a failure and its last ``PART_ATTEMPTS``
    failures (see :func:`history_window`)."""
    latest: dict[str, _Row] = {}
    failures: dict[str, list[_Row]] = {}
    for row in rows:
        if row[0] < since or not row[4]:
            continue
        if row[3] == "failed":
            failures.setdefault(row[4], []).append(row)
        else:
            latest[row[4]] = row
    kept = [*latest.values(), *(r for rs in failures.values() for r in rs[-PART_ATTEMPTS:])]
    return sorted(kept, key=lambda r: r[0])


def planning_request(
    world: World,
    events: dict[str, StoryEvent],
    outcomes: Sequence[tuple[int, Outcome]],
    claimed: Mapping[str, Flight],
    *,
    index: int,
    instruction: str,
    since: int,
) -> PlanningRequest:
    """The request for step ``index``, from the world now; the characters of the steps in flight
    (``claimed``: character -> its step) show as busy with their event, which shows as ongoing in
    the history."""
    targets, seats = world_commitments(world)
    roster = world_roster(world, events)
    pending: list[HistoryEntry] = []
    if claimed:
        roster = tuple(
            c.model_copy(update={"busy": True, "event_index": claimed[c.name].request.index})
            if c.name in claimed else c
            for c in roster
        )
        pending = [
            HistoryEntry(
                index=fl.request.index, characters=fl.claim, activity=fl.activity, state="ongoing", part=fl.part
            )
            for fl in sorted({f.request.index: f for f in claimed.values()}.values(), key=lambda f: f.request.index)
            if fl.claim
        ]
    history, earlier = history_window(events, outcomes, pending, since=since)
    return PlanningRequest(
        index=index,
        frame=world.frame,
        roster=roster,
        history=history,
        earlier=earlier,
        targets=targets,
        objects_in_use=seats,
        instruction=instruction,
        instruction_since=since,
    )


def applied_event(event_id: str, request: PlanningRequest, outcome: ParsedEvent, frame: int, scene: Scene) -> StoryEvent:
    """The story's record of ``outcome``'s event, applied at ``frame`` (ongoing, from then on)."""
    return StoryEvent(
        index=request.index,
        event_id=event_id,
        characters=tuple(outcome.event.characters),
        activity=outcome.event.activity,
        requested_frame=request.frame,
        applied_frame=frame,
        part=outcome.part,
        text=event_text(outcome, scene),
        narration=narration(outcome, scene),
    )


def apply_step_output(
    events: dict[str, StoryEvent],
    failures: list[EventFailure],
    out: StepOutput,
    on_event: Callable[[StoryEvent], None] | None,
) -> int:
    """Move ``events`` on with what frame ``out`` reports (looping, completed, failed; a failure
    is also appended to ``failures``), calling ``on_event`` for each event that finished; returns
    how many such changes the frame reported."""
    changes = len(out.looping_events) + len(out.completed_events) + len(out.failures)
    for eid in out.looping_events:
        if eid in events and events[eid].state == "ongoing":
            events[eid].state = "looping"
    for eid in out.completed_events:
        if eid in events:
            events[eid].state = "completed"
            events[eid].finished_frame = out.frame
            if on_event is not None:
                on_event(events[eid])
    for failure in out.failures:
        failures.append(failure)
        ev = events.get(failure.event_id)
        if ev is not None and ev.state != "failed":
            ev.state = "failed"
            ev.failure = failure.message
            ev.finished_frame = out.frame
            if on_event is not None:
                on_event(ev)
    return changes

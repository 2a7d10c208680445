"""What a running story looks like now, for a live view: fed by the session's happenings.

:class:`RunStatus` hears what the run already reports (the session's ``on_event``,
``on_outcome``, ``on_instruction`` and ``on_frame``; the LLM port's calls, through
``storyteller.orchestrator.llm.watched_port``) and answers :meth:`RunStatus.snapshot`: the simulated
clock and speed, one row per character (its state, event, action and place), the LLM calls in
flight per role and for how long, calls and tokens so far, and the events by state.

Cheap where the simulation pays: every happening is O(1) (``frame`` keeps a reference to the
world, nothing more); the per-character work is done by :meth:`~RunStatus.snapshot`, which a
view calls a few times a second on the event loop, between two frames, so the world it reads
is never half-stepped. Nothing here renders or prints: the text it returns is data (names,
activities and places from the user or a model) and the view escapes it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Literal

from storyteller.agents.llm_port import NodeName, TokenUsage
from storyteller.agents.messages import ParsedEvent
from storyteller.agents.story_text import place_text
from storyteller.orchestrator.session.session_types import Outcome, StoryEvent, TimedInstruction, event_id_for
from storyteller.sim.world.event_book import EventStatus
from storyteller.sim.world.phases import CharacterState
from storyteller.sim.world.step import World

CharacterActivity = Literal["idle", "seated", "waiting", "walking", "starting", "acting", "finishing"]
"""What a character is doing: ``idle`` (no event, standing), ``seated`` (no event, on a seat),
``waiting`` (at its point, for the others of its event), ``walking`` (to its point), ``starting``
(turning to face, sitting down), ``acting`` (its action), ``finishing`` (leaving it, standing up)."""

ROLE_ORDER: tuple[NodeName, ...] = ("describer", "narrator", "event_parser", "planner")


def character_activity(c: CharacterState) -> CharacterActivity:
    """The state a person reads, from the world's phase of ``c``."""
    if c.phase == "approaching":
        return "walking"
    if c.phase == "transition_in":
        return "starting"
    if c.phase == "interacting":
        return "acting"
    if c.phase == "transition_out":
        return "finishing"
    if c.waiting:
        return "waiting"
    return "seated" if c.seated else "idle"


@dataclass(frozen=True)
class CharacterRow:
    """One character now. ``event_id`` / ``activity`` / ``action`` / ``place``: its current
    event, what the event is (its plan sentence), its own action label and where, in words ("on
    the couch", ``agents.story_text.place_text``); empty without one."""

    name: str
    state: CharacterActivity
    event_id: str = ""
    activity: str = ""
    action: str = ""
    place: str = ""


@dataclass(frozen=True)
class RoleCalls:
    """The LLM calls of one role (node): ``in_flight`` now, the oldest of them running for
    ``longest_s`` wall seconds; ``calls`` ended so far (answered or failed; a call cancelled
    when the story ended or stopped is not counted), ``failed`` of them without an answer; the
    tokens of the answers."""

    role: str
    in_flight: int = 0
    longest_s: float = 0.0
    calls: int = 0
    failed: int = 0
    prompt_tokens: int = 0
    completion_tokens: int = 0


@dataclass(frozen=True)
class RunSnapshot:
    """A run at one moment. ``frames``: the story's length; ``speed``: simulated seconds per
    wall second since the session started (None before a frame ran); ``events``: applied
    events by state; ``steps``: planning steps applied (events, waits, failures)."""

    frame: int = 0
    frames: int = 0
    fps: int = 30
    pace: str = ""
    wall_s: float = 0.0
    speed: float | None = None
    started: bool = False
    characters: tuple[CharacterRow, ...] = ()
    roles: tuple[RoleCalls, ...] = ()
    events: tuple[tuple[EventStatus, int], ...] = ()
    steps: int = 0
    instruction: str = ""

    def count(self, state: EventStatus) -> int:
        return dict(self.events).get(state, 0)

    @property
    def prompt_tokens(self) -> int:
        return sum(r.prompt_tokens for r in self.roles)

    @property
    def completion_tokens(self) -> int:
        return sum(r.completion_tokens for r in self.roles)

    @property
    def calls(self) -> int:
        return sum(r.calls for r in self.roles)

    @property
    def in_flight(self) -> int:
        return sum(r.in_flight for r in self.roles)


@dataclass
class _Tally:
    calls: int = 0
    failed: int = 0
    prompt_tokens: int = 0
    completion_tokens: int = 0


class RunStatus:
    """The live state of one run (see the module doc). ``clock``: wall seconds (injectable)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.clock = clock
        self._world: World | None = None
        self._frames = 0
        self._pace = ""
        self._t0 = 0.0
        self._frame0 = 0
        self._instruction = ""
        self._activity: dict[str, str] = {}  # event id -> its plan sentence (StoryEvent.text)
        self._places: dict[str, dict[str, str]] = {}  # event id -> character -> place
        self._states: dict[str, EventStatus] = {}  # event id -> its state now
        self._counts: dict[EventStatus, int] = {}
        self._steps = 0
        self._flying: dict[int, tuple[NodeName, float]] = {}  # call id -> (role, started at)
        self._next_call = 0
        self._roles: dict[str, _Tally] = {}

    # ----- the session's happenings -------------------------------------------------------
    def started(self, world: World, *, frames: int, pace: str, instruction: str,
                events: Iterable[StoryEvent] = (), outcomes: Iterable[tuple[int, Outcome]] = ()) -> None:
        """The session starts at ``world.frame`` (a resume: its checkpoint's, with the ``events``
        and step ``outcomes`` of the story so far)."""
        self._world = world
        self._frames = frames
        self._pace = pace
        self._instruction = instruction
        self._t0 = self.clock()
        self._frame0 = world.frame
        for index, outcome in outcomes:
            self.outcome(index, outcome, world.frame)
        for event in events:
            self.event(event)

    def frame(self, world: World) -> None:
        """A frame was stepped (called every frame: keeps a reference, nothing more)."""
        self._world = world

    def event(self, event: StoryEvent) -> None:
        """An event started, loops, completed or failed."""
        eid = event.event_id
        self._activity[eid] = event.text
        before = self._states.get(eid)
        if before is not None:
            self._counts[before] -= 1
        self._states[eid] = event.state
        self._counts[event.state] = self._counts.get(event.state, 0) + 1

    def outcome(self, index: int, outcome: Outcome, frame: int) -> None:
        """A planning step's outcome was applied (the places of its event's characters)."""
        self._steps += 1
        if isinstance(outcome, ParsedEvent):
            scene = self._world.scene if self._world is not None else None
            self._places[event_id_for(index)] = {
                p.character: place_text(p, scene) for p in outcome.plans
            }

    def instruction(self, timed: TimedInstruction) -> None:
        self._instruction = timed.text

    # ----- the LLM port's calls (a CallWatcher) -------------------------------------------
    def call_started(self, node: NodeName) -> int:
        call = self._next_call
        self._next_call += 1
        self._flying[call] = (node, self.clock())
        return call

    def call_finished(self, call: int, usage: TokenUsage | None) -> None:
        flying = self._flying.pop(call, None)
        if flying is None:
            return
        tally = self._roles.setdefault(flying[0], _Tally())
        tally.calls += 1
        if usage is None:
            tally.failed += 1
        else:
            tally.prompt_tokens += usage.prompt_tokens
            tally.completion_tokens += usage.completion_tokens

    def call_cancelled(self, call: int) -> None:
        self._flying.pop(call, None)

    # ----- for a view ---------------------------------------------------------------------
    def snapshot(self) -> RunSnapshot:
        """The run now (a few times a second; linear in the characters and the calls in flight)."""
        now = self.clock()
        world = self._world
        if world is None:
            return RunSnapshot(roles=self._role_rows(now), instruction=self._instruction)
        wall = max(0.0, now - self._t0)
        fps = world.config.fps
        simulated = (world.frame - self._frame0) / fps
        return RunSnapshot(
            frame=world.frame,
            frames=self._frames,
            fps=fps,
            pace=self._pace,
            wall_s=wall,
            speed=simulated / wall if wall > 0 and world.frame > self._frame0 else None,
            started=True,
            characters=tuple(self._character_row(name, world.characters[name]) for name in world.names),
            roles=self._role_rows(now),
            events=tuple((s, n) for s, n in self._counts.items() if n),
            steps=self._steps,
            instruction=self._instruction,
        )

    def _character_row(self, name: str, c: CharacterState) -> CharacterRow:
        state = character_activity(c)
        eid = c.event_id
        if eid is None:
            return CharacterRow(name, state)
        action = c.assignment.action if c.assignment is not None else ""
        place = self._places.get(eid, {}).get(name, "")
        if not place and c.assignment is not None and c.assignment.seat is not None:
            place = f"on {c.assignment.seat}"
        return CharacterRow(name, state, eid, self._activity.get(eid, ""), action, place)

    def _role_rows(self, now: float) -> tuple[RoleCalls, ...]:
        flying: dict[str, list[float]] = {}
        for node, since in self._flying.values():
            flying.setdefault(node, []).append(now - since)
        order: dict[str, int] = {r: i for i, r in enumerate(ROLE_ORDER)}
        rows = []
        for name in sorted(set(self._roles) | set(flying), key=lambda r: (order.get(r, len(order)), r)):
            t = self._roles.get(name, _Tally())
            ages = flying.get(name, [])
            rows.append(RoleCalls(name, len(ages), max(ages, default=0.0), t.calls, t.failed,
                                  t.prompt_tokens, t.completion_tokens))
        return tuple(rows)

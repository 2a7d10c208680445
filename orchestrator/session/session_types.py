"""The story session's data types: what it asks its planner, what it is told, what it returns.

A planning step is asked with a :class:`PlanningRequest` (the world as of one frame) and answers
with an :data:`Outcome`; instructions take effect as :class:`TimedInstruction`, overlapping
steps are requested as :class:`RecordedRequest` (what a replay reads back). The story keeps one
:class:`StoryEvent` per applied event; :class:`SessionSettings` configures a
:class:`~storyteller.orchestrator.session.runtime.Session`, :class:`SessionResult` is what it returns and
:class:`SessionCheckpoint` is what it goes on from. Plain data, no behaviour: the checkpoint
file (``storyteller.orchestrator.session.snapshot_file``) stores these classes by their import path here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field

from storyteller.agents.messages import (
    CharacterStatus,
    EarlierEvents,
    HistoryEntry,
    ParsedEvent,
    PlanningFailure,
)
from storyteller.orchestrator.planning.state import StepProgress
from storyteller.orchestrator.session.frame_profile import FrameProfile
from storyteller.orchestrator.session.pace import Pace
from storyteller.sim.world.event_book import EventStatus
from storyteller.sim.world.events import EventFailure
from storyteller.sim.world.step import WorldSnapshot

Outcome = ParsedEvent | PlanningFailure | None


class PlanningRequest(BaseModel):
    """What the planner gets for one step: the world as of ``frame``."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    index: int = Field(ge=0, description="Planning step number, from 0.")
    frame: int = Field(ge=0, description="Simulation frame the snapshot was taken at.")
    roster: tuple[CharacterStatus, ...]
    history: tuple[HistoryEntry, ...]
    earlier: EarlierEvents | None = Field(
        default=None, description="The events before ``history``, summarised (None: there are none)."
    )
    targets: dict[str, tuple[float, float]] = Field(
        default_factory=dict, description="Character -> where its current event sends it (x, y)."
    )
    objects_in_use: dict[str, str] = Field(
        default_factory=dict, description="Seat object -> character who sits or is about to sit on it."
    )
    instruction: str = Field(default="", description="The latest instruction as of ``frame``.")
    instruction_since: int = Field(
        default=0, ge=0, description="First step planned under it: earlier events are not matched to its parts."
    )


InstructionSource = Literal["initial", "script", "api", "stdin", "viewer", "replay"]


class TimedInstruction(BaseModel):
    """An instruction and the frame at which it takes (or took) effect."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    frame: int = Field(ge=0, description="Simulation frame it takes effect at (before that frame's step).")
    text: str = Field(min_length=1)
    source: InstructionSource = "script"
    recorded: bool = Field(
        default=False, description="Resume only: already in the trace; applied again, not reported again."
    )


RequestPhase = Literal["frame_start", "frame_end"]
"""Where in a frame a request was made: ``frame_end`` after the world stepped (the only phase
with ``planners`` = 1), ``frame_start`` before the frame's outcomes are applied (a step in
flight just named its characters)."""


class RecordedRequest(BaseModel):
    """When one planning step was requested (a ``requested`` trace record)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    step: int = Field(ge=0)
    frame: int = Field(ge=0, description="World frame the request was built at.")
    phase: RequestPhase
    after: tuple[int, ...] = Field(default=(), description="Steps in flight then; their characters were left out.")


class StepPlanner(Protocol):
    """Planning steps (the planning graph behind it); with ``planners`` > 1 several run at once.

    ``progress`` gets the step's LLM calls and, as soon as the narrator's event is accepted,
    its characters. A planner may also define ``trace_seqs(index) -> Sequence[int]``: the seqs
    of the trace records (LLM attempts) that produced step ``index``'s outcome."""

    async def plan(self, request: PlanningRequest, progress: StepProgress | None = None) -> Outcome: ...


class Pacer(Protocol):
    """A director's pause and speed of a ``realtime`` session (``orchestrator.session.viewer_controls``),
    asked by the simulation at every frame boundary, after the checkpoint and before the sleep."""

    async def hold(self, frame: int) -> float:
        """Wait while paused before ``frame``; the wall seconds waited."""
        ...

    def speed(self, current: float) -> float:
        """Simulated seconds per wall second from now on (``current``: the speed so far)."""
        ...


class SessionError(Exception):
    """A session cannot go on (e.g. a replay whose recorded frames do not fit the story)."""


@dataclass
class StoryEvent:
    """An applied event and how it is going in the simulation."""

    index: int
    event_id: str
    characters: tuple[str, ...]
    activity: str
    requested_frame: int
    applied_frame: int
    state: EventStatus = "ongoing"
    finished_frame: int | None = None
    failure: str | None = None
    part: str = ""
    """The instruction part the event carries out (empty: none)."""
    text: str = ""
    """What a person reads: the applied plan in plain English (``storyteller.agents.story_text.event_text``)."""
    narration: str | None = None
    """The narrator's activity in human names, when it agrees with the plan (None otherwise)."""


@dataclass
class SessionResult:
    frames: int
    steps: int
    events: list[StoryEvent]
    outcomes: list[tuple[int, Outcome]]
    applied_frames: list[int]
    failures: list[EventFailure] = field(default_factory=list)
    instructions: list[TimedInstruction] = field(default_factory=list)
    """Every instruction that took effect while the story ran (``SessionSettings.instruction``, the
    one at the start, is not listed), in order, with its frame."""
    planner_error: BaseException | None = None
    wall_s: float = 0.0
    """Wall-clock seconds the simulation task ran (this process)."""
    frame_intervals_s: Sequence[float] = ()
    """Wall-clock seconds between consecutive frames (this process)."""
    frame_profile: FrameProfile = field(default_factory=FrameProfile)
    """Where each of those frames' wall time went (``storyteller.orchestrator.session.frame_profile``)."""
    slipped_s: float = 0.0
    """``realtime``: wall seconds the frame schedule slipped after frames that ran more than a
    frame late (simulated time is behind the wall clock by this much times ``speed``)."""


@dataclass
class SessionSettings:
    """frames: frames to simulate; pace: see module doc; speed: simulated seconds per wall
    second in ``realtime`` pace; max_steps: planning steps at most, not counting steps that
    came back as a wait (None: unbounded);
    retry_after_s: simulated seconds before asking again after a wait or a failed step;
    recheck_after_s: after a wait, the planner is asked again only once the free characters or
    an event's state (looping, completed, failed) changed since the request, or after this many
    simulated seconds (the same question would get the same answer: a wait costs a planning
    step, so waits are not repeated every ``retry_after_s`` for nothing);
    applied_frames: replay only, the recorded frame of every planning step's result, by step
    (None: a step the recorded run requested but never applied, e.g. in flight at its end)."""

    frames: int
    pace: Pace = "lockstep"
    speed: float = 1.0
    max_steps: int | None = None
    retry_after_s: float = 3.0
    recheck_after_s: float = 30.0
    applied_frames: Sequence[int | None] | None = None
    recorded_frames: Mapping[int, int] = field(default_factory=dict)
    """Resume only: step -> frame at which an earlier process already applied (and traced) that
    step's outcome; it is applied at that frame again and not traced twice."""
    checkpoint_every_s: float | None = None
    """Call ``on_checkpoint`` after every applied outcome and at least this often (simulated
    seconds); None: never."""
    instruction: str = ""
    """The instruction at frame 0."""
    instructions: Sequence[TimedInstruction] = ()
    """Instructions that take effect at their frames (a timed script, or a replay's recorded ones)."""
    live_instructions: bool = True
    """Accept :meth:`Session.instruct` (False in a replay: only the recorded ones count)."""
    planners: int = 1
    """Planning steps in flight at most. Above 1, a new step starts once every step in flight has
    named its characters (the narrator's event), for the free characters left: see the module doc."""
    offline_latency_s: float | None = None
    """``offline`` pace: simulated seconds each LLM call takes (None: the call's own latency,
    as measured or as recorded in the replayed trace)."""
    schedule: Sequence[RecordedRequest] | None = None
    """Replay of a run with ``planners`` > 1: when each step was requested (the trace's
    ``requested`` records); the replay makes each request at its frame and phase, after the
    steps it saw in flight named their characters."""
    recorded_requests: Sequence[RecordedRequest] = ()
    """Resume only (``planners`` > 1): the ``requested`` records the trace already holds. Those
    of steps after the checkpoint (an earlier process made them before it was killed) are made
    again at their frames and phases as a replay makes them, and not traced twice; until the
    last of them is made, no other step is requested and no outcome the trace does not show
    applied is applied (the earlier process still had it in flight). Then the session goes on
    live."""
    recorded_until: int = -1
    """Resume only: the last frame the trace shows the earlier process at (any record made at
    it). Live instructions take effect after it, so none changes what a request the trace holds
    (and its LLM calls) saw."""


def check_settings(settings: SessionSettings) -> None:
    """Raise :class:`SessionError` for settings no session can run with."""
    if settings.pace not in ("lockstep", "realtime", "fast", "offline"):
        raise SessionError(f"unknown pace {settings.pace!r}; expected lockstep, realtime, fast or offline")
    if settings.speed <= 0 or not math.isfinite(settings.speed):
        raise SessionError(f"speed must be a positive number, got {settings.speed!r}")
    if settings.planners < 1:
        raise SessionError(f"planners must be at least 1, got {settings.planners!r}")
    lat = settings.offline_latency_s
    if lat is not None and not (math.isfinite(lat) and lat >= 0):
        raise SessionError(f"offline latency must be a non-negative number of seconds, got {lat!r}")


@dataclass
class SessionCheckpoint:
    """Everything a session needs to go on from a frame (``Session.checkpoint`` /
    ``Session.resume``): the world's snapshot, the story so far and the planning request in
    flight (re-sent on resume; the planner answers it from its own checkpoints)."""

    world: WorldSnapshot
    events: dict[str, StoryEvent]
    outcomes: list[tuple[int, Outcome]]
    applied_frames: list[int]
    failures: list[EventFailure]
    steps: int
    next_plan_frame: int
    in_flight: PlanningRequest | None
    failures_in_a_row: int
    changes: int
    asked: tuple[tuple[str, ...], int] | None
    unchanged_until: int | None
    instruction: str = ""
    instruction_since: int = 0
    instructions: list[TimedInstruction] = field(default_factory=list)
    more_in_flight: tuple[PlanningRequest, ...] = ()
    """Further steps in flight (``planners`` > 1), after ``in_flight``; re-sent on resume."""


def event_id_for(index: int) -> str:
    return f"event-{index:04d}"

"""A story session: the simulation and the planner run concurrently in one anyio task group.

The simulation task owns the world and steps it frame by frame; it never waits on an LLM
call (except in ``lockstep`` and ``offline`` pace or when a replay says a result was applied at
this frame). When characters are available and no planning step is in flight, it takes a
snapshot of the world (roster and event history, at a known frame) and starts a planning task
for it in the session's task group; the task runs one step of the planning graph (narrator,
event parser, their retries) and sends its news (calls, claim, outcome) back through a memory
channel. The simulation applies the outcome at the
frame it arrives and records that frame (story log and trace ``applied`` record). The
``applied`` record names the step, the frame its request was made at and the seqs of the
trace records that produced the outcome, as the planner reports them
(``planner.trace_seqs(index)``, optional; without it the record names none).

Determinism: a planning request is built from the world at a frame the simulation chose, so
its content depends only on earlier frames. What can differ between two live runs is the
frame at which a result arrives; that frame is recorded. A replay reads the recorded frames
back and applies each result at exactly its frame, so the same events and the same motion
come out. ``lockstep`` pace applies every result at the frame it was requested (the
simulation pauses while the planner thinks), which is deterministic without a trace.

Overlapping steps (``SessionSettings.planners`` = N > 1): a step names its characters as soon
as the narrator's event is accepted (``StepProgress.claim``), before its program is written
and run. Once every step in flight has done so, and fewer than N are in flight, the next step
is requested for the free characters left: their roster shows the claimed ones busy, and the
history shows the claimed events ongoing, so no character is in two events. Such a request is
made at the start of a frame (``frame_start``, before the frame's outcomes are applied) or,
like every request with N = 1, after the world stepped (``frame_end``). With N = 1 nothing is
requested while a step is in flight, exactly as before. ``lockstep`` stays deterministic with
N > 1: it waits for every step in flight to claim or finish before deciding, and applies every
outcome at its request frame. In ``realtime`` / ``fast`` pace the requests are reported to
``on_request`` (the run job writes them to the trace) and a replay makes each at its recorded
frame and phase (``SessionSettings.schedule``), after the steps it saw in flight claimed.

``offline`` pace: the planner reports each LLM call's latency (``StepProgress.llm_call``);
a step's claim is known at its request frame plus the latency of the calls before it, its
outcome applied at its request frame plus the latency of all its calls (or
``offline_latency_s`` per call). The simulation steps ahead freely up to the frame where a
step in flight might next produce news, and waits there, so the story is the same however
fast the machine or the model is.

Off the event loop: nothing here blocks; the planning graph runs event programs and other CPU
work in worker threads (``orchestrator.planning.graph.off_loop``), so in ``realtime`` pace the
simulation task keeps its frame rate while steps are planned.

``realtime`` pace: frame k is due ``k / (fps * speed)`` wall seconds after the start, and the
simulation task sleeps until then. A checkpoint is taken before that sleep, which absorbs its
cost. A frame that ends more than one frame period late (a stall) is not followed by a burst
of catch-up frames: the schedule slips by the delay instead (``SessionResult.slipped_s``), and
the next frame is due one period after it. Where each frame's wall time went is kept in
``SessionResult.frame_profile`` (``orchestrator.session.frame_profile``); timing decides
nothing but when a realtime frame starts, so it never changes a story in the other paces.
A ``pacer`` (a director's pause and speed, ``orchestrator.session.viewer_controls``) may hold
a realtime simulation between two frames and change its speed: that too moves only when frames
start (a pause is left out of the frame intervals).

Failures: an ``LLMError`` from the planner stops planning and the story goes on
(``SessionResult.planner_error``); any other exception in any task cancels the task group
(every step in flight is cancelled, none is left pending) and :meth:`Session.run` raises it.

Checkpoints: with ``checkpoint_every_s`` set, ``on_checkpoint`` gets a
:class:`SessionCheckpoint` (between two frames) after every applied outcome and at least that
often; ``Session.resume(checkpoint)`` on a world built from the same inputs goes on from it
(the step in flight then is asked again), and ends as the uninterrupted session would in
``lockstep`` pace or with ``recorded_frames`` for the steps applied after the checkpoint.

Instructions: the narrator always sees the latest one (a new instruction replaces the old).
A new instruction takes effect at the start of a frame, before the world steps: scheduled
ones (``SessionSettings.instructions``: a timed script, or a replay's recorded ones) at their
frame, live ones (:meth:`Session.instruct`, :meth:`Session.instruct_nowait`, e.g. from stdin)
at the first frame the simulation starts after they arrive. Every request made after that
frame carries it, with ``instruction_since`` = its own step index, so events planned under an
earlier instruction never count as parts of this one done (``agents.instruction_parts``).
Each one is reported to ``on_instruction`` (the run job records it in the trace with its
frame); a replay passes the recorded ones as scheduled and ignores live ones, so they take
effect at the same frames again.
"""

from __future__ import annotations

import contextlib
import math
import time
from array import array
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal, Protocol

import anyio
import anyio.abc
import structlog
from anyio.streams.memory import MemoryObjectReceiveStream, MemoryObjectSendStream
from pydantic import BaseModel, ConfigDict, Field

from agents.history import HISTORY_WINDOW
from agents.instruction_parts import PART_ATTEMPTS
from agents.llm_port import LLMError, ReplayMissError, TraceRecorder
from agents.messages import (
    CharacterStatus,
    EarlierEvents,
    HistoryEntry,
    ParsedEvent,
    PlanningFailure,
)
from agents.story_text import event_text, narration
from orchestrator.planning.state import StepProgress
from orchestrator.session.frame_profile import FrameProfile
from orchestrator.session.pace import Pace
from sim.world.event_book import EventStatus
from sim.world.events import AssignEvent, EventFailure, StepOutput
from sim.world.step import World, WorldSnapshot, step

Outcome = ParsedEvent | PlanningFailure | None

_log = structlog.get_logger("storyteller.session")


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
    """What a person reads: the applied plan in plain English (``agents.story_text.event_text``)."""
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
    """Where each of those frames' wall time went (``orchestrator.session.frame_profile``)."""
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
    """Targets of characters with an assignment, and seats taken or about to be taken."""
    targets: dict[str, tuple[float, float]] = {}
    seats: dict[str, str] = {}
    for name in world.names:
        c = world.characters[name]
        a = c.assignment
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


def event_id_for(index: int) -> str:
    return f"event-{index:04d}"


class Session:
    """Runs one story: ``await Session(world, planner, settings).run()``.

    Callbacks (all on the event loop): ``on_event`` when an event starts, loops, completes or
    fails; ``on_outcome(index, outcome, frame)`` when a step's outcome is applied;
    ``on_instruction``, ``on_request``, ``on_checkpoint`` (see the module doc); ``on_frame(world)``
    after every frame is stepped (it runs for every frame: keep it O(1))."""

    def __init__(
        self,
        world: World,
        planner: StepPlanner,
        settings: SessionSettings,
        *,
        trace: TraceRecorder | None = None,
        on_event: Callable[[StoryEvent], None] | None = None,
        on_outcome: Callable[[int, Outcome, int], None] | None = None,
        on_checkpoint: Callable[[SessionCheckpoint], None] | None = None,
        on_instruction: Callable[[TimedInstruction], None] | None = None,
        on_request: Callable[[RecordedRequest], None] | None = None,
        on_frame: Callable[[World], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        pacer: Pacer | None = None,
    ) -> None:
        if settings.pace not in ("lockstep", "realtime", "fast", "offline"):
            raise SessionError(f"unknown pace {settings.pace!r}; expected lockstep, realtime, fast or offline")
        if settings.speed <= 0 or not math.isfinite(settings.speed):
            raise SessionError(f"speed must be a positive number, got {settings.speed!r}")
        if settings.planners < 1:
            raise SessionError(f"planners must be at least 1, got {settings.planners!r}")
        lat = settings.offline_latency_s
        if lat is not None and not (math.isfinite(lat) and lat >= 0):
            raise SessionError(f"offline latency must be a non-negative number of seconds, got {lat!r}")
        self.world = world
        self.planner = planner
        self.settings = settings
        self.trace = trace
        self.on_event = on_event
        self.on_outcome = on_outcome
        self.on_checkpoint = on_checkpoint
        self.on_instruction = on_instruction
        self.on_request = on_request
        self.on_frame = on_frame
        self.clock = clock
        self.pacer = pacer if settings.pace == "realtime" else None
        self.events: dict[str, StoryEvent] = {}
        self.outcomes: list[tuple[int, Outcome]] = []
        self._waits = 0  # outcomes that are waits
        self.applied_frames: list[int] = []
        self.failures: list[EventFailure] = []
        self._steps = 0
        self._next_plan_frame = 0
        self._flights: dict[int, _Flight] = {}  # steps in flight, by index
        self._schedule = list(settings.schedule) if settings.schedule is not None else None
        self._news_send: MemoryObjectSendStream[_News] | None = None
        self._tg: anyio.abc.TaskGroup | None = None
        self.planner_error: BaseException | None = None
        self._failures_in_a_row = 0
        self._changes = 0  # event state changes seen so far (looping, completed, failed)
        self._asked: tuple[tuple[str, ...], int] | None = None  # (free, changes) at the last request
        self._unchanged_until: int | None = None  # after a wait: no new request before this frame
        # unless the free characters or an event's state changed since the request
        self.instruction = settings.instruction
        self._instruction_since = 0
        self.instructions: list[TimedInstruction] = []  # taken effect, in order
        self._scheduled = sorted(settings.instructions, key=lambda i: i.frame)  # stable: file order on ties
        self._live: deque[tuple[str, InstructionSource, anyio.Event | None]] = deque()  # thread-safe appends
        self._taken: dict[int, int] = {}  # id(event) of a waiting instruct() -> frame it took effect at
        self._ended = False
        self._resent: list[PlanningRequest] = []  # resumed: steps in flight at the checkpoint, asked again
        self.frame_intervals: array[float] = array("d")  # wall seconds between frames (8 B each)
        self.profile = FrameProfile()  # where each frame's wall time went (24 B each)
        self.slipped_s = 0.0  # realtime: wall seconds the schedule slipped after stalls
        self.wall_s = 0.0

    # ----- checkpoints ---------------------------------------------------------------------
    def checkpoint(self) -> SessionCheckpoint:
        """A copy of the session's state at the current frame (between two frames)."""
        import copy

        flying = [f.request for _, f in sorted(self._flights.items())]
        return SessionCheckpoint(
            world=self.world.snapshot(),
            events=copy.deepcopy(self.events),
            outcomes=list(self.outcomes),
            applied_frames=list(self.applied_frames),
            failures=list(self.failures),
            steps=self._steps,
            next_plan_frame=self._next_plan_frame,
            in_flight=flying[0] if flying else None,
            more_in_flight=tuple(flying[1:]),
            failures_in_a_row=self._failures_in_a_row,
            changes=self._changes,
            asked=self._asked,
            unchanged_until=self._unchanged_until,
            instruction=self.instruction,
            instruction_since=self._instruction_since,
            instructions=list(self.instructions),
        )

    def resume(self, cp: SessionCheckpoint) -> None:
        """Go on from ``cp`` (taken from a session on an equal world) instead of frame 0."""
        import copy

        self.world = self.world.restore(cp.world)
        self.events = copy.deepcopy(cp.events)
        self.outcomes = list(cp.outcomes)
        self._waits = sum(1 for _, o in self.outcomes if o is None)
        self.applied_frames = list(cp.applied_frames)
        self.failures = list(cp.failures)
        self._steps = cp.steps
        self._next_plan_frame = cp.next_plan_frame
        self._resent = [r for r in (cp.in_flight, *cp.more_in_flight) if r is not None]
        self._failures_in_a_row = cp.failures_in_a_row
        self._changes = cp.changes
        self._asked = cp.asked
        self._unchanged_until = cp.unchanged_until
        self.instruction = cp.instruction
        self._instruction_since = cp.instruction_since
        self.instructions = list(cp.instructions)
        # scheduled instructions before the checkpoint's frame took effect already
        self._scheduled = [i for i in self._scheduled if i.frame >= self.world.frame]

    # ----- instructions ------------------------------------------------------------------
    async def instruct(self, text: str, source: InstructionSource = "api") -> int | None:
        """Make ``text`` the instruction from the next frame the simulation starts; returns
        that frame once it took effect (None: ignored, in a replay, or the story had ended).
        Called before :meth:`run`, it waits for the run's first frame. Raises ValueError for
        an empty text."""
        event = anyio.Event()
        if not self._enqueue(text, source, event):
            return None
        await event.wait()
        return self._taken.pop(id(event), None)

    def instruct_nowait(self, text: str, source: InstructionSource = "stdin") -> bool:
        """:meth:`instruct` without waiting; safe to call from any thread (e.g. a stdin reader).
        False when the instruction is ignored (a replay, or the story has ended)."""
        return self._enqueue(text, source, None)

    def _enqueue(self, text: str, source: InstructionSource, event: anyio.Event | None) -> bool:
        text = " ".join(text.split())
        if not text:
            raise ValueError("an instruction must not be empty")
        if not self.settings.live_instructions or self._ended:
            _log.warning("instruction_ignored", text=text, reason="replay" if not self._ended else "story ended")
            return False
        self._live.append((text, source, event))
        return True

    def _take_instructions(self) -> None:
        """Apply the instructions due at the current frame (before it steps), in order."""
        frame = self.world.frame
        due: list[tuple[TimedInstruction, anyio.Event | None]] = []
        while self._scheduled and self._scheduled[0].frame <= frame:
            due.append((self._scheduled.pop(0), None))
        while self._live:
            text, source, event = self._live.popleft()
            due.append((TimedInstruction(frame=frame, text=text, source=source), event))
        for timed, event in due:
            if timed.frame != frame:
                raise SessionError(f"instruction for frame {timed.frame} reached at frame {frame}")
            self.instruction = timed.text
            self._instruction_since = self._steps
            self._unchanged_until = None  # a new instruction is a change: ask again
            self.instructions.append(timed.model_copy(update={"recorded": False}))
            if self.on_instruction is not None and not timed.recorded:
                self.on_instruction(timed)
            _log.info("instruction", frame=frame, source=timed.source, text=timed.text)
            if event is not None:
                self._taken[id(event)] = frame
                event.set()

    def _release_waiters(self) -> None:
        self._ended = True
        while self._live:
            _, _, event = self._live.popleft()
            if event is not None:
                event.set()

    # ----- planning side ------------------------------------------------------------------
    async def _plan_step(self, request: PlanningRequest, news: MemoryObjectSendStream[_News]) -> None:
        """One planning step; its progress and outcome go to the simulation as news. An
        ``LLMError`` stops planning (the story goes on, see ``planner_error``); any other
        exception ends the session (the task group cancels every task)."""
        with news:
            try:
                outcome = await self.planner.plan(request, _Progress(request.index, news))
            except LLMError as exc:
                _post(news, _News(request.index, "stopped", error=exc))
                return
            _post(news, _News(request.index, "outcome", outcome=outcome))

    def _send(self, request: PlanningRequest, phase: RequestPhase, *, resent: bool = False) -> None:
        assert self._tg is not None and self._news_send is not None
        after = tuple(sorted(self._flights))
        self._flights[request.index] = _Flight(request)
        if self.on_request is not None and self.settings.planners > 1 and not resent:
            self.on_request(RecordedRequest(step=request.index, frame=request.frame, phase=phase, after=after))
        self._tg.start_soon(self._plan_step, request, self._news_send.clone())

    def _note(self, news: _News) -> None:
        fl = self._flights.get(news.index)
        if fl is None:
            return
        fps = self.world.config.fps
        if news.kind == "call":
            fixed = self.settings.offline_latency_s
            fl.latency_s += fixed if fixed is not None else news.latency_s
        elif news.kind == "claim":
            fl.claim = news.characters
            fl.activity = news.activity
            fl.part = news.part
            fl.claim_frame = fl.request.frame + round(fl.latency_s * fps) if self.settings.pace == "offline" else None
        elif news.kind == "outcome":
            fl.done = True
            fl.outcome = news.outcome
            if self.settings.pace == "offline":
                fl.due = fl.request.frame + round(fl.latency_s * fps)
        else:  # stopped: the story goes on without a planner; the caller reports it
            self.planner_error = news.error
            # a replay miss is the replayed command's one error line (its diff a record at info level)
            log = _log.info if isinstance(news.error, ReplayMissError) else _log.error
            log("planner_stopped", step=news.index, error=f"{type(news.error).__name__}: {news.error}")
            del self._flights[news.index]

    def _drain(self, news: MemoryObjectReceiveStream[_News]) -> None:
        while True:
            try:
                self._note(news.receive_nowait())
            except anyio.WouldBlock:
                return

    async def _next_news(self, news: MemoryObjectReceiveStream[_News]) -> None:
        self._note(await news.receive())

    def _recorded_due(self, index: int) -> int | None:
        due = self.settings.recorded_frames.get(index)
        if due is None and self.settings.applied_frames is not None and index < len(self.settings.applied_frames):
            due = self.settings.applied_frames[index]
        return due

    def _replaying(self) -> bool:
        return self.settings.applied_frames is not None

    def _horizon(self, fl: _Flight) -> int:
        """``offline``: nothing of ``fl`` can happen before this frame (its calls so far took that long)."""
        return fl.request.frame + round(fl.latency_s * self.world.config.fps)

    def _pending(self, fl: _Flight, frame: int) -> bool:
        """More news of ``fl`` is needed before ``frame`` steps: its outcome may be applied then."""
        due = self._recorded_due(fl.request.index)
        if due is not None and due < frame:
            raise SessionError(
                f"replay: step {fl.request.index} was applied at frame {due}, "
                f"but its request was made at frame {fl.request.frame}"
            )
        if fl.done:
            return False
        if due is not None:
            return due == frame
        if self._replaying():
            return False  # requested but never applied in the recorded run
        pace = self.settings.pace
        if pace == "lockstep":
            return True
        if pace == "offline":
            return self._horizon(fl) <= frame
        return False

    def _unsettled(self, fl: _Flight, frame: int) -> bool:
        """More news of ``fl`` is needed to know whether it named its characters as of ``frame``."""
        if fl.done or self._replaying():
            return False
        pace = self.settings.pace
        if pace == "lockstep":
            return fl.claim is None
        if pace == "offline":
            if fl.claim is not None and fl.claim_frame is not None and fl.claim_frame <= frame:
                return False
            return self._horizon(fl) <= frame
        return False

    def _due(self, fl: _Flight, frame: int) -> bool:
        """``fl``'s outcome is applied at ``frame`` (before the world steps)."""
        due = self._recorded_due(fl.request.index)
        if due is not None:
            return due == frame
        if self._replaying():
            return False
        if self.settings.pace == "offline":
            if fl.due is not None and fl.due < frame:
                raise SessionError(f"offline: step {fl.request.index} landed at frame {fl.due}, before frame {frame}")
            return fl.due == frame
        return self.settings.pace == "lockstep" or fl.done

    def _claimed(self, frame: int) -> dict[str, _Flight] | None:
        """Character -> the step in flight it takes part in, as of ``frame``; None while a step
        in flight has not named its characters yet (nothing can be planned beside it)."""
        out: dict[str, _Flight] = {}
        offline = self.settings.pace == "offline" and not self._replaying()  # a replay: the recorded schedule
        for fl in self._flights.values():
            if fl.claim is not None and (not offline or (fl.claim_frame is not None and fl.claim_frame <= frame)):
                names: Sequence[str] = fl.claim
            elif fl.done and (not offline or (fl.due is not None and fl.due <= frame)):
                names = fl.outcome.event.characters if isinstance(fl.outcome, ParsedEvent) else ()
            else:
                return None
            out.update((n, fl) for n in names)
        return out

    def _wants_plan(self, available: Sequence[str], frame: int) -> tuple[str, ...] | None:
        """The free characters to plan for now (not in a step in flight), or None."""
        s = self.settings
        if len(self._flights) >= s.planners or self.planner_error is not None:
            return None
        if s.max_steps is not None and self._steps - self._waits >= s.max_steps:
            return None
        if s.applied_frames is not None and self._steps >= len(s.applied_frames):
            return None
        claimed = self._claimed(frame)
        if claimed is None:
            return None
        free = tuple(a for a in available if a not in claimed)
        if not free or self.world.frame < self._next_plan_frame:
            return None
        if self._unchanged_until is not None:
            if (free, self._changes) == self._asked and self.world.frame < self._unchanged_until:
                return None
            self._unchanged_until = None
        return free

    def _request(self, frame: int) -> PlanningRequest:
        """The request for the next step, from the world now; characters of the steps in
        flight show as busy with their event, which shows as ongoing in the history."""
        targets, seats = world_commitments(self.world)
        roster = world_roster(self.world, self.events)
        claimed = self._claimed(frame) or {}
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
        history, earlier = history_window(self.events, self.outcomes, pending, since=self._instruction_since)
        return PlanningRequest(
            index=self._steps,
            frame=self.world.frame,
            roster=roster,
            history=history,
            earlier=earlier,
            targets=targets,
            objects_in_use=seats,
            instruction=self.instruction,
            instruction_since=self._instruction_since,
        )

    def _ask(self, free: Sequence[str], frame: int, phase: RequestPhase) -> None:
        request = self._request(frame)
        self._steps += 1
        self._asked = (tuple(free), self._changes)
        self._send(request, phase)

    async def _ask_scheduled(self, news: MemoryObjectReceiveStream[_News], phase: RequestPhase) -> None:
        """Replay of a concurrent run: make the requests recorded at this frame and phase."""
        assert self._schedule is not None
        frame = self.world.frame
        while self._schedule and (self._schedule[0].frame, self._schedule[0].phase) == (frame, phase):
            rec = self._schedule.pop(0)
            while self._claimed(frame) is None:
                await self._next_news(news)
            if rec.step != self._steps or tuple(sorted(self._flights)) != rec.after:
                raise SessionError(
                    f"replay: step {rec.step} was requested at frame {rec.frame} beside steps {list(rec.after)}, "
                    f"but the replay is at step {self._steps} beside {sorted(self._flights)}"
                )
            request = self._request(frame)
            self._steps += 1
            self._send(request, phase)
        if self._schedule and self._schedule[0].frame < frame:
            raise SessionError(f"replay: step {self._schedule[0].step} was requested at frame {self._schedule[0].frame}, "
                               f"which the replay passed")

    async def _settle(self, news: MemoryObjectReceiveStream[_News]) -> list[_Flight]:
        """Take the news the current frame needs (waiting for it in ``lockstep`` and
        ``offline`` pace, and for recorded frames), start the steps it allows beside the ones
        in flight, and return the steps whose outcome is applied at this frame, in step order."""
        frame = self.world.frame
        while True:
            self._drain(news)
            if any(self._unsettled(fl, frame) for fl in list(self._flights.values())):
                await self._next_news(news)
                continue
            if self._schedule is not None:
                await self._ask_scheduled(news, "frame_start")
            elif self._flights and self.settings.planners > 1:
                free = self._wants_plan(self.world.available(), frame)
                if free is not None:
                    self._ask(free, frame, "frame_start")
                    continue
            if any(self._pending(fl, frame) for fl in list(self._flights.values())):
                await self._next_news(news)
                continue
            return sorted((fl for fl in self._flights.values() if self._due(fl, frame)), key=lambda f: f.request.index)

    def _apply(self, request: PlanningRequest, outcome: Outcome) -> list[AssignEvent]:
        frame = self.world.frame
        self.outcomes.append((request.index, outcome))
        self._waits += outcome is None  # a wait does not use up max_steps
        self.applied_frames.append(frame)
        if self.trace is not None and request.index not in self.settings.recorded_frames:
            seqs_of: Callable[[int], Sequence[int]] | None = getattr(self.planner, "trace_seqs", None)
            seqs = tuple(seqs_of(request.index)) if seqs_of is not None else ()
            self.trace.record_applied(seqs, frame, step=request.index, requested_frame=request.frame)
        if self.on_outcome is not None:
            self.on_outcome(request.index, outcome, frame)
        retry = max(1, round(self.settings.retry_after_s * self.world.config.fps))
        if isinstance(outcome, PlanningFailure):  # back off while the planner keeps failing
            self._failures_in_a_row += 1
            retry *= 2 ** min(self._failures_in_a_row - 1, 5)
        else:
            self._failures_in_a_row = 0
        if not isinstance(outcome, ParsedEvent):
            self._next_plan_frame = frame + retry
            if outcome is None:  # a wait: ask again when something changed (or much later)
                self._unchanged_until = frame + max(retry, round(self.settings.recheck_after_s * self.world.config.fps))
            return []
        eid = event_id_for(request.index)
        try:
            command = AssignEvent.from_plans(eid, outcome.plans, self.world.scene)
        except ValueError as exc:  # e.g. an action the motion library does not know
            _log.warning("event_rejected", event_id=eid, error=str(exc))
            self._next_plan_frame = frame + retry
            return []
        ev = StoryEvent(
            index=request.index,
            event_id=eid,
            characters=tuple(outcome.event.characters),
            activity=outcome.event.activity,
            requested_frame=request.frame,
            applied_frame=frame,
            part=outcome.part,
            text=event_text(outcome, self.world.scene),
            narration=narration(outcome, self.world.scene),
        )
        self.events[eid] = ev
        if self.on_event is not None:
            self.on_event(ev)
        return [command]

    def _observe(self, out: StepOutput) -> None:
        self._changes += len(out.looping_events) + len(out.completed_events) + len(out.failures)
        for eid in out.looping_events:
            if eid in self.events and self.events[eid].state == "ongoing":
                self.events[eid].state = "looping"
        for eid in out.completed_events:
            if eid in self.events:
                self.events[eid].state = "completed"
                self.events[eid].finished_frame = out.frame
                if self.on_event is not None:
                    self.on_event(self.events[eid])
        for failure in out.failures:
            self.failures.append(failure)
            ev = self.events.get(failure.event_id)
            if ev is not None and ev.state != "failed":
                ev.state = "failed"
                ev.failure = failure.message
                ev.finished_frame = out.frame
                if self.on_event is not None:
                    self.on_event(ev)

    async def _simulation_task(self, news: MemoryObjectReceiveStream[_News]) -> None:
        s = self.settings
        start = begin = self.clock()  # ``start`` moves on when a realtime schedule slips
        last = start
        every = None if s.checkpoint_every_s is None else max(1, round(s.checkpoint_every_s * self.world.config.fps))
        last_checkpoint = self.world.frame
        for request in self._resent:  # resumed with steps in flight: ask again
            self._send(request, "frame_end", resent=True)
        self._resent = []
        clock = self.clock
        speed = s.speed  # realtime: a pacer may change it
        while self.world.frame < s.frames:
            self._take_instructions()
            commands: list[AssignEvent] = []
            applied = False
            for fl in await self._settle(news):
                del self._flights[fl.request.index]
                commands += self._apply(fl.request, fl.outcome)
                applied = True
            t_step = clock()
            self.world, out = step(self.world, commands, self.world.dt)
            self._observe(out)
            if self.on_frame is not None:
                self.on_frame(self.world)
            t_ask = clock()
            if self._schedule is not None:
                await self._ask_scheduled(news, "frame_end")
            else:
                free = self._wants_plan(out.available, self.world.frame - 1)
                if free is not None:
                    self._ask(free, self.world.frame - 1, "frame_end")
            t_checkpoint = clock()
            if self.on_checkpoint is not None and every is not None and (
                applied or self.world.frame - last_checkpoint >= every
            ):  # before the sleep, which absorbs its cost (nothing changes the session in between)
                self.on_checkpoint(self.checkpoint())
                last_checkpoint = self.world.frame
            t_sleep = clock()
            delay = held = 0.0
            if s.pace == "realtime":
                if self.pacer is not None:  # paused: held here; after a pause or a new speed the next
                    held = await self.pacer.hold(self.world.frame)  # frame is due one period from now
                    wanted = self.pacer.speed(speed)
                    if held > 0 or wanted != speed:
                        speed = wanted
                        start = t_sleep + held - (self.world.frame - 1) / (self.world.config.fps * speed)
                period = 1.0 / (self.world.config.fps * speed)
                behind = t_sleep + held - (start + self.world.frame * period)
                if behind > period:  # a stall: no burst of catch-up frames, the schedule slips instead
                    start += behind
                    self.slipped_s += behind
                    behind = 0.0
                delay = max(0.0, -behind)
                await anyio.sleep(delay)
            elif self.world.frame % 8 == 0 or self._flights:
                await anyio.sleep(0)
            now = clock()
            self.frame_intervals.append(now - last - held)  # a pause is no late frame
            self.profile.add(t_step - last, t_ask - t_step, t_checkpoint - t_ask, t_sleep - t_checkpoint, delay,
                             max(0.0, now - t_sleep - held - delay))
            last = now
        self.wall_s = last - begin
        # steps still in flight are abandoned (not applied); run() cancels them

    async def run(self) -> SessionResult:
        """Run the story to its last frame. An ``LLMError`` of the planner stops planning (see
        ``SessionResult.planner_error``); any other exception in any task cancels the others
        and is raised here (alone, not in an exception group)."""
        news_send, news_recv = anyio.create_memory_object_stream[_News](math.inf)
        try:
            async with anyio.create_task_group() as tg:
                self._tg = tg
                self._news_send = news_send
                try:
                    with news_recv:
                        await self._simulation_task(news_recv)
                finally:
                    self._release_waiters()
                    news_send.close()
                tg.cancel_scope.cancel()
        except BaseExceptionGroup as group:  # surface a lone error as itself
            if len(group.exceptions) == 1:
                raise group.exceptions[0] from None
            raise
        finally:
            self._tg = None
            self._news_send = None
        return self.result()

    def result(self) -> SessionResult:
        """The story so far (what :meth:`run` returns at its end; also after a cancelled run)."""
        return SessionResult(
            frames=self.world.frame,
            steps=len(self.outcomes),
            events=sorted(self.events.values(), key=lambda e: e.index),
            outcomes=list(self.outcomes),
            applied_frames=list(self.applied_frames),
            failures=list(self.failures),
            instructions=list(self.instructions),
            planner_error=self.planner_error,
            wall_s=self.wall_s,
            frame_intervals_s=self.frame_intervals,
            frame_profile=self.profile,
            slipped_s=self.slipped_s,
        )


@dataclass
class _Flight:
    """A planning step in flight, as far as its news went."""

    request: PlanningRequest
    latency_s: float = 0.0
    """LLM seconds of the step so far (``offline``: the configured latency per call, if set)."""
    claim: tuple[str, ...] | None = None
    activity: str = ""
    part: str = ""
    claim_frame: int | None = None
    """``offline``: the frame the claim is known at (request frame + the latency before it)."""
    done: bool = False
    outcome: Outcome = None
    due: int | None = None
    """``offline``: the frame the outcome is applied at (request frame + the step's latency)."""


@dataclass(frozen=True)
class _News:
    index: int
    kind: Literal["call", "claim", "outcome", "stopped"]
    latency_s: float = 0.0
    characters: tuple[str, ...] = ()
    activity: str = ""
    part: str = ""
    outcome: Outcome = None
    error: BaseException | None = None


class _Progress:
    """:class:`StepProgress` of one step: news to the simulation (never blocks)."""

    def __init__(self, index: int, news: MemoryObjectSendStream[_News]) -> None:
        self.index = index
        self.news = news

    def llm_call(self, node: str, latency_s: float) -> None:
        _post(self.news, _News(self.index, "call", latency_s=latency_s))

    def claim(self, characters: Sequence[str], activity: str, part: str = "") -> None:
        _post(self.news, _News(self.index, "claim", characters=tuple(characters), activity=activity, part=part))


def _post(news: MemoryObjectSendStream[_News], item: _News) -> None:
    """Send without waiting; after the simulation ended nobody reads news, and it is dropped."""
    with contextlib.suppress(anyio.ClosedResourceError, anyio.BrokenResourceError):
        news.send_nowait(item)

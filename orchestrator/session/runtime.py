"""A story session: the simulation and the planner run concurrently in one anyio task group.

The simulation task owns the world and steps it frame by frame; it never waits on an LLM
call (except in ``lockstep`` pace or when a replay says a result was applied at this frame).
When characters are available and no planning step is in flight, it takes a snapshot of the
world (roster and event history, at a known frame) and hands it to the planning task through a
memory channel; the planning task runs one step of the planning graph (narrator, event
parser, their retries) and sends the outcome back. The simulation applies the outcome at the
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

import math
import time
from array import array
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal, Protocol

import anyio
import structlog
from anyio.streams.memory import MemoryObjectReceiveStream, MemoryObjectSendStream
from pydantic import BaseModel, ConfigDict, Field

from agents.llm_port import TraceRecorder
from agents.messages import CharacterStatus, HistoryEntry, ParsedEvent, PlanningFailure
from orchestrator.session.pace import Pace
from sim.world.event_book import EventStatus
from sim.world.events import AssignEvent, EventFailure, StepOutput
from sim.world.step import World, WorldSnapshot, step

Outcome = ParsedEvent | PlanningFailure | None

_log = structlog.get_logger("storyteller.session")

HISTORY_WINDOW = 12


class PlanningRequest(BaseModel):
    """What the planner gets for one step: the world as of ``frame``."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    index: int = Field(ge=0, description="Planning step number, from 0.")
    frame: int = Field(ge=0, description="Simulation frame the snapshot was taken at.")
    roster: tuple[CharacterStatus, ...]
    history: tuple[HistoryEntry, ...]
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


InstructionSource = Literal["initial", "script", "api", "stdin", "replay"]


class TimedInstruction(BaseModel):
    """An instruction and the frame at which it takes (or took) effect."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    frame: int = Field(ge=0, description="Simulation frame it takes effect at (before that frame's step).")
    text: str = Field(min_length=1)
    source: InstructionSource = "script"
    recorded: bool = Field(
        default=False, description="Resume only: already in the trace; applied again, not reported again."
    )


class StepPlanner(Protocol):
    """One planning step at a time (the planning graph behind it).

    A planner may also define ``trace_seqs(index) -> Sequence[int]``: the seqs of the trace
    records (LLM attempts) that produced step ``index``'s outcome."""

    async def plan(self, request: PlanningRequest) -> Outcome: ...


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


@dataclass
class SessionSettings:
    """frames: frames to simulate; pace: see module doc; speed: simulated seconds per wall
    second in ``realtime`` pace; max_steps: planning steps at most (None: unbounded);
    retry_after_s: simulated seconds before asking again after a wait or a failed step;
    recheck_after_s: after a wait, the planner is asked again only once the free characters or
    an event's state (looping, completed, failed) changed since the request, or after this many
    simulated seconds (the same question would get the same answer: a wait costs a planning
    step, so waits are not repeated every ``retry_after_s`` for nothing);
    applied_frames: replay only, the recorded frame of every planning step's result."""

    frames: int
    pace: Pace = "lockstep"
    speed: float = 1.0
    max_steps: int | None = None
    retry_after_s: float = 3.0
    recheck_after_s: float = 30.0
    applied_frames: Sequence[int] | None = None
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


def story_history(events: dict[str, StoryEvent]) -> tuple[HistoryEntry, ...]:
    entries = sorted(events.values(), key=lambda e: e.index)[-HISTORY_WINDOW:]
    return tuple(
        HistoryEntry(
            index=e.index,
            characters=e.characters,
            activity=e.activity,
            state="completed" if e.state == "failed" else e.state,
        )
        for e in entries
    )


def event_id_for(index: int) -> str:
    return f"event-{index:04d}"


class Session:
    """Runs one story: ``await Session(world, planner, settings).run()``."""

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
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if settings.pace not in ("lockstep", "realtime", "fast"):
            raise SessionError(f"unknown pace {settings.pace!r}; expected lockstep, realtime or fast")
        if settings.speed <= 0 or not math.isfinite(settings.speed):
            raise SessionError(f"speed must be a positive number, got {settings.speed!r}")
        self.world = world
        self.planner = planner
        self.settings = settings
        self.trace = trace
        self.on_event = on_event
        self.on_outcome = on_outcome
        self.on_checkpoint = on_checkpoint
        self.on_instruction = on_instruction
        self.clock = clock
        self.events: dict[str, StoryEvent] = {}
        self.outcomes: list[tuple[int, Outcome]] = []
        self.applied_frames: list[int] = []
        self.failures: list[EventFailure] = []
        self._steps = 0
        self._next_plan_frame = 0
        self._in_flight: PlanningRequest | None = None
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
        self.frame_intervals: array[float] = array("d")  # wall seconds between frames (8 B each)
        self.wall_s = 0.0

    # ----- checkpoints ---------------------------------------------------------------------
    def checkpoint(self) -> SessionCheckpoint:
        """A copy of the session's state at the current frame (between two frames)."""
        import copy

        return SessionCheckpoint(
            world=self.world.snapshot(),
            events=copy.deepcopy(self.events),
            outcomes=list(self.outcomes),
            applied_frames=list(self.applied_frames),
            failures=list(self.failures),
            steps=self._steps,
            next_plan_frame=self._next_plan_frame,
            in_flight=self._in_flight,
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
        self.applied_frames = list(cp.applied_frames)
        self.failures = list(cp.failures)
        self._steps = cp.steps
        self._next_plan_frame = cp.next_plan_frame
        self._in_flight = cp.in_flight
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
    async def _planning_task(
        self,
        requests: MemoryObjectReceiveStream[PlanningRequest],
        results: MemoryObjectSendStream[tuple[PlanningRequest, Outcome]],
    ) -> None:
        async with requests, results:
            async for request in requests:
                try:
                    outcome = await self.planner.plan(request)
                except Exception as exc:  # the story goes on without a planner; the caller reports it
                    self.planner_error = exc
                    _log.error("planner_stopped", step=request.index, error=f"{type(exc).__name__}: {exc}")
                    return
                await results.send((request, outcome))

    # ----- simulation side ----------------------------------------------------------------
    def _wants_plan(self, out: StepOutput | None) -> bool:
        if self._in_flight is not None or self.planner_error is not None:
            return False
        if self.settings.max_steps is not None and self._steps >= self.settings.max_steps:
            return False
        if self.settings.applied_frames is not None and self._steps >= len(self.settings.applied_frames):
            return False
        available = out.available if out is not None else self.world.available()
        if not available or self.world.frame < self._next_plan_frame:
            return False
        if self._unchanged_until is not None:
            if (tuple(available), self._changes) == self._asked and self.world.frame < self._unchanged_until:
                return False
            self._unchanged_until = None
        return True

    def _apply(self, request: PlanningRequest, outcome: Outcome) -> list[AssignEvent]:
        frame = self.world.frame
        self.outcomes.append((request.index, outcome))
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

    async def _simulation_task(
        self,
        requests: MemoryObjectSendStream[PlanningRequest],
        results: MemoryObjectReceiveStream[tuple[PlanningRequest, Outcome]],
    ) -> None:
        s = self.settings
        replay = list(s.applied_frames) if s.applied_frames is not None else None
        start = self.clock()
        last = start
        out: StepOutput | None = None
        every = None if s.checkpoint_every_s is None else max(1, round(s.checkpoint_every_s * self.world.config.fps))
        last_checkpoint = self.world.frame
        async with requests, results:
            if self._in_flight is not None:  # resumed with a step in flight: ask again
                await requests.send(self._in_flight)
            while self.world.frame < s.frames:
                self._take_instructions()
                commands: list[AssignEvent] = []
                applied = False
                if self._in_flight is not None:
                    got: tuple[PlanningRequest, Outcome] | None = None
                    due = s.recorded_frames.get(self._in_flight.index)
                    if due is None and replay is not None:
                        due = replay[self._in_flight.index]
                    if due is not None:
                        if due < self.world.frame:
                            raise SessionError(
                                f"replay: step {self._in_flight.index} was applied at frame {due}, "
                                f"but its request was made at frame {self._in_flight.frame}"
                            )
                        if due == self.world.frame:
                            got = await self._receive(results)
                    elif s.pace == "lockstep":
                        got = await self._receive(results)
                    else:
                        try:
                            got = results.receive_nowait()
                        except anyio.WouldBlock:
                            got = None
                        except (anyio.EndOfStream, anyio.ClosedResourceError):
                            self._in_flight = None
                    if got is not None:
                        request, outcome = got
                        self._in_flight = None
                        commands = self._apply(request, outcome)
                        applied = True
                self.world, out = step(self.world, commands, self.world.dt)
                self._observe(out)
                if self._wants_plan(out):
                    targets, seats = world_commitments(self.world)
                    request = PlanningRequest(
                        index=self._steps,
                        frame=self.world.frame,
                        roster=world_roster(self.world, self.events),
                        history=story_history(self.events),
                        targets=targets,
                        objects_in_use=seats,
                        instruction=self.instruction,
                        instruction_since=self._instruction_since,
                    )
                    self._steps += 1
                    self._asked = (tuple(out.available), self._changes)
                    self._in_flight = request
                    await requests.send(request)
                if s.pace == "realtime":
                    due_time = start + self.world.frame / (self.world.config.fps * s.speed)
                    delay = due_time - self.clock()
                    await anyio.sleep(max(0.0, delay))
                elif self.world.frame % 8 == 0 or self._in_flight is not None:
                    await anyio.sleep(0)
                if self.on_checkpoint is not None and every is not None and (
                    applied or self.world.frame - last_checkpoint >= every
                ):
                    self.on_checkpoint(self.checkpoint())
                    last_checkpoint = self.world.frame
                now = self.clock()
                self.frame_intervals.append(now - last)
                last = now
            self.wall_s = last - start
            # Close the request side; a step still in flight is abandoned (not applied).

    async def _receive(
        self, results: MemoryObjectReceiveStream[tuple[PlanningRequest, Outcome]]
    ) -> tuple[PlanningRequest, Outcome] | None:
        """The next planning result, or None when the planner stopped (see ``planner_error``)."""
        try:
            return await results.receive()
        except (anyio.EndOfStream, anyio.ClosedResourceError):
            self._in_flight = None
            return None

    async def run(self) -> SessionResult:
        req_send, req_recv = anyio.create_memory_object_stream[PlanningRequest](1)
        res_send, res_recv = anyio.create_memory_object_stream[tuple[PlanningRequest, Outcome]](1)
        try:
            async with anyio.create_task_group() as tg:
                tg.start_soon(self._planning_task, req_recv, res_send)
                try:
                    await self._simulation_task(req_send, res_recv)
                finally:
                    self._release_waiters()
                tg.cancel_scope.cancel()
        except BaseExceptionGroup as group:  # surface a lone error as itself
            if len(group.exceptions) == 1:
                raise group.exceptions[0] from None
            raise
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
        )

"""A story session: the simulation and the planner run concurrently in one anyio task group.

The simulation task owns the world and steps it frame by frame; it never waits on an LLM
call (except in ``lockstep`` and ``offline`` pace or when a replay says a result was applied at
this frame). When characters are available and no planning step is in flight, it takes a
snapshot of the world (roster and event history, at a known frame) and starts a planning task
for it in the session's task group; the task runs one step of the planning graph (narrator,
event parser, their retries) and sends its news (calls, claim, outcome) back through a memory
channel. The simulation applies the outcome at the frame it arrives and records that frame (story
log and trace ``applied`` record). The ``applied`` record names the step, the frame its request
was made at and the seqs of the trace records that produced the outcome, as the planner reports
them (``planner.trace_seqs(index)``, optional; without it the record names none).

Determinism: a planning request is built from the world at a frame the simulation chose, so
its content depends only on earlier frames. What can differ between two live runs is the
frame at which a result arrives; that frame is recorded. A replay reads the recorded frames
back and applies each result at exactly its frame, so the same events and the same motion
come out. ``lockstep`` pace applies every result at the frame it was requested (the
simulation pauses while the planner thinks), which is deterministic without a trace.

Overlapping steps (``SessionSettings.planners`` = N > 1): once every step in flight has named its
characters and fewer than N are in flight, the next step is requested for the free characters left
(``storyteller.orchestrator.session.steps_in_flight`` says when a step's news counts, in each pace). Such a
request is made at the start of a frame (``frame_start``, before the frame's outcomes are applied)
or, like every request with N = 1, after the world stepped (``frame_end``). With N = 1 nothing is
requested while a step is in flight. In ``realtime`` / ``fast`` pace the requests are reported to
``on_request`` (the run job writes them to the trace) and a replay makes each at its recorded frame
and phase (``SessionSettings.schedule``), after the steps it saw in flight claimed.

Off the event loop: nothing here blocks; the planning graph runs event programs and other CPU
work in worker threads (``storyteller.orchestrator.planning.node_calls.off_loop``), so in ``realtime`` pace the
simulation task keeps its frame rate while steps are planned.

``realtime`` pace: frame k is due ``k / (fps * speed)`` wall seconds after the start, and the
simulation task sleeps until then. A checkpoint is taken before that sleep, which absorbs its cost.
A frame that ends more than one frame period late (a stall) is not followed by a burst of catch-up
frames: the schedule slips by the delay instead (``SessionResult.slipped_s``), and the next frame is
due one period after it. Where each frame's wall time went is kept in
``SessionResult.frame_profile`` (``storyteller.orchestrator.session.frame_profile``); timing decides nothing but
when a realtime frame starts, so it never changes a story in the other paces. A ``pacer`` (a
director's pause and speed, ``storyteller.orchestrator.session.viewer_controls``) may hold a realtime simulation
between two frames and change its speed: that too moves only when frames start (a pause is left out
of the frame intervals). While a realtime session runs, its thread asks Linux for a short CPU slice,
so a frame's wait ends sooner on a busy machine (``storyteller.orchestrator.session.scheduler_slice``).

Failures: an ``LLMError`` from the planner stops planning and the story goes on
(``SessionResult.planner_error``); any other exception in any task cancels the task group
(every step in flight is cancelled, none is left pending) and :meth:`Session.run` raises it.

Checkpoints: with ``checkpoint_every_s`` set, ``on_checkpoint`` gets a
:class:`SessionCheckpoint` (between two frames) after every applied outcome and at least that
often; ``Session.resume(checkpoint)`` on a world built from the same inputs goes on from it
(the steps in flight then are asked again), and ends as the uninterrupted session would in ``lockstep`` pace
or with ``recorded_frames`` / ``recorded_requests`` for what the trace shows after it (``request_schedule``).

Instructions take effect at the start of a frame, before the world steps
(``storyteller.orchestrator.session.instruction_queue``: scheduled ones at their frame, live ones from
:meth:`Session.instruct` / :meth:`Session.instruct_nowait` at the next frame, on resume after
``recorded_until``); each is reported to ``on_instruction``.

The session's data types are in ``storyteller.orchestrator.session.session_types``, the planner's view of
the story (roster, history window, request) in ``storyteller.orchestrator.session.story_history``.
"""

from __future__ import annotations

import copy
import math
import time
from array import array
from collections.abc import Callable, Sequence

import anyio
import anyio.abc
import structlog
from anyio.streams.memory import MemoryObjectReceiveStream, MemoryObjectSendStream

from storyteller.agents.llm_port import LLMError, TraceRecorder
from storyteller.agents.messages import ParsedEvent, PlanningFailure
from storyteller.orchestrator.session.frame_profile import FrameProfile
from storyteller.orchestrator.session.instruction_queue import InstructionQueue
from storyteller.orchestrator.session.request_schedule import RequestSchedule
from storyteller.orchestrator.session.scheduler_slice import short_slice
from storyteller.orchestrator.session.session_types import (
    InstructionSource,
    Outcome,
    Pacer,
    PlanningRequest,
    RecordedRequest,
    RequestPhase,
    SessionCheckpoint,
    SessionError,
    SessionResult,
    SessionSettings,
    StepPlanner,
    StoryEvent,
    TimedInstruction,
    check_settings,
    event_id_for,
)
from storyteller.orchestrator.session.steps_in_flight import Flight, News, StepNews, StepsInFlight, post_news
from storyteller.orchestrator.session.story_history import applied_event, apply_step_output, planning_request
from storyteller.sim.world.events import AssignEvent, EventFailure
from storyteller.sim.world.step import World, step

_log = structlog.get_logger("storyteller.session")


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
        check_settings(settings)
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
        self._inflight = StepsInFlight(settings, world.config.fps)
        self._flights = self._inflight.by_index  # steps in flight, by index (the same dict)
        self._schedule: RequestSchedule | None = None  # recorded requests to make again (request_schedule)
        self._follow(RequestSchedule.of(settings))
        self._news_send: MemoryObjectSendStream[News] | None = None
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
        self._queue = InstructionQueue(settings.instructions, live=settings.live_instructions)
        self._resent: list[PlanningRequest] = []  # resumed: steps in flight at the checkpoint, asked again
        self.frame_intervals: array[float] = array("d")  # wall seconds between frames (8 B each)
        self.profile = FrameProfile()  # where each frame's wall time went (24 B each)
        self.slipped_s = 0.0  # realtime: wall seconds the schedule slipped after stalls
        self.wall_s = 0.0

    # ----- checkpoints ---------------------------------------------------------------------
    def checkpoint(self) -> SessionCheckpoint:
        """A copy of the session's state at the current frame (between two frames)."""
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
        self._queue.skip_before(self.world.frame)
        if self.settings.schedule is None:  # the trace's requests of the steps after the checkpoint, first
            self._follow(RequestSchedule.of(self.settings, after_step=cp.steps))

    def _follow(self, schedule: RequestSchedule | None) -> None:
        self._schedule = schedule
        self._inflight.holding = schedule is not None and schedule.then_live

    # ----- instructions ------------------------------------------------------------------
    async def instruct(self, text: str, source: InstructionSource = "api") -> int | None:
        """Make ``text`` the instruction from the next frame the simulation starts; returns
        that frame once it took effect (None: ignored, in a replay, or the story had ended).
        Called before :meth:`run`, it waits for the run's first frame. Raises ValueError for
        an empty text."""
        return await self._queue.instruct(text, source)

    def instruct_nowait(self, text: str, source: InstructionSource = "stdin") -> bool:
        """:meth:`instruct` without waiting; safe to call from any thread (e.g. a stdin reader).
        False when the instruction is ignored (a replay, or the story has ended)."""
        return self._queue.instruct_nowait(text, source)

    def _take_instructions(self) -> None:
        """Apply the instructions due at the current frame (before it steps), in order."""
        frame = self.world.frame
        for timed, event in self._queue.due(frame, live=frame > self.settings.recorded_until):
            if timed.frame != frame:
                raise SessionError(f"instruction for frame {timed.frame} reached at frame {frame}")
            self.instruction = timed.text
            self._instruction_since = self._steps
            self._unchanged_until = None  # a new instruction is a change: ask again
            self.instructions.append(timed.model_copy(update={"recorded": False}))
            if self.on_instruction is not None and not timed.recorded:
                self.on_instruction(timed)
            _log.info("instruction", frame=frame, source=timed.source, text=timed.text)
            self._queue.took_effect(event, frame)

    # ----- planning side ------------------------------------------------------------------
    async def _plan_step(self, request: PlanningRequest, news: MemoryObjectSendStream[News]) -> None:
        """One planning step; its progress and outcome go to the simulation as news. An
        ``LLMError`` stops planning (the story goes on, see ``planner_error``); any other
        exception ends the session (the task group cancels every task)."""
        with news:
            try:
                outcome = await self.planner.plan(request, StepNews(request.index, news))
            except LLMError as exc:
                post_news(news, News(request.index, "stopped", error=exc))
                return
            post_news(news, News(request.index, "outcome", outcome=outcome))

    def _send(self, request: PlanningRequest, phase: RequestPhase, *, resent: bool = False) -> None:
        assert self._tg is not None and self._news_send is not None
        after = tuple(sorted(self._flights))
        self._flights[request.index] = Flight(request)
        if self.on_request is not None and self.settings.planners > 1 and not resent:
            self.on_request(RecordedRequest(step=request.index, frame=request.frame, phase=phase, after=after))
        self._tg.start_soon(self._plan_step, request, self._news_send.clone())

    def _note(self, news: News) -> None:
        error = self._inflight.note(news)
        if error is not None:  # stopped: the story goes on without a planner; the caller reports it
            self.planner_error = error

    def _drain(self, news: MemoryObjectReceiveStream[News]) -> None:
        while True:
            try:
                self._note(news.receive_nowait())
            except anyio.WouldBlock:
                return

    async def _next_news(self, news: MemoryObjectReceiveStream[News]) -> None:
        self._note(await news.receive())

    def _wants_plan(self, available: Sequence[str], frame: int) -> tuple[str, ...] | None:
        """The free characters to plan for now (not in a step in flight), or None."""
        s = self.settings
        if len(self._flights) >= s.planners or self.planner_error is not None:
            return None
        if s.max_steps is not None and self._steps - self._waits >= s.max_steps:
            return None
        if s.applied_frames is not None and self._steps >= len(s.applied_frames):
            return None
        claimed = self._inflight.claimed(frame)
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
        """The request for the next step, from the world now (``story_history.planning_request``)."""
        return planning_request(
            self.world, self.events, self.outcomes, self._inflight.claimed(frame) or {},
            index=self._steps, instruction=self.instruction, since=self._instruction_since,
        )

    def _ask(self, free: Sequence[str], frame: int, phase: RequestPhase, *, resent: bool = False) -> None:
        request = self._request(frame)
        self._steps += 1
        self._asked = (tuple(free), self._changes)
        self._send(request, phase, resent=resent)

    async def _ask_scheduled(self, news: MemoryObjectReceiveStream[News], phase: RequestPhase) -> int:
        """Make the requests recorded at this frame and phase (``request_schedule``); how many."""
        schedule = self._schedule
        assert schedule is not None
        at = self.world.frame - 1 if phase == "frame_end" else self.world.frame  # as a live request sees claims
        first = self._steps
        while (rec := schedule.take(self.world.frame, phase)) is not None:
            while (claimed := self._inflight.claimed(at)) is None:
                await self._next_news(news)
            schedule.check(rec, self._steps, list(self._flights))
            self._unchanged_until = None  # as after a live request; a resume's are in the trace already:
            self._ask([a for a in self.world.available() if a not in claimed], at, phase, resent=schedule.then_live)
        if schedule.done:
            self._follow(None)
        return self._steps - first

    async def _settle(self, news: MemoryObjectReceiveStream[News]) -> list[Flight]:
        """Take the news the current frame needs (waiting for it in ``lockstep`` and
        ``offline`` pace, and for recorded frames), start the steps it allows beside the ones
        in flight, and return the steps whose outcome is applied at this frame, in step order."""
        frame = self.world.frame
        while True:
            self._drain(news)
            if any(self._inflight.unsettled(fl, frame) for fl in list(self._flights.values())):
                await self._next_news(news)
                continue
            if self._schedule is not None:
                await self._ask_scheduled(news, "frame_start")
            if self._schedule is None and self._flights and self.settings.planners > 1:
                free = self._wants_plan(self.world.available(), frame)
                if free is not None:
                    self._ask(free, frame, "frame_start")
                    continue
            if any(self._inflight.pending(fl, frame) for fl in list(self._flights.values())):
                await self._next_news(news)
                continue
            due = (fl for fl in self._flights.values() if self._inflight.due(fl, frame))
            return sorted(due, key=lambda f: f.request.index)

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
        ev = applied_event(eid, request, outcome, frame, self.world.scene)
        self.events[eid] = ev
        if self.on_event is not None:
            self.on_event(ev)
        return [command]

    async def _simulation_task(self, news: MemoryObjectReceiveStream[News]) -> None:
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
            self._changes += apply_step_output(self.events, self.failures, out, self.on_event)
            if self.on_frame is not None:
                self.on_frame(self.world)
            t_ask = clock()
            made = await self._ask_scheduled(news, "frame_end") if self._schedule is not None else 0
            if self._schedule is None and not made:  # a frame makes one request at its end at most
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
        news_send, news_recv = anyio.create_memory_object_stream[News](math.inf)
        try:
            async with anyio.create_task_group() as tg:
                self._tg = tg
                self._news_send = news_send
                try:
                    with news_recv, short_slice(enabled=self.settings.pace == "realtime"):
                        await self._simulation_task(news_recv)
                finally:
                    self._queue.close()
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


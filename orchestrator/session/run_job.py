"""The ``run`` job: plan and animate a story in a scene, then write its outputs.

:func:`run_story` builds the world (characters at the start positions of the seed), the LLM
port (recording to a trace, or replaying one), the planning graph of the chosen ablation and
the story session, and runs them to the end; :func:`~storyteller.orchestrator.session.run_outputs.write_outputs` writes ``story.json``
(:func:`~storyteller.orchestrator.session.run_outputs.story_json`), ``story.md`` and ``metrics.json`` (``storyteller.orchestrator.session.run_report``),
the motion exports and the pictures. With a replayed trace the session applies each planning
result at the frame recorded there, so the same arguments give the same story and the same
motion.

Resume: a run writes ``run.json`` (``storyteller.orchestrator.session.run_manifest``) before its first
frame and keeps its session's last checkpoint in ``session.snapshot``
(``storyteller.orchestrator.session.snapshot_file``), written by a worker thread
(``storyteller.orchestrator.session.checkpoint_writer``: the frames never wait on its fsyncs; the newest
checkpoint is on disk before :func:`run_story` returns or raises). ``run_story(..., resume=True)`` restores the world
and the story from it; steps the trace shows applied are applied again at their recorded
frames (and not traced twice), and the planner answers finished steps from the story log and
finishes a cut step from its langgraph checkpoint, so no event is lost or duplicated and no
call whose node was checkpointed is repeated.

Motion: the world streams its frames to ``motion/<name>.chunks`` in the run folder
(``storyteller.sim.world.track_chunks``) and keeps one window of them in memory; the checkpoint holds only
the frames not yet in the chunk files and how many are. A resume keeps the streamed frames up
to that count and goes on from the checkpoint; the exports read the chunk files.

Live viewing: ``scene.json`` is written (and a ``story.json`` of an earlier run in the folder
removed) before the first frame, and ``story.jsonl`` (``storyteller.orchestrator.session.story_stream``)
gets a line whenever an event starts, completes or fails, so ``storyteller view`` can follow a
run in progress from them and the chunk files; ``story.json`` appears when the run ends.
``live.json`` (``storyteller.orchestrator.session.live_state``) is the run now for a viewer's panels (frame,
pause and speed, the planner's roles and last replies, each character), replaced a few times a
second; a realtime run takes a director's pause and speed from ``viewer_controls.jsonl``
(``storyteller.orchestrator.session.viewer_controls``), applied between two frames, nothing of it traced.

Instructions: the timed script (``RunArguments.instructions``) is scheduled at its frames,
lines typed on stdin (``interactive``) and lines a viewer's box appends to
``viewer_instructions.jsonl`` (``storyteller.orchestrator.session.viewer_instructions``; read by every run
that is not a replay) take effect at the next frame, and every one is
written to the trace as an ``instruction`` record with its frame. A replay schedules the
trace's instruction records at their frames and ignores the script and stdin; a resume
applies the recorded ones again (not traced twice) and the script lines not yet applied.

Overlapping planning (``RunArguments.planners`` > 1): the trace gets a ``requested`` record per
step, and a replay makes every request where the recorded run did
(``SessionSettings.schedule``), and a resume makes the ones its trace holds after the checkpoint
again, not traced twice, before it asks live (``storyteller.orchestrator.session.request_schedule``), and
takes a viewer's or stdin's line after the last frame its trace shows; a step the recorded run
still had in flight when its story ended is asked again and its unanswered call waits to the end
as it did (the replay port's ``unanswered="wait"``, ``storyteller.orchestrator.llm.replay``), so the replay
ends with the recorded story and exit 0. Any error other than the user's inputs or the LLM's (a bug, a
failing disk) cancels the session's task group and is raised from :func:`run_story` after the
trace, the story log and the program worker are closed.

Writes: every file in the run folder is written without following a symbolic link (replaced
through a fresh temporary name, or opened with ``O_NOFOLLOW``: ``storyteller.sim.no_follow_writes``), and
:func:`run_story` first refuses a folder that is a link or holds one where the run writes
(``storyteller.orchestrator.session.run_folder_links``), so nothing is written outside the folder.

Problems with the user's inputs (an unreadable trace or motion config, a model that cannot be
opened, a damaged ``runs.sqlite``, a session that cannot go on) are raised as
:class:`~storyteller.orchestrator.session.run_setup.RunSetupError`, one sentence each, naming the file. A write that fails (a full disk)
raises ``OSError`` naming the file; what was written before stays readable (the trace keeps
whole lines, ``session.snapshot`` the previous checkpoint). A run stopped through ``stop``
(SIGINT, SIGTERM) saves its checkpoint at the frame it stopped at and returns the story so far.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from storyteller.orchestrator.planning.ablation_graph import Ablation
from storyteller.orchestrator.session.run_folder_links import PlantedLinkError, refuse_planted_links
from storyteller.orchestrator.session.run_manifest import RunArguments, RunManifest
from storyteller.orchestrator.session.run_outputs import write_scene_json
from storyteller.orchestrator.session.run_setup import (
    RecordedInputs,
    RunContext,
    RunSetupError,
    check_motion,
    check_replayed,
    open_run_port,
    open_story_log,
    planning_deps,
    read_recorded,
    saved_checkpoint,
    session_settings,
    start_manifest,
    start_world,
    streaming_world,
)
from storyteller.orchestrator.session.run_status import RunStatus
from storyteller.orchestrator.session.runtime import Session
from storyteller.orchestrator.session.session_types import (
    RecordedRequest,
    SessionCheckpoint,
    SessionError,
    SessionResult,
    SessionSettings,
    StoryEvent,
    TimedInstruction,
)
from storyteller.sim.no_follow_writes import remove_stale_temporaries
from storyteller.sim.run_folder_names import (
    MOTION_FOLDER,
    RUNS_DB,
    STORY_JSON,
)
from storyteller.sim.scene.model import Scene

if TYPE_CHECKING:
    from storyteller.orchestrator.planning.state import PlanningDeps
    from storyteller.orchestrator.sandbox_worker import WorkerRunner
    from storyteller.orchestrator.session.live_state import ReplyTap
    from storyteller.sim.world.step import World
    from storyteller.sim.world.track_chunks import ChunkStore


@dataclass(frozen=True)
class StoryRun:
    """What :func:`run_story` returns: the session's result, the names, the fps, the world, and
    whether the run was stopped early (``stop`` was set) rather than played to its end."""

    result: SessionResult
    names: list[str]
    fps: int
    world: World
    stopped: bool = False


async def run_story(
    scene: Scene,
    args: RunArguments,
    *,
    out: Path,
    trace_path: Path | None,
    replay: Path | None,
    thread_id: str | None = None,
    resume: bool = False,
    interactive: bool = False,
    on_event: Callable[[StoryEvent, int], None] | None = None,
    on_start: Callable[[RunManifest], None] | None = None,
    on_resume: Callable[[int, int], None] | None = None,
    on_instruction: Callable[[TimedInstruction, int], None] | None = None,
    in_process_programs: bool = False,
    stop: asyncio.Event | None = None,
    status: RunStatus | None = None,
    stdin_reader: Callable[[Session], object] | None = None,
    programs: WorkerRunner | None = None,
) -> StoryRun:
    """Run the story session; returns the result, the character names, the fps and the world.

    A live or replayed run writes ``run.json`` before the first frame (``on_start(manifest)``
    is called then) and keeps the session's last checkpoint in ``session.snapshot`` (after
    every applied planning step and every :data:`~storyteller.orchestrator.session.run_setup.CHECKPOINT_EVERY_S` simulated seconds).
    ``resume=True`` goes on from that checkpoint on the thread ``thread_id``: the world is
    restored from it, steps whose result the trace already shows applied are applied at their
    recorded frames again, and the planner answers finished steps from its story log.

    ``on_resume(frame, fps)`` tells the frame a resumed session goes on from (0: no checkpoint was
    kept). ``on_event(event, fps)`` is called whenever a story event starts, loops, completes or fails.
    ``on_instruction(instruction, fps)`` when a new instruction takes effect. ``interactive``: lines typed on stdin become the instruction while the story runs (not in a replay),
    read by ``stdin_reader(session)`` when given (e.g. ``storyteller.orchestrator.session.terminal_prompt``
    under a live view), else by ``storyteller.orchestrator.session.stdin_instructions``.
    Event programs run in an OS-limited worker process started for the run and stopped when
    it ends (``in_process_programs``: in this process instead; the plans are the same). It is
    started first, with the scene to load, so its imports and the scene's navigation grid
    overlap this set-up; ``programs``: that worker, started (:meth:`WorkerRunner.prestart`)
    by the caller even earlier (the command, before it imports this job), stopped here too.

    ``stop``: once set (by a signal handler), the session is cancelled where it waits (a frame
    is never cut in half), its checkpoint at that frame is saved and the story so far is
    returned with ``stopped=True``; an LLM call in flight is abandoned, and resume asks it
    again unless its node was checkpointed.

    ``status``: told every happening of the run (its frames, events, outcomes, instructions and
    LLM calls; ``storyteller.orchestrator.session.run_status``), for a live view."""
    from storyteller.orchestrator.sandbox_worker import WorkerRunner

    if programs is None and not in_process_programs:
        programs = WorkerRunner()
    if programs is not None:
        programs.prestart(scene)  # its imports and the scene's grid overlap the set-up below
    try:
        return await _run_story(
            scene, args, out=out, trace_path=trace_path, replay=replay, thread_id=thread_id, resume=resume,
            interactive=interactive, on_event=on_event, on_start=on_start, on_resume=on_resume,
            on_instruction=on_instruction, stop=stop, status=status, stdin_reader=stdin_reader, programs=programs,
        )
    finally:
        if programs is not None:
            programs.close()


async def _run_story(
    scene: Scene,
    args: RunArguments,
    *,
    out: Path,
    trace_path: Path | None,
    replay: Path | None,
    thread_id: str | None,
    resume: bool,
    interactive: bool,
    on_event: Callable[[StoryEvent, int], None] | None,
    on_start: Callable[[RunManifest], None] | None,
    on_resume: Callable[[int, int], None] | None,
    on_instruction: Callable[[TimedInstruction, int], None] | None,
    stop: asyncio.Event | None,
    status: RunStatus | None,
    stdin_reader: Callable[[Session], object] | None,
    programs: WorkerRunner | None,
) -> StoryRun:
    """:func:`run_story` once its program worker (``programs``; None: programs run in this
    process) is started; the caller stops it too. What the run opens (the LLM port and its
    trace, the story log, the story stream, the checkpoint writer, the readers of a viewer's
    instructions and controls, the program worker) is closed once, by one exit stack, whether
    the set-up fails, the story ends or it stops with an error."""
    from storyteller.agents.llm_port import LLMError
    from storyteller.orchestrator.session.snapshot_file import SNAPSHOT_FILE
    from storyteller.sim.world.step import WorldConfig

    names = list(args.names)
    try:
        refuse_planted_links(out, names)  # before anything is read from the folder or written to it
    except PlantedLinkError as exc:
        raise RunSetupError(str(exc)) from None
    world_config = WorldConfig(seed=args.seed, foot_ik=args.foot_ik)
    fps = world_config.fps
    recorded = read_recorded(args, fps, trace_path=trace_path, replay=replay, resume=resume)
    world = start_world(scene, args, names, world_config)
    ablation = Ablation(planner=args.planner, description=args.description)
    thread = thread_id if resume and thread_id is not None else ablation.thread_id(thread_id or f"run-{uuid.uuid4().hex[:12]}")
    snapshot_path = out / SNAPSHOT_FILE
    checkpoint = saved_checkpoint(snapshot_path, world) if resume else None
    check_motion(out, names, checkpoint)
    # the trace is opened (a resumed run appends to it) once what the folder holds has been read and checked,
    # and the temporary files of a run killed mid-write (kill -9) are gone
    for folder in (out, out / MOTION_FOLDER):
        remove_stale_temporaries(folder)
    if status is None:  # the run's state for a viewer (live.json) is read from it too
        status = RunStatus()
    run = RunContext(scene, args, names, fps, out, thread, replay, resume, interactive, stop, stdin_reader, on_resume)
    with contextlib.ExitStack() as stack:  # closes, in this order: readers, checkpoints, stream, story, port, programs
        if programs is not None:  # stopped before the chunk files are closed and the outputs written
            stack.callback(programs.close)
        replies, describer_model = open_run_port(args, trace_path, replay, status, stack)
        world = streaming_world(world, out, names, checkpoint)
        if not resume:
            start_manifest(run, on_start)
        # for a live viewer: the scene before the first frame, and no story.json (it marks a finished run)
        write_scene_json(scene, out)
        (out / STORY_JSON).unlink(missing_ok=True)
        story = open_story_log(out / RUNS_DB, thread, stack)
        deps = planning_deps(run, replies, story, describer_model, programs)
        settings = session_settings(args, fps, recorded, live=replay is None)
        hooks = _RunHooks(run, snapshot_path, replies, status, on_event=on_event, on_instruction=on_instruction)
        stack.callback(hooks.stream.close)
        stack.callback(hooks.close_checkpoints)  # after an error: the newest checkpoint still lands
        stack.callback(hooks.inbox_closed.set)
        try:
            session, result, stopped = await _play(run, ablation, deps, settings, world, hooks, checkpoint, recorded)
        except (LLMError, SessionError) as exc:
            raise RunSetupError(f"{type(exc).__name__}: {exc}") from None
    end = session.world.buffers
    if end.store is not None:  # the whole story in the chunk files (the viewer reads them)
        end.spill()
        end.store.sync()
        end.store.close()  # read back by path from here on
    applied = recorded.applied
    if replay is not None and applied is not None and not stopped and result.planner_error is None:
        check_replayed(replay, applied, result)
    return StoryRun(result, names, fps, session.world, stopped)


class _RunHooks:
    """The session's callbacks in a run and what they write to: the trace's instruction and
    request records, the run's status, ``story.jsonl``, ``session.snapshot`` (by a
    :class:`CheckpointWriter`), ``live.json`` and a director's controls, and the caller's own."""

    def __init__(self, run: RunContext, snapshot_path: Path, replies: ReplyTap, status: RunStatus, *,
                 on_event: Callable[[StoryEvent, int], None] | None,
                 on_instruction: Callable[[TimedInstruction, int], None] | None) -> None:
        from storyteller.orchestrator.llm.trace_writer import TraceWriter
        from storyteller.orchestrator.session.checkpoint_writer import CheckpointWriter
        from storyteller.orchestrator.session.live_state import LivePublisher
        from storyteller.orchestrator.session.story_stream import StoryStream
        from storyteller.orchestrator.session.viewer_controls import DirectorControls, controls_refusal

        self.fps = run.fps
        self.status = status
        self.on_event = on_event
        self.on_instruction = on_instruction
        self.refusal = controls_refusal(run.args.pace)  # a director's pause and speed: realtime only
        self.controls = DirectorControls(run.args.speed)
        self.live = LivePublisher(run.out, run.thread, status, replies, self.controls, speed=run.args.speed,
                                  refusal=self.refusal)
        self.trace = replies.trace
        self.writer = replies.trace if isinstance(replies.trace, TraceWriter) else None
        self.session: Session | None = None
        self.stream = StoryStream(run.out)
        self.checkpoints = CheckpointWriter(snapshot_path, write=self._write_after_trace)
        self.inbox_closed = threading.Event()
        self.finished = False
        """The run ended without an error (a failed checkpoint write is then raised on close)."""

    def said(self, timed: TimedInstruction) -> None:
        if self.writer is not None:
            self.writer.record_instruction(timed.text, timed.frame, source=timed.source)
        self.status.instruction(timed)
        if self.on_instruction is not None:
            self.on_instruction(timed, self.fps)

    def requested(self, r: RecordedRequest) -> None:
        if self.writer is not None:
            self.writer.record_requested(r.step, r.frame, phase=r.phase, after_steps=r.after)

    def keep(self, cp: SessionCheckpoint) -> None:  # written in the writer's thread: the frames go on
        assert self.session is not None
        self.checkpoints.submit(self.session.world, cp)

    def streamed(self, event: StoryEvent) -> None:
        self.stream.event(event)
        self.status.event(event)
        if self.on_event is not None:
            self.on_event(event, self.fps)

    def _write_after_trace(self, path: Path, cp: SessionCheckpoint, shared: dict[int, str], store: ChunkStore | None) -> None:
        from storyteller.orchestrator.session.snapshot_file import write_checkpoint

        if self.writer is not None:  # the checkpoint counts on the trace's applied records: on disk first
            self.writer.sync()
        write_checkpoint(path, cp, shared, store)

    def close_checkpoints(self) -> None:
        self.checkpoints.close(raise_errors=self.finished)


async def _play(run: RunContext, ablation: Ablation, deps: PlanningDeps, settings: SessionSettings, world: World,
                hooks: _RunHooks, checkpoint: SessionCheckpoint | None,
                recorded: RecordedInputs) -> tuple[Session, SessionResult, bool]:
    """Build the session on the planning graph and run it (until ``run.stop``, if set first),
    publishing ``live.json`` meanwhile; its last checkpoint is on disk when this returns."""
    from storyteller.orchestrator.planning.ablation_graph import compile_graph
    from storyteller.orchestrator.planning.checkpoints import open_checkpointer
    from storyteller.orchestrator.session.step_planner import GraphStepPlanner

    async with open_checkpointer(run.out / RUNS_DB) as saver:
        planner = GraphStepPlanner(compile_graph(ablation, saver), deps, run.thread, lanes=run.args.planners)
        session = Session(world, planner, settings, trace=hooks.trace, on_event=hooks.streamed,
                          on_checkpoint=hooks.keep, on_instruction=hooks.said, on_request=hooks.requested,
                          on_outcome=hooks.status.outcome, on_frame=hooks.status.frame,
                          pacer=hooks.controls if hooks.refusal is None else None)
        hooks.session = session
        _start_session(run, session, hooks, checkpoint, recorded.said)
        publishing = asyncio.ensure_future(hooks.live.run())
        try:
            result, stopped = await _run_until_stopped(session, run.stop)
        finally:
            publishing.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await publishing
        with contextlib.suppress(OSError):
            hooks.live.write(hooks.live.state(running=False))
        if stopped:
            hooks.keep(session.checkpoint())
        hooks.checkpoints.flush()  # the last checkpoint on disk before the run returns
        hooks.finished = True
    return session, result, stopped


def _start_session(run: RunContext, session: Session, hooks: _RunHooks, checkpoint: SessionCheckpoint | None,
                   said: list[TimedInstruction]) -> None:
    """Resume ``session`` from ``checkpoint``, tell the status and ``story.jsonl`` where the
    story starts, and start the readers of stdin, a viewer's instructions and its controls."""
    from storyteller.orchestrator.session.story_stream import StreamStart
    from storyteller.orchestrator.session.viewer_controls import CONTROLS_FILE, start_control_reader
    from storyteller.orchestrator.session.viewer_instructions import INBOX_FILE, start_inbox_reader

    if checkpoint is not None:
        session.resume(checkpoint)
    hooks.status.started(session.world, frames=session.settings.frames, pace=session.settings.pace,
                         instruction=session.instruction, events=session.events.values(), outcomes=session.outcomes)
    hooks.stream.start(
        StreamStart(scene=run.scene.name, characters=tuple(run.names), instruction=run.args.instruction, fps=run.fps,
                    frame=session.world.frame),
        checkpoint.events.values() if checkpoint is not None else (),
    )
    if run.resume and run.on_resume is not None:
        run.on_resume(session.world.frame, run.fps)
    if run.interactive and run.replay is None:
        from storyteller.orchestrator.session.stdin_instructions import start_stdin_reader

        (run.stdin_reader or start_stdin_reader)(session)
    if run.replay is None:  # a viewer's instruction box, in this process or another
        start_inbox_reader(session, run.out / INBOX_FILE, run.thread, [i.text for i in said if i.source == "viewer"],
                           stop=hooks.inbox_closed, after_frame=max((i.frame for i in said), default=-1))
    if hooks.refusal is None:
        start_control_reader(hooks.controls, run.out / CONTROLS_FILE, run.thread, stop=hooks.inbox_closed)


async def _run_until_stopped(session: Session, stop: asyncio.Event | None) -> tuple[SessionResult, bool]:
    """``session.run()``, cancelled when ``stop`` is set first; (the story so far, stopped?)."""
    if stop is None:
        return await session.run(), False
    running = asyncio.ensure_future(session.run())
    stopping = asyncio.ensure_future(stop.wait())
    try:
        await asyncio.wait({running, stopping}, return_when=asyncio.FIRST_COMPLETED)
    except BaseException:
        running.cancel()
        raise
    finally:
        stopping.cancel()
    if running.done():
        return running.result(), False
    running.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await running
    return session.result(), True



"""The ``run`` job: plan and animate a story in a scene, then write its outputs.

:func:`run_story` builds the world (characters at the start positions of the seed), the LLM
port (recording to a trace, or replaying one), the planning graph of the chosen ablation and
the story session, and runs them to the end; :func:`write_outputs` writes ``story.json``
(:func:`story_json`), ``story.md`` and ``metrics.json`` (``orchestrator.session.run_report``),
the motion exports and the pictures. With a replayed trace the session applies each planning
result at the frame recorded there, so the same arguments give the same story and the same
motion.

Resume: a run writes ``run.json`` (``orchestrator.session.run_manifest``) before its first
frame and keeps its session's last checkpoint in ``session.snapshot``
(``orchestrator.session.snapshot_file``), written by a worker thread
(``orchestrator.session.checkpoint_writer``: the frames never wait on its fsyncs; the newest
checkpoint is on disk before :func:`run_story` returns or raises). ``run_story(..., resume=True)`` restores the world
and the story from it; steps the trace shows applied are applied again at their recorded
frames (and not traced twice), and the planner answers finished steps from the story log and
finishes a cut step from its langgraph checkpoint, so no event is lost or duplicated and no
call whose node was checkpointed is repeated.

Motion: the world streams its frames to ``motion/<name>.chunks`` in the run folder
(``sim.world.track_chunks``) and keeps one window of them in memory; the checkpoint holds only
the frames not yet in the chunk files and how many are. A resume keeps the streamed frames up
to that count and goes on from the checkpoint; the exports read the chunk files.

Live viewing: ``scene.json`` is written (and a ``story.json`` of an earlier run in the folder
removed) before the first frame, and ``story.jsonl`` (``orchestrator.session.story_stream``)
gets a line whenever an event starts, completes or fails, so ``storyteller view`` can follow a
run in progress from them and the chunk files; ``story.json`` appears when the run ends.
``live.json`` (``orchestrator.session.live_state``) is the run now for a viewer's panels (frame,
pause and speed, the planner's roles and last replies, each character), replaced a few times a
second; a realtime run takes a director's pause and speed from ``viewer_controls.jsonl``
(``orchestrator.session.viewer_controls``), applied between two frames, nothing of it traced.

Instructions: the timed script (``RunArguments.instructions``) is scheduled at its frames,
lines typed on stdin (``interactive``) and lines a viewer's box appends to
``viewer_instructions.jsonl`` (``orchestrator.session.viewer_instructions``; read by every run
that is not a replay) take effect at the next frame, and every one is
written to the trace as an ``instruction`` record with its frame. A replay schedules the
trace's instruction records at their frames and ignores the script and stdin; a resume
applies the recorded ones again (not traced twice) and the script lines not yet applied.

Overlapping planning (``RunArguments.planners`` > 1): the trace gets a ``requested`` record per
step, and a replay makes every request where the recorded run did
(``SessionSettings.schedule``); a step the recorded run still had in flight when its story
ended is asked again and its unanswered call waits to the end as it did (the replay port's
``unanswered="wait"``, ``orchestrator.llm.replay``), so the replay ends with the recorded story
and exit 0. Any error other than the user's inputs or the LLM's (a bug, a
failing disk) cancels the session's task group and is raised from :func:`run_story` after the
trace, the story log and the program worker are closed.

Writes: every file in the run folder is written without following a symbolic link (replaced
through a fresh temporary name, or opened with ``O_NOFOLLOW``: ``sim.no_follow_writes``), and
:func:`run_story` first refuses a folder that is a link or holds one where the run writes
(``orchestrator.session.run_folder_links``), so nothing is written outside the folder.

Problems with the user's inputs (an unreadable trace or motion config, a model that cannot be
opened, a damaged ``runs.sqlite``, a session that cannot go on) are raised as
:class:`RunSetupError`, one sentence each, naming the file. A write that fails (a full disk)
raises ``OSError`` naming the file; what was written before stays readable (the trace keeps
whole lines, ``session.snapshot`` the previous checkpoint). A run stopped through ``stop``
(SIGINT, SIGTERM) saves its checkpoint at the frame it stopped at and returns the story so far.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import sqlite3
import threading
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, get_args

from agents.messages import ParsedEvent, PlanningFailure
from agents.story_text import step_text
from orchestrator.planning.ablation_graph import Ablation
from orchestrator.session.run_folder_links import PlantedLinkError, refuse_planted_links
from orchestrator.session.run_manifest import RunArguments, RunManifest
from orchestrator.session.run_status import RunStatus
from orchestrator.session.runtime import Session
from orchestrator.session.session_types import (
    InstructionSource,
    RecordedRequest,
    SessionResult,
    StoryEvent,
    TimedInstruction,
)
from sim.no_follow_writes import remove_stale_temporaries, replacing, write_file
from sim.run_folder_names import (
    ANIMATION_STEM,
    METRICS_JSON,
    MOTION_FOLDER,
    RUNS_DB,
    SCENE_JSON,
    STORY_JSON,
    STORY_MD,
    TOPDOWN_PNG,
)
from sim.scene.model import Scene

if TYPE_CHECKING:
    from orchestrator.sandbox_worker import WorkerRunner

CHECKPOINT_EVERY_S = 10.0
"""Simulated seconds between two session checkpoints at most (also one after every applied step)."""


class RunSetupError(Exception):
    """A run that cannot start or go on because of its inputs (the message says which)."""


@dataclass(frozen=True)
class StoryRun:
    """What :func:`run_story` returns: the session's result, the names, the fps, the world, and
    whether the run was stopped early (``stop`` was set) rather than played to its end."""

    result: SessionResult
    names: list[str]
    fps: int
    world: Any
    stopped: bool = False


def applied_frames_from_trace(path: Path) -> list[int | None]:
    """Frame at which a recorded run applied each planning step's result, by step (overlapping
    steps may be applied out of order; None: a step it never applied). Records without a step
    (older traces) count in the order written."""
    from orchestrator.llm.traces import AppliedRecord, read_trace

    records = [r for r in read_trace(path).records if isinstance(r, AppliedRecord)]
    if any(r.step is None for r in records):
        return [r.sim_frame for r in records]
    frames: list[int | None] = [None] * (max((r.step for r in records if r.step is not None), default=-1) + 1)
    for r in records:
        assert r.step is not None
        frames[r.step] = r.sim_frame
    return frames


def schedule_from_trace(path: Path) -> list[RecordedRequest]:
    """When a recorded run with overlapping planning steps requested each step."""
    from orchestrator.llm.traces import read_trace

    return [RecordedRequest(step=r.step, frame=r.sim_frame, phase=r.phase, after=r.after_steps)
            for r in read_trace(path).requests()]


def replayable_frames(path: Path) -> list[int | None]:
    """:func:`applied_frames_from_trace` of a trace to replay, which must end with a whole line:
    a cut last record (a run killed mid-write) is a :class:`RunSetupError`, not a shorter story."""
    from orchestrator.llm.traces import read_trace

    contents = read_trace(path)
    if contents.torn_tail is not None:
        raise RunSetupError(
            f"{path}: line {contents.torn_tail.line_no} is cut short ({contents.torn_tail.size} bytes; the run "
            "stopped while writing it): `storyteller resume` the run to repair it, or replay a complete trace"
        )
    return applied_frames_from_trace(path)


def check_replayable(trace: Path, applied: list[int | None], instructions: list[TimedInstruction], frames: int) -> None:
    """Refuse (:class:`RunSetupError`) a replay that could not apply every recorded step and
    instruction: one recorded at or after the run's last frame (``frames``, from ``run.json``)
    would be dropped without a word."""
    for step_index, frame in enumerate(applied):
        if frame is not None and frame >= frames:
            raise RunSetupError(
                f"{trace}: step {step_index} was applied at frame {frame}, but the run has {frames} frames "
                "(run.json's duration): the replay could not apply it"
            )
    for instruction in instructions:
        if instruction.frame >= frames:
            raise RunSetupError(
                f"{trace}: an instruction took effect at frame {instruction.frame}, but the run has {frames} frames "
                "(run.json's duration): the replay could not apply it"
            )


def check_replayed(trace: Path, applied: list[int | None], result: SessionResult) -> None:
    """Refuse (:class:`RunSetupError`) a finished replay that left a recorded step unapplied."""
    done = {index for index, _ in result.outcomes}
    missed = [i for i, frame in enumerate(applied) if frame is not None and i not in done]
    if missed:
        raise RunSetupError(
            f"{trace}: the replay did not apply {len(missed)} recorded step(s) (the first: step {missed[0]} at "
            f"frame {applied[missed[0]]}): it is not the recorded story"
        )


def instructions_from_trace(path: Path) -> list[TimedInstruction]:
    """The instructions a recorded run applied, with their frames and sources, in order."""
    from orchestrator.llm.traces import read_trace

    out = []
    for r in read_trace(path).instructions():
        source = r.source if r.source in get_args(InstructionSource) else "replay"
        out.append(TimedInstruction.model_validate({"frame": r.sim_frame, "text": r.text, "source": source}))
    return out


def scheduled_instructions(
    args: RunArguments, fps: int, *, replay: Path | None, recorded: list[TimedInstruction]
) -> list[TimedInstruction]:
    """What the session schedules: a replay's recorded instructions; otherwise the script's
    lines at their frames, and on resume (``recorded``: the trace's instruction records so
    far) the recorded ones again, marked so they are not traced twice, in place of the
    script lines they applied."""
    if replay is not None:
        return instructions_from_trace(replay)
    applied_script = sum(1 for i in recorded if i.source == "script")
    script = [TimedInstruction(frame=round(line.time_s * fps), text=line.text, source="script")
              for line in args.instructions]
    return [*(i.model_copy(update={"recorded": True}) for i in recorded), *script[applied_script:]]


def story_json(result: SessionResult, scene_name: str, names: list[str], instruction: str, fps: int) -> dict[str, Any]:
    """``story.json``: every planning step with the frame it was applied at, and every event."""
    steps = []
    for (index, outcome), frame in zip(result.outcomes, result.applied_frames, strict=True):
        entry: dict[str, Any] = {"index": index, "applied_frame": frame}
        if outcome is None:
            entry.update(kind="wait", text=step_text(None))
        elif isinstance(outcome, PlanningFailure):
            entry.update(kind="failed", node=outcome.node, feedback=outcome.feedback, text=step_text(outcome))
        elif isinstance(outcome, ParsedEvent):
            entry.update(
                kind="event",
                characters=list(outcome.event.characters),
                activity=outcome.event.activity,
                plans=[
                    {
                        "character": p.character,
                        "action": p.action,
                        "area": p.area,
                        "position": [round(p.position[0], 3), round(p.position[1], 3)],
                        "facing": [round(p.facing[0], 3), round(p.facing[1], 3)],
                        "seat": p.seat,
                    }
                    for p in outcome.plans
                ],
            )
        steps.append(entry)
    events = [
        {
            "event_id": e.event_id,
            "index": e.index,
            "characters": list(e.characters),
            "activity": e.activity,
            "requested_frame": e.requested_frame,
            "applied_frame": e.applied_frame,
            "state": e.state,
            "finished_frame": e.finished_frame,
            "failure": e.failure,
            "part": e.part,
            "text": e.text,
            "narration": e.narration,
        }
        for e in result.events
    ]
    return {
        "scene": scene_name,
        "characters": names,
        "instruction": instruction,
        "instructions": [
            {"frame": i.frame, "time_s": round(i.frame / fps, 3), "source": i.source, "text": i.text}
            for i in result.instructions
        ],
        "fps": fps,
        "frames": result.frames,
        "steps": steps,
        "events": events,
    }


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
    every applied planning step and every :data:`CHECKPOINT_EVERY_S` simulated seconds).
    ``resume=True`` goes on from that checkpoint on the thread ``thread_id``: the world is
    restored from it, steps whose result the trace already shows applied are applied at their
    recorded frames again, and the planner answers finished steps from its story log.

    ``on_resume(frame, fps)`` tells the frame a resumed session goes on from (0: no checkpoint was
    kept). ``on_event(event, fps)`` is called whenever a story event starts, loops, completes or fails.
    ``on_instruction(instruction, fps)`` when a new instruction takes effect. ``interactive``: lines typed on stdin become the instruction while the story runs (not in a replay),
    read by ``stdin_reader(session)`` when given (e.g. ``orchestrator.session.terminal_prompt``
    under a live view), else by ``orchestrator.session.stdin_instructions``.
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
    LLM calls; ``orchestrator.session.run_status``), for a live view."""
    from orchestrator.sandbox_worker import WorkerRunner

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
    process) is started; the caller stops it."""
    from agents.event_parser import scene_action_labels
    from agents.llm_port import LLMError
    from agents.prompt_templates import PromptLibrary
    from orchestrator.llm.traces import TraceCorruptError, TraceWriter
    from orchestrator.llm.watched_port import WatchedPort
    from orchestrator.planning.ablation_graph import compile_graph
    from orchestrator.planning.checkpoints import StoryLog, open_checkpointer
    from orchestrator.planning.state import PlanningDeps
    from orchestrator.session.checkpoint_writer import CheckpointWriter
    from orchestrator.session.live_state import LivePublisher, ReplyTap
    from orchestrator.session.port_setup import describer_mode_for, open_port
    from orchestrator.session.roster import RosterWorld, StartPositionError, start_positions
    from orchestrator.session.run_manifest import (
        MANIFEST_FILE,
        ManifestError,
        manifest_bytes,
        write_manifest,
    )
    from orchestrator.session.session_types import SessionCheckpoint, SessionError, SessionSettings
    from orchestrator.session.snapshot_file import (
        SNAPSHOT_FILE,
        SnapshotError,
        load_checkpoint,
        write_checkpoint,
    )
    from orchestrator.session.step_planner import GraphStepPlanner
    from orchestrator.session.story_stream import StoryStream, StreamStart
    from orchestrator.session.viewer_controls import (
        CONTROLS_FILE,
        DirectorControls,
        controls_refusal,
        start_control_reader,
    )
    from orchestrator.session.viewer_instructions import INBOX_FILE, start_inbox_reader
    from sim.world.step import World, WorldConfig

    names = list(args.names)
    try:
        refuse_planted_links(out, names)  # before anything is read from the folder or written to it
    except PlantedLinkError as exc:
        raise RunSetupError(str(exc)) from None
    config = Path(args.config) if args.config is not None else None
    motion_config = Path(args.motion_config) if args.motion_config is not None else None
    try:
        applied = replayable_frames(replay) if replay is not None else None
        schedule = schedule_from_trace(replay) if replay is not None and args.planners > 1 else None
        # a trace that is there but not a regular file (a link to a device) is read, and refused
        resumed_trace = resume and trace_path is not None and (trace_path.exists() or trace_path.is_symlink())
        recorded = recorded_frames(trace_path) if resumed_trace and trace_path is not None else {}
        said = instructions_from_trace(trace_path) if resumed_trace and trace_path is not None else []
    except (TraceCorruptError, OSError) as exc:
        raise RunSetupError(str(exc)) from None
    world_config = WorldConfig(seed=args.seed, foot_ik=args.foot_ik)
    fps = world_config.fps
    try:
        scheduled = scheduled_instructions(args, fps, replay=replay, recorded=said)
        if replay is not None and applied is not None:
            check_replayable(replay, applied, scheduled, round(args.duration * fps))
    except (TraceCorruptError, OSError, RunSetupError) as exc:
        raise RunSetupError(str(exc)) from None
    try:
        positions = start_positions(scene, len(names), args.seed)
    except StartPositionError as exc:
        raise RunSetupError(str(exc)) from None
    motion = _motion_layer(motion_config)
    world = World(scene, {n: (p, 0.0) for n, p in zip(names, positions, strict=True)}, motion, config=world_config)
    ablation = Ablation(planner=args.planner, description=args.description)
    thread = thread_id if resume and thread_id is not None else ablation.thread_id(thread_id or f"run-{uuid.uuid4().hex[:12]}")
    snapshot_path = out / SNAPSHOT_FILE
    checkpoint: SessionCheckpoint | None = None
    if resume and (snapshot_path.exists() or snapshot_path.is_symlink()):  # a folder or a device there is refused
        try:
            checkpoint = load_checkpoint(snapshot_path, world)
        except SnapshotError as exc:
            raise RunSetupError(str(exc)) from None
    # the trace is opened (a resumed run appends to it) once what the folder holds has been read and checked,
    # and the temporary files of a run killed mid-write (kill -9) are gone
    for folder in (out, out / MOTION_FOLDER):
        remove_stale_temporaries(folder)
    try:
        # a call the recorded story's end cut short waits again, to the end: that step stays in flight
        port, describer_model = open_port(config, trace_path, replay, unanswered="wait")
    except (LLMError, ValueError, OSError, TraceCorruptError) as exc:  # a replayed trace that does not check
        raise RunSetupError(str(exc)) from None
    if status is None:  # the run's state for a viewer (live.json) is read from it too
        status = RunStatus()
    replies = ReplyTap(WatchedPort(port, status))
    port = replies
    try:
        world = _stream_motion(world, out, names, checkpoint)
    except ValueError as exc:  # ChunkError, WorldError: chunk files that do not fit the checkpoint
        port.close()
        raise RunSetupError(str(exc)) from None
    if not resume:
        manifest = RunManifest(thread_id=thread, scene_name=scene.name, seed=args.seed, config=args.config, arguments=args)
        try:  # what resume and replay would refuse is refused now, before run.json is written
            manifest_bytes(manifest, out / MANIFEST_FILE)
        except ManifestError as exc:
            port.close()
            raise RunSetupError(str(exc)) from None
        write_manifest(out, manifest)
        if on_start is not None:
            on_start(manifest)
    # for a live viewer: the scene before the first frame, and no story.json (it marks a finished run)
    _write_scene_json(scene, out)
    (out / STORY_JSON).unlink(missing_ok=True)
    runs_db = out / RUNS_DB
    try:
        check_runs_db(runs_db)
        story = StoryLog(runs_db, thread)
    except (RunSetupError, sqlite3.DatabaseError) as exc:
        port.close()
        raise RunSetupError(str(exc) if isinstance(exc, RunSetupError) else f"{runs_db}: {exc}") from None
    deps = PlanningDeps(
        port=port,
        scene=scene,
        world=RosterWorld(),
        story=story,
        action_labels=scene_action_labels(scene),
        prompts=PromptLibrary(),
        seed=args.seed,
        max_retries=args.max_retries,
        describer_model=describer_model,
        describer_mode=describer_mode_for(describer_model),
        description_cache=None,
        program_grammar=args.program_grammar,
        runner=programs,
    )
    settings = SessionSettings(
        frames=round(args.duration * fps),
        pace=args.pace,
        speed=args.speed,
        max_steps=args.max_events,
        applied_frames=applied,
        recorded_frames=recorded,
        checkpoint_every_s=CHECKPOINT_EVERY_S,
        instruction=args.instruction,
        instructions=scheduled,
        live_instructions=replay is None,
        planners=args.planners,
        offline_latency_s=args.offline_latency,
        schedule=schedule,
    )
    refusal = controls_refusal(args.pace)  # a director's pause and speed: realtime only
    controls = DirectorControls(args.speed)
    live = LivePublisher(out, thread, status, replies, controls, speed=args.speed, refusal=refusal)
    session: Session | None = None
    writer = port.trace if isinstance(port.trace, TraceWriter) else None

    def said_now(timed: TimedInstruction) -> None:
        if writer is not None:
            writer.record_instruction(timed.text, timed.frame, source=timed.source)
        if status is not None:
            status.instruction(timed)
        if on_instruction is not None:
            on_instruction(timed, fps)

    def requested(r: RecordedRequest) -> None:
        if writer is not None:
            writer.record_requested(r.step, r.frame, phase=r.phase, after_steps=r.after)

    def keep(cp: SessionCheckpoint) -> None:  # written in the writer's thread: the frames go on
        assert session is not None
        checkpoints.submit(session.world, cp)

    def streamed(event: StoryEvent) -> None:
        stream.event(event)
        if status is not None:
            status.event(event)
        if on_event is not None:
            on_event(event, fps)

    def write_after_trace(path: Path, cp: SessionCheckpoint, shared: dict[int, str], store: Any) -> None:
        if writer is not None:  # the checkpoint counts on the trace's applied records: on disk first
            writer.sync()
        write_checkpoint(path, cp, shared, store)

    stream = StoryStream(out)
    checkpoints = CheckpointWriter(snapshot_path, write=write_after_trace)
    inbox_closed = threading.Event()
    finished = False
    try:
        async with open_checkpointer(runs_db) as saver:
            graph = compile_graph(ablation, saver)
            planner = GraphStepPlanner(graph, deps, thread, lanes=args.planners)
            session = Session(world, planner, settings, trace=port.trace, on_event=streamed, on_checkpoint=keep,
                              on_instruction=said_now, on_request=requested,
                              on_outcome=status.outcome, on_frame=status.frame,
                              pacer=controls if refusal is None else None)
            if checkpoint is not None:
                session.resume(checkpoint)
            if status is not None:
                status.started(session.world, frames=settings.frames, pace=settings.pace,
                               instruction=session.instruction, events=session.events.values(),
                               outcomes=session.outcomes)
            stream.start(
                StreamStart(scene=scene.name, characters=tuple(names), instruction=args.instruction, fps=fps,
                            frame=session.world.frame),
                checkpoint.events.values() if checkpoint is not None else (),
            )
            if resume and on_resume is not None:
                on_resume(session.world.frame, fps)
            if interactive and replay is None:
                from orchestrator.session.stdin_instructions import start_stdin_reader

                (stdin_reader or start_stdin_reader)(session)
            if replay is None:  # a viewer's instruction box, in this process or another
                start_inbox_reader(session, out / INBOX_FILE, thread, [i.text for i in said if i.source == "viewer"],
                                   stop=inbox_closed, after_frame=max((i.frame for i in said), default=-1))
            if refusal is None:
                start_control_reader(controls, out / CONTROLS_FILE, thread, stop=inbox_closed)
            publishing = asyncio.ensure_future(live.run())
            try:
                result, stopped = await _run_until_stopped(session, stop)
            finally:
                publishing.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await publishing
            with contextlib.suppress(OSError):
                live.write(live.state(running=False))
            if stopped:
                keep(session.checkpoint())
            checkpoints.flush()  # the last checkpoint on disk before the run returns
            finished = True
    except (LLMError, SessionError) as exc:
        raise RunSetupError(f"{type(exc).__name__}: {exc}") from None
    finally:
        inbox_closed.set()
        try:
            checkpoints.close(raise_errors=finished)  # after an error: the newest checkpoint still lands
        finally:
            stream.close()
            story.close()
            port.close()
            if programs is not None:
                programs.close()  # before the chunk files are closed and the outputs written
    end = session.world.buffers
    if end.store is not None:  # the whole story in the chunk files (the viewer reads them)
        end.spill()
        end.store.sync()
        end.store.close()  # read back by path from here on
    if replay is not None and applied is not None and not stopped and result.planner_error is None:
        check_replayed(replay, applied, result)
    return StoryRun(result, names, fps, session.world, stopped)


async def _run_until_stopped(session: Any, stop: asyncio.Event | None) -> tuple[SessionResult, bool]:
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


def check_runs_db(path: Path) -> None:
    """Raise :class:`RunSetupError` naming ``path`` when it exists but is not a sound SQLite
    database (garbage, truncated, damaged pages), before any checkpoint is read from it."""
    if not path.is_file():
        return
    try:
        with contextlib.closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True)) as conn:
            verdict = conn.execute("PRAGMA quick_check").fetchone()[0]
    except sqlite3.DatabaseError as exc:
        raise RunSetupError(f"{path}: not a readable checkpoint database ({exc})") from None
    if verdict != "ok":
        raise RunSetupError(f"{path}: the checkpoint database is damaged ({verdict})")


def _stream_motion(world: Any, out: Path, names: list[str], checkpoint: Any) -> Any:
    """``world`` streaming its motion to ``out/motion/<name>.chunks``: new files for a new run;
    on resume the files of the killed process, cut back to the frames the checkpoint says are
    there (a torn last record and frames after the checkpoint are dropped), with the world
    restored from the checkpoint."""
    from sim.world.track_chunks import MOTION_FOLDER, ChunkStore

    folder = out / MOTION_FOLDER
    if checkpoint is None:
        store = ChunkStore.open(folder, names)
        world.stream_tracks(store)
        return world
    store = ChunkStore.open(folder, names, frames=checkpoint.world.buffers.base)
    return world.restore(checkpoint.world, store=store)


def recorded_frames(trace_path: Path) -> dict[int, int]:
    """Step -> frame of every ``applied`` record with a step index in a trace."""
    from orchestrator.llm.traces import AppliedRecord, read_trace

    return {r.step: r.sim_frame for r in read_trace(trace_path).records if isinstance(r, AppliedRecord) and r.step is not None}


def _motion_layer(motion_config: Path | None) -> Any:
    from orchestrator.cache_paths import motion_cache_dir
    from sim.motion.database import load_databases
    from sim.motion.matching import MotionMatcher

    if motion_config is None:
        return MotionMatcher(load_databases(cache_dir=motion_cache_dir()))
    from sim.motion.config import build_databases_from_config, load_motion_config

    try:
        cfg = load_motion_config(motion_config)
        return MotionMatcher(build_databases_from_config(cfg, cache_dir=motion_cache_dir()))
    except (ValueError, OSError) as exc:
        raise RunSetupError(str(exc)) from None


def write_outputs(
    out: Path, scene: Scene, world: Any, result: SessionResult, names: list[str], instruction: str, fps: int, gif: bool,
    video: bool = False,
    trace_path: Path | None = None,
    smplx_model: Path | None = None,
) -> None:
    """``story.json``, ``story.md``, ``metrics.json`` (LLM use from ``trace_path``, when the run
    wrote a trace), ``scene.json`` (the scene as run, for ``storyteller view``), the motion
    exports (npz, BVH, GLB; with ``smplx_model`` the GLB carries SMPL-X body meshes) and the
    top-down pictures in ``out``."""
    from orchestrator.session.run_report import run_metrics, story_markdown
    from sim.export.bundle import export_run
    from sim.export.video import (
        RunRecording,
        animation_suffix,
        save_run_animation,
        save_run_png,
    )

    _write_scene_json(scene, out)
    payload = story_json(result, scene.name, names, instruction, fps)
    write_file(out / STORY_JSON, (json.dumps(payload, indent=2) + "\n").encode("utf-8"))
    write_file(out / STORY_MD, story_markdown(payload).encode("utf-8"))
    metrics = run_metrics(payload, trace_path, wall_s=result.wall_s, frame_intervals_s=list(result.frame_intervals_s))
    write_file(out / METRICS_JSON, (json.dumps(metrics, indent=2) + "\n").encode("utf-8"))
    tracks = world.tracks()
    bodies = None
    if smplx_model is not None:
        from orchestrator.bodies.smplx_meshes import smplx_bodies
        from sim.export.smplx_npz import smplx_parameters

        params = {t.name: smplx_parameters(t) for t in tracks.values()}
        bodies = {name: body.skin for name, body in smplx_bodies(smplx_model, params).items()}
    export_run(out, scene, list(tracks.values()), bodies=bodies)
    recording = RunRecording(scene, tracks, world.event_ids(), world.grid)  # the tracks read above, not again
    save_run_png(out / TOPDOWN_PNG, recording)
    # --video: story.mp4 (story.gif without imageio-ffmpeg); --gif: story.gif
    animations = {name for name, wanted in ((f"{ANIMATION_STEM}.gif", gif), (f"{ANIMATION_STEM}{animation_suffix()}", video))
                  if wanted}
    for name in sorted(animations):
        save_run_animation(out / name, recording, stride=10, speed=4.0)


def _write_scene_json(scene: Scene, out: Path) -> None:
    """``scene.json`` (the scene as run, for ``storyteller view``), replaced through a fresh name."""
    from sim.scene.files import save_scene_json

    with replacing(out / SCENE_JSON) as fresh:
        save_scene_json(scene, fresh)

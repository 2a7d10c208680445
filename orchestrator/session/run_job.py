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
    SessionCheckpoint,
    SessionError,
    SessionResult,
    SessionSettings,
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
    from orchestrator.planning.checkpoints import StoryLog
    from orchestrator.planning.state import PlanningDeps
    from orchestrator.sandbox_worker import WorkerRunner
    from orchestrator.session.live_state import ReplyTap
    from sim.world.step import World, WorldConfig

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


@dataclass(frozen=True)
class _Recorded:
    """What a run reads from the traces before it starts (see :func:`_read_recorded`)."""

    applied: list[int | None] | None
    """Replay: the frame each recorded step was applied at."""
    schedule: list[RecordedRequest] | None
    """Replay with overlapping steps: when each step was requested."""
    recorded: dict[int, int]
    """Resume: step -> frame of the steps the trace shows applied."""
    said: list[TimedInstruction]
    """Resume: the instructions the trace shows applied."""
    scheduled: list[TimedInstruction]
    """What the session schedules (:func:`scheduled_instructions`)."""


@dataclass(frozen=True)
class _Run:
    """The arguments of one :func:`_run_story` that its parts share."""

    scene: Scene
    args: RunArguments
    names: list[str]
    fps: int
    out: Path
    thread: str
    replay: Path | None
    resume: bool
    interactive: bool
    stop: asyncio.Event | None
    stdin_reader: Callable[[Session], object] | None
    on_resume: Callable[[int, int], None] | None


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
    from agents.llm_port import LLMError
    from orchestrator.session.snapshot_file import SNAPSHOT_FILE
    from sim.world.step import WorldConfig

    names = list(args.names)
    try:
        refuse_planted_links(out, names)  # before anything is read from the folder or written to it
    except PlantedLinkError as exc:
        raise RunSetupError(str(exc)) from None
    world_config = WorldConfig(seed=args.seed, foot_ik=args.foot_ik)
    fps = world_config.fps
    recorded = _read_recorded(args, fps, trace_path=trace_path, replay=replay, resume=resume)
    world = _start_world(scene, args, names, world_config)
    ablation = Ablation(planner=args.planner, description=args.description)
    thread = thread_id if resume and thread_id is not None else ablation.thread_id(thread_id or f"run-{uuid.uuid4().hex[:12]}")
    snapshot_path = out / SNAPSHOT_FILE
    checkpoint = _saved_checkpoint(snapshot_path, world) if resume else None
    # the trace is opened (a resumed run appends to it) once what the folder holds has been read and checked,
    # and the temporary files of a run killed mid-write (kill -9) are gone
    for folder in (out, out / MOTION_FOLDER):
        remove_stale_temporaries(folder)
    if status is None:  # the run's state for a viewer (live.json) is read from it too
        status = RunStatus()
    run = _Run(scene, args, names, fps, out, thread, replay, resume, interactive, stop, stdin_reader, on_resume)
    with contextlib.ExitStack() as stack:  # closes, in this order: readers, checkpoints, stream, story, port, programs
        if programs is not None:  # stopped before the chunk files are closed and the outputs written
            stack.callback(programs.close)
        replies, describer_model = _open_run_port(args, trace_path, replay, status, stack)
        world = _streaming_world(world, out, names, checkpoint)
        if not resume:
            _start_manifest(run, on_start)
        # for a live viewer: the scene before the first frame, and no story.json (it marks a finished run)
        _write_scene_json(scene, out)
        (out / STORY_JSON).unlink(missing_ok=True)
        story = _open_story_log(out / RUNS_DB, thread, stack)
        deps = _planning_deps(run, replies, story, describer_model, programs)
        settings = _session_settings(args, fps, recorded, live=replay is None)
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


def _read_recorded(args: RunArguments, fps: int, *, trace_path: Path | None, replay: Path | None,
                   resume: bool) -> _Recorded:
    """The recorded frames, requests and instructions of the trace to replay, or of the run's
    own trace on resume; an unreadable or unreplayable trace is a :class:`RunSetupError`."""
    from orchestrator.llm.traces import TraceCorruptError

    try:
        applied = replayable_frames(replay) if replay is not None else None
        schedule = schedule_from_trace(replay) if replay is not None and args.planners > 1 else None
        # a trace that is there but not a regular file (a link to a device) is read, and refused
        resumed_trace = resume and trace_path is not None and (trace_path.exists() or trace_path.is_symlink())
        recorded = recorded_frames(trace_path) if resumed_trace and trace_path is not None else {}
        said = instructions_from_trace(trace_path) if resumed_trace and trace_path is not None else []
    except (TraceCorruptError, OSError) as exc:
        raise RunSetupError(str(exc)) from None
    try:
        scheduled = scheduled_instructions(args, fps, replay=replay, recorded=said)
        if replay is not None and applied is not None:
            check_replayable(replay, applied, scheduled, round(args.duration * fps))
    except (TraceCorruptError, OSError, RunSetupError) as exc:
        raise RunSetupError(str(exc)) from None
    return _Recorded(applied, schedule, recorded, said, scheduled)


def _start_world(scene: Scene, args: RunArguments, names: list[str], world_config: WorldConfig) -> World:
    """The world at frame 0: the characters at the start positions of the seed."""
    from orchestrator.session.roster import StartPositionError, start_positions
    from sim.world.step import World

    try:
        positions = start_positions(scene, len(names), args.seed)
    except StartPositionError as exc:
        raise RunSetupError(str(exc)) from None
    motion = _motion_layer(Path(args.motion_config) if args.motion_config is not None else None)
    return World(scene, {n: (p, 0.0) for n, p in zip(names, positions, strict=True)}, motion, config=world_config)


def _saved_checkpoint(path: Path, world: World) -> SessionCheckpoint | None:
    """The checkpoint a resumed run goes on from (None: none was kept)."""
    from orchestrator.session.snapshot_file import SnapshotError, load_checkpoint

    if not (path.exists() or path.is_symlink()):  # a folder or a device there is refused
        return None
    try:
        return load_checkpoint(path, world)
    except SnapshotError as exc:
        raise RunSetupError(str(exc)) from None


def _open_run_port(args: RunArguments, trace_path: Path | None, replay: Path | None, status: RunStatus,
                   stack: contextlib.ExitStack) -> tuple[ReplyTap, str]:
    """The run's LLM port (recording to ``trace_path`` or replaying ``replay``), watched by
    ``status`` and tapped for the live view's replies, closed by ``stack``; and the describer's model."""
    from agents.llm_port import LLMError
    from orchestrator.llm.traces import TraceCorruptError
    from orchestrator.llm.watched_port import WatchedPort
    from orchestrator.session.live_state import ReplyTap
    from orchestrator.session.port_setup import open_port

    config = Path(args.config) if args.config is not None else None
    try:
        # a call the recorded story's end cut short waits again, to the end: that step stays in flight
        port, describer_model = open_port(config, trace_path, replay, unanswered="wait")
    except (LLMError, ValueError, OSError, TraceCorruptError) as exc:  # a replayed trace that does not check
        raise RunSetupError(str(exc)) from None
    stack.callback(port.close)
    return ReplyTap(WatchedPort(port, status)), describer_model


def _streaming_world(world: World, out: Path, names: list[str], checkpoint: SessionCheckpoint | None) -> World:
    """:func:`_stream_motion`, its chunk files that do not fit the checkpoint a :class:`RunSetupError`."""
    try:
        streaming: World = _stream_motion(world, out, names, checkpoint)
    except ValueError as exc:  # ChunkError, WorldError: chunk files that do not fit the checkpoint
        raise RunSetupError(str(exc)) from None
    return streaming


def _start_manifest(run: _Run, on_start: Callable[[RunManifest], None] | None) -> None:
    """Write a new run's ``run.json`` (refused first if resume or replay would refuse it)."""
    from orchestrator.session.run_manifest import (
        MANIFEST_FILE,
        ManifestError,
        manifest_bytes,
        write_manifest,
    )

    args = run.args
    manifest = RunManifest(thread_id=run.thread, scene_name=run.scene.name, seed=args.seed, config=args.config,
                           arguments=args)
    try:  # what resume and replay would refuse is refused now, before run.json is written
        manifest_bytes(manifest, run.out / MANIFEST_FILE)
    except ManifestError as exc:
        raise RunSetupError(str(exc)) from None
    write_manifest(run.out, manifest)
    if on_start is not None:
        on_start(manifest)


def _open_story_log(runs_db: Path, thread: str, stack: contextlib.ExitStack) -> StoryLog:
    """The story log of ``thread`` in ``runs_db`` (checked first), closed by ``stack``."""
    from orchestrator.planning.checkpoints import StoryLog

    try:
        check_runs_db(runs_db)
        story = StoryLog(runs_db, thread)
    except (RunSetupError, sqlite3.DatabaseError) as exc:
        raise RunSetupError(str(exc) if isinstance(exc, RunSetupError) else f"{runs_db}: {exc}") from None
    stack.callback(story.close)
    return story


def _planning_deps(run: _Run, port: ReplyTap, story: StoryLog, describer_model: str,
                   programs: WorkerRunner | None) -> PlanningDeps:
    from agents.event_parser import scene_action_labels
    from agents.prompt_templates import PromptLibrary
    from orchestrator.planning.state import PlanningDeps
    from orchestrator.session.port_setup import describer_mode_for
    from orchestrator.session.roster import RosterWorld

    return PlanningDeps(
        port=port,
        scene=run.scene,
        world=RosterWorld(),
        story=story,
        action_labels=scene_action_labels(run.scene),
        prompts=PromptLibrary(),
        seed=run.args.seed,
        max_retries=run.args.max_retries,
        describer_model=describer_model,
        describer_mode=describer_mode_for(describer_model),
        description_cache=None,
        program_grammar=run.args.program_grammar,
        runner=programs,
    )


def _session_settings(args: RunArguments, fps: int, recorded: _Recorded, *, live: bool) -> SessionSettings:
    return SessionSettings(
        frames=round(args.duration * fps),
        pace=args.pace,
        speed=args.speed,
        max_steps=args.max_events,
        applied_frames=recorded.applied,
        recorded_frames=recorded.recorded,
        checkpoint_every_s=CHECKPOINT_EVERY_S,
        instruction=args.instruction,
        instructions=recorded.scheduled,
        live_instructions=live,
        planners=args.planners,
        offline_latency_s=args.offline_latency,
        schedule=recorded.schedule,
    )


class _RunHooks:
    """The session's callbacks in a run and what they write to: the trace's instruction and
    request records, the run's status, ``story.jsonl``, ``session.snapshot`` (by a
    :class:`CheckpointWriter`), ``live.json`` and a director's controls, and the caller's own."""

    def __init__(self, run: _Run, snapshot_path: Path, replies: ReplyTap, status: RunStatus, *,
                 on_event: Callable[[StoryEvent, int], None] | None,
                 on_instruction: Callable[[TimedInstruction, int], None] | None) -> None:
        from orchestrator.llm.traces import TraceWriter
        from orchestrator.session.checkpoint_writer import CheckpointWriter
        from orchestrator.session.live_state import LivePublisher
        from orchestrator.session.story_stream import StoryStream
        from orchestrator.session.viewer_controls import DirectorControls, controls_refusal

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

    def _write_after_trace(self, path: Path, cp: SessionCheckpoint, shared: dict[int, str], store: Any) -> None:
        from orchestrator.session.snapshot_file import write_checkpoint

        if self.writer is not None:  # the checkpoint counts on the trace's applied records: on disk first
            self.writer.sync()
        write_checkpoint(path, cp, shared, store)

    def close_checkpoints(self) -> None:
        self.checkpoints.close(raise_errors=self.finished)


async def _play(run: _Run, ablation: Ablation, deps: PlanningDeps, settings: SessionSettings, world: World,
                hooks: _RunHooks, checkpoint: SessionCheckpoint | None,
                recorded: _Recorded) -> tuple[Session, SessionResult, bool]:
    """Build the session on the planning graph and run it (until ``run.stop``, if set first),
    publishing ``live.json`` meanwhile; its last checkpoint is on disk when this returns."""
    from orchestrator.planning.ablation_graph import compile_graph
    from orchestrator.planning.checkpoints import open_checkpointer
    from orchestrator.session.step_planner import GraphStepPlanner

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


def _start_session(run: _Run, session: Session, hooks: _RunHooks, checkpoint: SessionCheckpoint | None,
                   said: list[TimedInstruction]) -> None:
    """Resume ``session`` from ``checkpoint``, tell the status and ``story.jsonl`` where the
    story starts, and start the readers of stdin, a viewer's instructions and its controls."""
    from orchestrator.session.story_stream import StreamStart
    from orchestrator.session.viewer_controls import CONTROLS_FILE, start_control_reader
    from orchestrator.session.viewer_instructions import INBOX_FILE, start_inbox_reader

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
        from orchestrator.session.stdin_instructions import start_stdin_reader

        (run.stdin_reader or start_stdin_reader)(session)
    if run.replay is None:  # a viewer's instruction box, in this process or another
        start_inbox_reader(session, run.out / INBOX_FILE, run.thread, [i.text for i in said if i.source == "viewer"],
                           stop=hooks.inbox_closed, after_frame=max((i.frame for i in said), default=-1))
    if hooks.refusal is None:
        start_control_reader(hooks.controls, run.out / CONTROLS_FILE, run.thread, stop=hooks.inbox_closed)


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

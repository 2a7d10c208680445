"""What a ``run`` reads and opens before its first frame (``storyteller.orchestrator.session.run_job``).

From the traces: the frames a recorded run applied its steps at, its requests and instructions
(a replay makes them again; a resume makes the requests and applies the steps already traced
again at their frames, not traced twice),
and the checks that a replay can apply them all (:func:`read_recorded`). From the run folder:
the session checkpoint to resume from, the chunk files to stream the motion to, the story log
(``runs.sqlite``, checked first). And the world at frame 0, the LLM port, ``run.json`` and the
planning graph's dependencies. Every problem with the user's inputs is a
:class:`RunSetupError`, one sentence naming the file; a resource opened here is registered
with the caller's exit stack, which closes it.
"""

from __future__ import annotations

import asyncio
import contextlib
import sqlite3
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, get_args

from storyteller.orchestrator.session.run_manifest import RunArguments, RunManifest
from storyteller.orchestrator.session.run_status import RunStatus
from storyteller.orchestrator.session.runtime import Session
from storyteller.orchestrator.session.session_types import (
    InstructionSource,
    RecordedRequest,
    SessionCheckpoint,
    SessionResult,
    SessionSettings,
    TimedInstruction,
)
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.step import World, WorldConfig

if TYPE_CHECKING:
    from storyteller.orchestrator.planning.checkpoints import StoryLog
    from storyteller.orchestrator.planning.state import PlanningDeps
    from storyteller.orchestrator.sandbox_worker import WorkerRunner
    from storyteller.orchestrator.session.live_state import ReplyTap
    from storyteller.sim.motion.matching import MotionMatcher

CHECKPOINT_EVERY_S = 10.0
"""Simulated seconds between two session checkpoints at most (also one after every applied step)."""


class RunSetupError(Exception):
    """A run that cannot start or go on because of its inputs (the message says which)."""


def applied_frames_from_trace(path: Path) -> list[int | None]:
    """Frame at which a recorded run applied each planning step's result, by step (overlapping
    steps may be applied out of order; None: a step it never applied). Records without a step
    (older traces) count in the order written."""
    from storyteller.orchestrator.llm.traces import AppliedRecord, read_trace

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
    from storyteller.orchestrator.llm.traces import read_trace

    return [RecordedRequest(step=r.step, frame=r.sim_frame, phase=r.phase, after=r.after_steps)
            for r in read_trace(path).requests()]


def replayable_frames(path: Path) -> list[int | None]:
    """:func:`applied_frames_from_trace` of a trace to replay, which must end with a whole line:
    a cut last record (a run killed mid-write) is a :class:`RunSetupError`, not a shorter story."""
    from storyteller.orchestrator.llm.traces import read_trace

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
    from storyteller.orchestrator.llm.traces import read_trace

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


@dataclass(frozen=True)
class RecordedInputs:
    """What a run reads from the traces before it starts (see :func:`read_recorded`)."""

    applied: list[int | None] | None
    """Replay: the frame each recorded step was applied at."""
    schedule: list[RecordedRequest] | None
    """Replay with overlapping steps: when each step was requested."""
    recorded: dict[int, int]
    """Resume: step -> frame of the steps the trace shows applied."""
    requested: list[RecordedRequest]
    """Resume with overlapping steps: the requests the trace holds (made again, not traced twice)."""
    reached: int
    """Resume: the last frame the trace shows (-1: none); live instructions take effect after it."""
    said: list[TimedInstruction]
    """Resume: the instructions the trace shows applied."""
    scheduled: list[TimedInstruction]
    """What the session schedules (:func:`scheduled_instructions`)."""


@dataclass(frozen=True)
class RunContext:
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


def read_recorded(args: RunArguments, fps: int, *, trace_path: Path | None, replay: Path | None,
                   resume: bool) -> RecordedInputs:
    """The recorded frames, requests and instructions of the trace to replay, or of the run's
    own trace on resume; an unreadable or unreplayable trace is a :class:`RunSetupError`."""
    from storyteller.orchestrator.llm.traces import TraceCorruptError

    try:
        applied = replayable_frames(replay) if replay is not None else None
        schedule = schedule_from_trace(replay) if replay is not None and args.planners > 1 else None
        # a trace that is there but not a regular file (a link to a device) is read, and refused
        resumed_trace = resume and trace_path is not None and (trace_path.exists() or trace_path.is_symlink())
        recorded = recorded_frames(trace_path) if resumed_trace and trace_path is not None else {}
        requested = schedule_from_trace(trace_path) if resumed_trace and trace_path is not None else []
        reached = last_traced_frame(trace_path) if resumed_trace and trace_path is not None else -1
        said = instructions_from_trace(trace_path) if resumed_trace and trace_path is not None else []
    except (TraceCorruptError, OSError) as exc:
        raise RunSetupError(str(exc)) from None
    try:
        scheduled = scheduled_instructions(args, fps, replay=replay, recorded=said)
        if replay is not None and applied is not None:
            check_replayable(replay, applied, scheduled, round(args.duration * fps))
    except (TraceCorruptError, OSError, RunSetupError) as exc:
        raise RunSetupError(str(exc)) from None
    return RecordedInputs(applied, schedule, recorded, requested, reached, said, scheduled)


def start_world(scene: Scene, args: RunArguments, names: list[str], world_config: WorldConfig) -> World:
    """The world at frame 0: the characters at the start positions of the seed."""
    from storyteller.orchestrator.session.roster import StartPositionError, start_positions
    from storyteller.sim.world.step import World

    try:
        positions = start_positions(scene, len(names), args.seed)
    except StartPositionError as exc:
        raise RunSetupError(str(exc)) from None
    motion = _motion_layer(Path(args.motion_config) if args.motion_config is not None else None)
    return World(scene, {n: (p, 0.0) for n, p in zip(names, positions, strict=True)}, motion, config=world_config)


def saved_checkpoint(path: Path, world: World) -> SessionCheckpoint | None:
    """The checkpoint a resumed run goes on from (None: none was kept)."""
    from storyteller.orchestrator.session.snapshot_errors import SnapshotError
    from storyteller.orchestrator.session.snapshot_file import load_checkpoint

    if not (path.exists() or path.is_symlink()):  # a folder or a device there is refused
        return None
    try:
        return load_checkpoint(path, world)
    except SnapshotError as exc:
        raise RunSetupError(str(exc)) from None


def open_run_port(args: RunArguments, trace_path: Path | None, replay: Path | None, status: RunStatus,
                   stack: contextlib.ExitStack) -> tuple[ReplyTap, str]:
    """The run's LLM port (recording to ``trace_path`` or replaying ``replay``), watched by
    ``status`` and tapped for the live view's replies, closed by ``stack``; and the describer's model."""
    from storyteller.agents.llm_port import LLMError
    from storyteller.orchestrator.llm.traces import TraceCorruptError
    from storyteller.orchestrator.llm.watched_port import WatchedPort
    from storyteller.orchestrator.session.live_state import ReplyTap
    from storyteller.orchestrator.session.port_setup import open_port

    config = Path(args.config) if args.config is not None else None
    try:
        # a call the recorded story's end cut short waits again, to the end: that step stays in flight
        port, describer_model = open_port(config, trace_path, replay, unanswered="wait", planner=args.planner)
    except (LLMError, ValueError, OSError, TraceCorruptError) as exc:  # a replayed trace that does not check
        raise RunSetupError(str(exc)) from None
    stack.callback(port.close)
    return ReplyTap(WatchedPort(port, status)), describer_model


def check_motion(out: Path, names: list[str], checkpoint: SessionCheckpoint | None) -> None:
    """On resume, the chunk files :func:`streaming_world` will cut back to the checkpoint, checked
    without writing (a :class:`RunSetupError`): a refused resume leaves the folder as it was."""
    from storyteller.sim.world.track_chunks import MOTION_FOLDER, ChunkError, check_resumable

    if checkpoint is not None:
        try:
            check_resumable(out / MOTION_FOLDER, names, checkpoint.world.buffers.base)
        except ChunkError as exc:
            raise RunSetupError(str(exc)) from None


def streaming_world(world: World, out: Path, names: list[str], checkpoint: SessionCheckpoint | None) -> World:
    """:func:`_stream_motion`, its chunk files that do not fit the checkpoint a :class:`RunSetupError`."""
    try:
        return _stream_motion(world, out, names, checkpoint)
    except ValueError as exc:  # ChunkError, WorldError: chunk files that do not fit the checkpoint
        raise RunSetupError(str(exc)) from None


def start_manifest(run: RunContext, on_start: Callable[[RunManifest], None] | None) -> None:
    """Write a new run's ``run.json`` (refused first if resume or replay would refuse it)."""
    from storyteller.orchestrator.session.run_manifest import (
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


def open_story_log(runs_db: Path, thread: str, stack: contextlib.ExitStack) -> StoryLog:
    """The story log of ``thread`` in ``runs_db`` (checked first), closed by ``stack``."""
    from storyteller.orchestrator.planning.checkpoints import StoryLog

    try:
        check_runs_db(runs_db)
        story = StoryLog(runs_db, thread)
    except (RunSetupError, sqlite3.DatabaseError) as exc:
        raise RunSetupError(str(exc) if isinstance(exc, RunSetupError) else f"{runs_db}: {exc}") from None
    stack.callback(story.close)
    return story


def planning_deps(run: RunContext, port: ReplyTap, story: StoryLog, describer_model: str,
                   programs: WorkerRunner | None) -> PlanningDeps:
    from storyteller.agents.event_parser import scene_action_labels
    from storyteller.agents.prompt_templates import PromptLibrary
    from storyteller.orchestrator.planning.state import PlanningDeps
    from storyteller.orchestrator.session.port_setup import describer_mode_for
    from storyteller.orchestrator.session.roster import RosterWorld

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


def session_settings(args: RunArguments, fps: int, recorded: RecordedInputs, *, live: bool) -> SessionSettings:
    return SessionSettings(
        frames=round(args.duration * fps),
        pace=args.pace,
        speed=args.speed,
        max_steps=args.max_events,
        applied_frames=recorded.applied,
        recorded_frames=recorded.recorded,
        recorded_requests=recorded.requested,
        recorded_until=recorded.reached,
        checkpoint_every_s=CHECKPOINT_EVERY_S,
        instruction=args.instruction,
        instructions=recorded.scheduled,
        live_instructions=live,
        planners=args.planners,
        offline_latency_s=args.offline_latency,
        schedule=recorded.schedule,
    )


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


def _stream_motion(world: World, out: Path, names: list[str], checkpoint: SessionCheckpoint | None) -> World:
    """``world`` streaming its motion to ``out/motion/<name>.chunks``: new files for a new run;
    on resume the files of the killed process, cut back to the frames the checkpoint says are
    there (a torn last record and frames after the checkpoint are dropped), with the world
    restored from the checkpoint."""
    from storyteller.sim.world.track_chunks import MOTION_FOLDER, ChunkStore

    folder = out / MOTION_FOLDER
    if checkpoint is None:
        store = ChunkStore.open(folder, names)
        world.stream_tracks(store)
        return world
    store = ChunkStore.open(folder, names, frames=checkpoint.world.buffers.base)
    return world.restore(checkpoint.world, store=store)


def last_traced_frame(trace_path: Path) -> int:
    """The last frame a trace shows its run at: of a step's request or its LLM calls, an applied
    step, an instruction (-1: none)."""
    from storyteller.orchestrator.llm.traces import (
        AppliedRecord,
        AttemptRecord,
        InstructionRecord,
        RequestedRecord,
        read_trace,
    )

    frames = [-1]
    for r in read_trace(trace_path).records:
        if isinstance(r, AttemptRecord) and r.request.sim_frame is not None:
            frames.append(r.request.sim_frame)
        elif isinstance(r, AppliedRecord | RequestedRecord | InstructionRecord):
            frames.append(r.sim_frame)
    return max(frames)


def recorded_frames(trace_path: Path) -> dict[int, int]:
    """Step -> frame of every ``applied`` record with a step index in a trace."""
    from storyteller.orchestrator.llm.traces import AppliedRecord, read_trace

    return {r.step: r.sim_frame for r in read_trace(trace_path).records if isinstance(r, AppliedRecord) and r.step is not None}


def _motion_layer(motion_config: Path | None) -> MotionMatcher:
    from storyteller.orchestrator.cache_paths import motion_cache_dir
    from storyteller.sim.motion.database import load_databases
    from storyteller.sim.motion.matching import MotionMatcher

    if motion_config is None:
        return MotionMatcher(load_databases(cache_dir=motion_cache_dir()))
    from storyteller.sim.motion.config import build_databases_from_config, load_motion_config

    try:
        cfg = load_motion_config(motion_config)
        return MotionMatcher(build_databases_from_config(cfg, cache_dir=motion_cache_dir()))
    except (ValueError, OSError) as exc:
        raise RunSetupError(str(exc)) from None

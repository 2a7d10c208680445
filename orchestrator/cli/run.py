"""``storyteller run``: plan and animate a story in a scene (the main job).

The simulation and the planner run concurrently (``orchestrator.session.runtime``). Outputs,
all in ``--out``: ``story.json`` (events with their frames and per-character plans),
``trace.jsonl`` (every LLM call, replayable), ``runs.sqlite`` (planning checkpoints and story
log), per character ``<name>.smplx.npz`` / ``.bvh`` / ``.track.npz``, ``scene.glb`` (whole scene,
skinned and animated), ``topdown.png`` and, with ``--gif``, ``story.gif``.

``--replay T.jsonl`` serves every LLM call from a recorded trace and applies each planning
result at the frame recorded there: the same arguments reproduce the same events and the same
motion, with no model loaded.

``--planner unified|direct`` and ``--description object-list|scene-graph`` plan with the
paper's ablations (``orchestrator.planning.ablation_graph``), driven by the same step planner.
"""

from __future__ import annotations

import asyncio
import json
import math
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn

import typer

from orchestrator.session.runtime import Outcome, Pace, SessionResult, StoryEvent

if TYPE_CHECKING:
    from orchestrator.planning.ablation_graph import Ablation


def register(app: typer.Typer) -> None:
    app.command("run")(run_command)


def _fail(message: str, code: int = 2) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


def applied_frames_from_trace(path: Path) -> list[int]:
    """Frames at which a recorded run applied each planning step's result, in order."""
    from orchestrator.llm.traces import AppliedRecord, read_trace

    return [r.sim_frame for r in read_trace(path).records if isinstance(r, AppliedRecord)]


def story_json(result: SessionResult, scene_name: str, names: list[str], instruction: str, fps: int) -> dict[str, Any]:
    from agents.messages import ParsedEvent, PlanningFailure

    steps = []
    for (index, outcome), frame in zip(result.outcomes, result.applied_frames, strict=True):
        entry: dict[str, Any] = {"index": index, "applied_frame": frame}
        if outcome is None:
            entry["kind"] = "wait"
        elif isinstance(outcome, PlanningFailure):
            entry.update(kind="failed", node=outcome.node, feedback=outcome.feedback)
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
        }
        for e in result.events
    ]
    return {
        "scene": scene_name,
        "characters": names,
        "instruction": instruction,
        "fps": fps,
        "frames": result.frames,
        "steps": steps,
        "events": events,
    }


def _event_line(e: StoryEvent, fps: int) -> str:
    t = (e.finished_frame if e.finished_frame is not None else e.applied_frame) / fps
    what = {"ongoing": "starts", "looping": "loops", "completed": "done", "failed": "failed"}[e.state]
    return f"[{t:7.1f}s] {e.event_id} {what}: {', '.join(e.characters)}: {e.activity}"


def run_command(
    scene: Annotated[str, typer.Argument(help="Bundled scene name or path to a scene.")],
    characters: Annotated[int, typer.Option("--characters", "-n", min=1, max=24, help="Number of characters.")] = 2,
    instruction: Annotated[str, typer.Option("--instruction", "-i", help="What should happen.")] = "",
    duration: Annotated[float, typer.Option("--duration", "-d", min=1.0, help="Simulated seconds.")] = 60.0,
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")] = Path("out"),
    pace: Annotated[str, typer.Option("--pace", help="lockstep (sim waits for the planner), realtime, or fast.")] = "lockstep",
    speed: Annotated[float, typer.Option("--speed", help="Simulated seconds per wall second (realtime pace).")] = 1.0,
    max_events: Annotated[int | None, typer.Option("--max-events", min=1, help="Planning steps at most.")] = None,
    record: Annotated[Path | None, typer.Option("--record", help="Trace file (default: OUT/trace.jsonl).")] = None,
    replay: Annotated[Path | None, typer.Option("--replay", help="Serve LLM calls and frames from this trace.")] = None,
    config: Annotated[Path | None, typer.Option("--config", help="TOML run config.")] = None,
    motion_config: Annotated[Path | None, typer.Option("--motion-config", help="TOML mapping mocap clips to actions.")] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of start positions, sampling and paths.")] = 0,
    max_retries: Annotated[int, typer.Option("--max-retries", min=0, max=10, help="Retries per LLM role.")] = 3,
    program_grammar: Annotated[bool, typer.Option("--program-grammar/--free-programs", help="Local models write event programs under a grammar of the API's area functions and the scene's names (--free-programs: free Python, as the paper).")] = True,
    gif: Annotated[bool, typer.Option("--gif/--no-gif", help="Also write an animated top-down GIF.")] = False,
    foot_ik: Annotated[bool, typer.Option("--foot-ik/--raw-feet", help="Leg IK on the synthesized motion: feet pinned while planted and kept out of furniture (--raw-feet: the matched poses as they are).")] = True,
    thread_id: Annotated[str | None, typer.Option("--thread-id", help="Resume this planning thread.")] = None,
    planner: Annotated[
        str, typer.Option("--planner", help="event (narrator + event parser), unified (w/o Event) or direct (coordinates).")
    ] = "event",
    description: Annotated[
        str, typer.Option("--description", help="Scene description: describer, object-list or scene-graph.")
    ] = "describer",
) -> None:
    """Plan and animate a story; write motion, pictures, the story log and the trace."""
    from orchestrator.planning.ablation_graph import Ablation, AblationChoiceError
    from sim.scene.bundled import resolve_scene
    from sim.scene.files import SceneFileError

    try:
        ablation = Ablation.parse(planner, description)
    except AblationChoiceError as exc:
        _fail(str(exc))
    if pace not in ("lockstep", "realtime", "fast"):
        _fail(f"--pace must be lockstep, realtime or fast, got {pace!r}")
    if not (math.isfinite(speed) and speed > 0):
        _fail(f"--speed must be a positive number, got {speed}")
    try:
        scene_obj = resolve_scene(scene)
    except SceneFileError as exc:
        _fail(str(exc))
    if replay is not None and not replay.is_file():
        _fail(f"{replay}: trace file not found")
    out.mkdir(parents=True, exist_ok=True)
    trace_path = record if record is not None else (None if replay is not None else out / "trace.jsonl")
    if trace_path is not None and replay is not None and trace_path.resolve() == replay.resolve():
        _fail("--record must name a different file than --replay")
    try:
        result, names, fps, world = asyncio.run(
            _run(
                scene_obj,
                characters=characters,
                instruction=instruction,
                duration=duration,
                out=out,
                pace=pace,  # type: ignore[arg-type]
                speed=speed,
                max_events=max_events,
                trace_path=trace_path,
                replay=replay,
                config=config,
                motion_config=motion_config,
                seed=seed,
                max_retries=max_retries,
                thread_id=thread_id,
                ablation=ablation,
                program_grammar=program_grammar,
                foot_ik=foot_ik,
            )
        )
    except _UserError as exc:
        _fail(str(exc))
    _write_outputs(out, scene_obj, world, result, names, instruction, fps, gif)
    typer.echo(
        f"{result.frames} frames ({result.frames / fps:.1f} s), {result.steps} planning steps, "
        f"{sum(e.state == 'completed' for e in result.events)} events completed -> {out}"
    )
    if result.planner_error is not None:
        err = result.planner_error
        typer.echo(f"error: planning stopped: {type(err).__name__}: {err}", err=True)
        raise typer.Exit(1)


class _UserError(Exception):
    pass


async def _run(
    scene_obj: Any,
    *,
    characters: int,
    instruction: str,
    duration: float,
    out: Path,
    pace: Pace,
    speed: float,
    max_events: int | None,
    trace_path: Path | None,
    replay: Path | None,
    config: Path | None,
    motion_config: Path | None,
    seed: int,
    max_retries: int,
    thread_id: str | None,
    ablation: Ablation | None = None,
    program_grammar: bool = False,
    foot_ik: bool = True,
) -> tuple[SessionResult, list[str], int, Any]:
    from agents.event_parser import scene_action_labels
    from agents.llm_port import LLMError
    from agents.prompt_templates import PromptLibrary
    from orchestrator.cli.plan import (
        character_names,
        close_port,
        describer_mode_for,
        open_port,
        start_positions,
    )
    from orchestrator.llm.traces import TraceCorruptError
    from orchestrator.planning.ablation_graph import Ablation, compile_graph
    from orchestrator.planning.checkpoints import StoryLog, open_checkpointer
    from orchestrator.planning.state import PlanningDeps
    from orchestrator.session.runtime import Session, SessionError, SessionSettings
    from orchestrator.session.step_planner import GraphStepPlanner, SessionWorld
    from sim.world.step import World, WorldConfig

    names = character_names(characters)
    try:
        applied = applied_frames_from_trace(replay) if replay is not None else None
    except (TraceCorruptError, OSError) as exc:
        raise _UserError(str(exc)) from None
    try:
        port, describer_model = open_port(config, trace_path, replay)
    except (LLMError, ValueError, OSError) as exc:
        raise _UserError(str(exc)) from None
    world_config = WorldConfig(seed=seed, foot_ik=foot_ik)
    fps = world_config.fps
    positions = start_positions(scene_obj, characters, seed)
    motion = _motion_layer(motion_config)
    world = World(scene_obj, {n: (p, 0.0) for n, p in zip(names, positions, strict=True)}, motion, config=world_config)
    ablation = ablation or Ablation()
    thread = ablation.thread_id(thread_id or f"run-{uuid.uuid4().hex[:12]}")
    runs_db = out / "runs.sqlite"
    story = StoryLog(runs_db, thread)
    deps = PlanningDeps(
        port=port,
        scene=scene_obj,
        world=SessionWorld(),
        story=story,
        action_labels=scene_action_labels(scene_obj),
        prompts=PromptLibrary(),
        seed=seed,
        max_retries=max_retries,
        describer_model=describer_model,
        describer_mode=describer_mode_for(describer_model),  # type: ignore[arg-type]
        description_cache=None,
        program_grammar=program_grammar,
    )
    settings = SessionSettings(
        frames=round(duration * fps),
        pace=pace,
        speed=speed,
        max_steps=max_events,
        applied_frames=applied,
    )

    def show(e: StoryEvent) -> None:
        typer.echo(_event_line(e, fps))

    try:
        async with open_checkpointer(runs_db) as saver:
            graph = compile_graph(ablation, saver)
            planner = GraphStepPlanner(graph, deps, thread, instruction)
            session = Session(world, planner, settings, trace=getattr(port, "trace", None), on_event=show)
            result = await session.run()
    except (LLMError, SessionError) as exc:
        raise _UserError(f"{type(exc).__name__}: {exc}") from None
    finally:
        story.close()
        await close_port(port)
    return result, names, fps, session.world


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
        raise _UserError(str(exc)) from None


def _write_outputs(
    out: Path, scene: Any, world: Any, result: SessionResult, names: list[str], instruction: str, fps: int, gif: bool
) -> None:
    from sim.export.bundle import export_run
    from sim.export.video import recording_from_world, save_run_animation, save_run_png

    payload = story_json(result, scene.name, names, instruction, fps)
    (out / "story.json").write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")
    tracks = world.tracks()
    export_run(out, scene, list(tracks.values()))
    recording = recording_from_world(world)
    save_run_png(out / "topdown.png", recording)
    if gif:
        save_run_animation(out / "story.gif", recording, stride=10, speed=4.0)


__all__ = ["Outcome", "register", "run_command"]

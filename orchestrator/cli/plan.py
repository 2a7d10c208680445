"""``storyteller plan``: plan K events in a scene with the planning graph, without a simulation.

Without a simulation nothing "finishes" by itself, so ``plan`` advances the story by steps:
each planned event moves its characters to their sampled positions and keeps them busy for
``--busy-events`` further steps (default 0: the event counts as completed as soon as it is
planned, and its characters are free again). Characters start idle at free floor positions
sampled with ``--seed``. A step whose narrator waits, or whose retries run out, still counts
as one of the K steps (printed as ``wait`` / ``failed``).

``--record T.jsonl`` writes every LLM call to a trace; ``--replay T.jsonl`` serves the calls
from that trace (no model is loaded) and reproduces the printed events byte for byte; a
request that differs from the recorded one (e.g. after a prompt file changed) fails with a
diff naming the node. The describer's on-disk cache is used only for live runs without
``--record``, so a recorded trace always holds the describer call.

Runs are checkpointed in SQLite (``--runs-db``); ``--thread-id ID`` of an interrupted run
resumes it without repeating its finished LLM calls.

``--planner unified|direct`` and ``--description object-list|scene-graph`` run the paper's
ablations (``orchestrator.planning.ablation_graph``) through the same LLM port, trace, replay and
output; the defaults (``event`` + ``describer``) run the planning graph itself. A thread is
resumed with the options it was started with (other options start their own thread).
"""

from __future__ import annotations

import asyncio
import json
import sys
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any, NoReturn

import numpy as np
import typer

from agents.event_parser import scene_action_labels
from agents.llm_port import LLMError, LLMPort
from agents.messages import CharacterStatus, ParsedEvent, PlanningFailure
from agents.prompt_templates import BENCHMARK_TAGS, PromptLibrary, PromptTemplateError
from agents.retry_feedback import RetriesExhaustedError
from orchestrator.planning.ablation_graph import Ablation, AblationChoiceError, compile_graph
from orchestrator.planning.checkpoints import StoryLog, default_runs_db, open_checkpointer
from orchestrator.planning.graph import recursion_limit
from orchestrator.planning.state import PlanningDeps, PlanningState
from sim.scene.model import Scene
from tools.character_states import CharacterState, WorldView
from tools.position_sampling import FloorMap

NAMES = ("Ava", "Ben", "Cleo", "Dan", "Eve", "Finn", "Gia", "Hugo", "Iris", "Jon", "Kai", "Lena")
START_SEPARATION = 1.0


class RosterWorld:
    """World view built from the planner's roster (used when no simulation runs)."""

    def world_view(self, roster: Sequence[CharacterStatus]) -> WorldView:
        chars = tuple(
            CharacterState(
                name=c.name, position=c.position, facing=c.facing, action=c.action, busy=c.busy, seat=c.seat
            )
            for c in roster
        )
        return WorldView(characters=chars, objects_in_use={c.seat: c.name for c in roster if c.seat})

    def seats_in_use(self, roster: Sequence[CharacterStatus]) -> list[str]:
        return sorted(c.seat for c in roster if c.seat)


def describer_mode_for(model: str) -> str:
    """Small embedded models name numbered regions; API models list every object."""
    return "regions" if model.startswith("local/") else "objects"


def character_names(count: int) -> list[str]:
    if count <= len(NAMES):
        return list(NAMES[:count])
    return [*NAMES, *(f"Extra{i}" for i in range(count - len(NAMES)))]


def start_positions(scene: Scene, count: int, seed: int) -> list[tuple[float, float]]:
    """``count`` free floor points, >= START_SEPARATION apart, deterministic for ``seed``."""
    rng = np.random.default_rng(seed)
    floor = FloorMap(scene)
    lo, hi = np.array(scene.bounds_min), np.array(scene.bounds_max)
    chosen: list[np.ndarray] = []
    for _ in range(200):
        pts = rng.uniform(lo, hi, size=(256, 2))
        for p in pts[floor.free(pts)]:
            if all(np.linalg.norm(p - q) >= START_SEPARATION for q in chosen):
                chosen.append(p)
                if len(chosen) == count:
                    return [(round(float(x), 3), round(float(y), 3)) for x, y in chosen]
    raise typer.BadParameter(f"cannot place {count} characters on the free floor of scene '{scene.name}'")


def initial_roster(scene: Scene, count: int, seed: int) -> tuple[CharacterStatus, ...]:
    return tuple(
        CharacterStatus(name=n, position=p, facing=(0.0, 1.0))
        for n, p in zip(character_names(count), start_positions(scene, count, seed), strict=True)
    )


def format_event_text(index: int, outcome: ParsedEvent | PlanningFailure | None) -> str:
    """Plain-text lines for one step (deterministic: fixed decimals, no timings)."""
    head = f"event {index + 1}:"
    if outcome is None:
        return f"{head} wait"
    if isinstance(outcome, PlanningFailure):
        return f"{head} failed in {outcome.node} after {outcome.attempts} attempts: {outcome.feedback}"
    lines = [f"{head} {', '.join(outcome.event.characters)}: {outcome.event.activity}"]
    for p in outcome.plans:
        lines.append(
            f"  {p.character}: {p.action} | {p.area} | position [{p.position[0]:.2f}, {p.position[1]:.2f}]"
            f" | facing [{p.facing[0]:.2f}, {p.facing[1]:.2f}]"
        )
    return "\n".join(lines)


def outcome_json(index: int, outcome: ParsedEvent | PlanningFailure | None) -> dict[str, Any]:
    if outcome is None:
        return {"index": index, "kind": "wait"}
    if isinstance(outcome, PlanningFailure):
        return {"index": index, "kind": "failure", **outcome.model_dump(mode="json", exclude={"index"})}
    return {
        "index": index,
        "kind": "event",
        "characters": list(outcome.event.characters),
        "activity": outcome.event.activity,
        "plans": [
            {
                "character": p.character,
                "action": p.action,
                "area": p.area,
                "position": [round(p.position[0], 3), round(p.position[1], 3)],
                "facing": [round(p.facing[0], 3), round(p.facing[1], 3)],
            }
            for p in outcome.plans
        ],
        "narrator_attempts": outcome.narrator_attempts,
        "parser_attempts": outcome.parser_attempts,
    }


def open_port(config_path: Path | None, record: Path | None, replay: Path | None) -> tuple[LLMPort, str]:
    """The LLM port from the run config (embedded model by default) and the describer's model."""
    from orchestrator.llm.config import load_config
    from orchestrator.llm.replay import build_llm_port

    config = load_config(config_path)
    return build_llm_port(config, record=record, replay=replay), config.node("describer").model


async def close_port(port: Any) -> None:
    for name in ("aclose", "close"):
        method = getattr(port, name, None)
        if method is not None:
            result = method()
            if asyncio.iscoroutine(result):
                await result
            return


async def run_plan(
    *,
    scene: Scene,
    port: LLMPort,
    instruction: str,
    characters: int,
    events: int,
    seed: int,
    runs_db: Path,
    thread_id: str,
    describer_model: str = "unknown",
    description_cache: Path | None = None,
    busy_events: int = 0,
    max_retries: int = 3,
    prompts: PromptLibrary | None = None,
    tags: tuple[str, ...] = BENCHMARK_TAGS,
    on_outcome: Any = None,
    ablation: Ablation | None = None,
    program_grammar: bool = False,
) -> list[tuple[int, ParsedEvent | PlanningFailure | None]]:
    """Run (or resume) the planning graph for one thread; returns every step's outcome.

    ``on_outcome(index, outcome)`` is called for each step as it is recorded, in order,
    including steps recorded before a resume. ``ablation`` picks the planner and the scene
    description (default: the full method with the describer).
    """
    ablation = ablation or Ablation()
    thread_id = ablation.thread_id(thread_id)
    story = StoryLog(runs_db, thread_id)
    printed = 0

    def flush() -> None:
        nonlocal printed
        outcomes = story.outcomes()
        for idx, outcome in outcomes[printed:]:
            if on_outcome is not None:
                on_outcome(idx, outcome)
        printed = len(outcomes)

    deps = PlanningDeps(
        port=port,
        scene=scene,
        world=RosterWorld(),
        story=story,
        action_labels=scene_action_labels(scene),
        prompts=prompts or PromptLibrary(),
        tags=tags,
        seed=seed,
        max_retries=max_retries,
        busy_for_events=busy_events,
        describer_model=describer_model,
        describer_mode=describer_mode_for(describer_model),
        description_cache=description_cache,
        program_grammar=program_grammar,
    )
    config = {"configurable": {"thread_id": thread_id}, "recursion_limit": recursion_limit(events, max_retries)}
    try:
        async with open_checkpointer(runs_db) as saver:
            graph = compile_graph(ablation, saver)
            snapshot = await graph.aget_state(config)
            start: dict[str, Any] | None
            if snapshot.values:
                start = None  # resume the interrupted thread
            else:
                start = PlanningState(
                    instruction=instruction, events_target=events, roster=initial_roster(scene, characters, seed)
                ).model_dump()
            async for _ in graph.astream(start, config=config, context=deps, durability="sync", stream_mode="updates"):
                flush()
        flush()
        return story.outcomes()
    finally:
        story.close()


def register(app: typer.Typer) -> None:
    app.command("plan")(plan_command)


def plan_command(
    scene: Annotated[str, typer.Argument(help="Bundled scene name or path to a scene.")],
    characters: Annotated[int, typer.Option("--characters", "-n", min=1, max=24, help="Number of characters.")] = 2,
    instruction: Annotated[str, typer.Option("--instruction", "-i", help="What should happen.")] = "",
    events: Annotated[int, typer.Option("--events", "-k", min=1, max=100, help="Planning steps (K).")] = 1,
    record: Annotated[Path | None, typer.Option("--record", help="Write every LLM call to this trace.")] = None,
    replay: Annotated[Path | None, typer.Option("--replay", help="Serve LLM calls from this trace.")] = None,
    config: Annotated[Path | None, typer.Option("--config", help="TOML run config.")] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of start positions and sampling.")] = 0,
    busy_events: Annotated[int, typer.Option("--busy-events", min=0, help="Steps an event keeps its characters busy.")] = 0,
    max_retries: Annotated[int, typer.Option("--max-retries", min=0, max=10, help="Retries per LLM role.")] = 3,
    program_grammar: Annotated[bool, typer.Option("--program-grammar/--free-programs", help="Local models write event programs under a grammar of the API's area functions and the scene's names (--free-programs: free Python, as the paper).")] = True,
    runs_db: Annotated[Path | None, typer.Option("--runs-db", help="SQLite file of checkpoints.")] = None,
    thread_id: Annotated[str | None, typer.Option("--thread-id", help="Resume this run.")] = None,
    prompts_dir: Annotated[Path | None, typer.Option("--prompts", help="Use prompt files from this folder.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    planner: Annotated[
        str, typer.Option("--planner", help="event (narrator + event parser), unified (w/o Event) or direct (coordinates).")
    ] = "event",
    description: Annotated[
        str, typer.Option("--description", help="Scene description: describer, object-list or scene-graph.")
    ] = "describer",
) -> None:
    """Plan K events with the narrator and event parser (or an ablation) and print them."""
    from sim.scene.bundled import resolve_scene
    from sim.scene.files import SceneFileError

    try:
        ablation = Ablation.parse(planner, description)
    except AblationChoiceError as exc:
        _fail(str(exc))
    if record is not None and replay is not None:
        _fail("--record and --replay cannot be used together")
    if prompts_dir is not None and not prompts_dir.is_dir():
        _fail(f"--prompts {prompts_dir}: not a folder")
    try:
        scene_obj = resolve_scene(scene)
    except SceneFileError as exc:
        _fail(str(exc))
    thread = thread_id or uuid.uuid4().hex[:12]
    resume = f"--thread-id {thread}" if ablation.is_default else (
        f"--thread-id {thread} --planner {ablation.planner} --description {ablation.description}"
    )
    typer.echo(f"thread {thread} (resume with {resume})", err=True)
    try:
        port, describer_model = open_port(config, record, replay)
    except (LLMError, ValueError, OSError) as exc:
        _fail(str(exc))
    cache = None
    if record is None and replay is None:
        cache = default_runs_db().parent / "descriptions"

    def show(index: int, outcome: ParsedEvent | PlanningFailure | None) -> None:
        if not as_json:
            typer.echo(format_event_text(index, outcome))

    async def main() -> list[tuple[int, ParsedEvent | PlanningFailure | None]]:
        try:
            return await run_plan(
                scene=scene_obj,
                port=port,
                instruction=instruction,
                characters=characters,
                events=events,
                seed=seed,
                runs_db=runs_db or default_runs_db(),
                thread_id=thread,
                describer_model=describer_model,
                description_cache=cache,
                busy_events=busy_events,
                max_retries=max_retries,
                prompts=PromptLibrary(prompts_dir) if prompts_dir is not None else None,
                on_outcome=show,
                ablation=ablation,
                program_grammar=program_grammar,
            )
        finally:
            await close_port(port)

    try:
        outcomes = asyncio.run(main())
    except (LLMError, RetriesExhaustedError, PromptTemplateError) as exc:
        _fail(f"{type(exc).__name__}: {exc}", code=1)
    if as_json:
        payload = {
            "scene": scene_obj.name,
            "characters": character_names(characters),
            "instruction": instruction,
            "events": [outcome_json(i, o) for i, o in outcomes],
        }
        if not ablation.is_default:
            payload["ablation"] = {"planner": ablation.planner, "description": ablation.description}
        typer.echo(json.dumps(payload, indent=2))


def _fail(message: str, code: int = 2) -> NoReturn:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(typer.run(plan_command))

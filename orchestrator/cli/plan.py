"""``storyteller plan``: plan K events in a scene with the planning graph, without a simulation.

The job itself is :func:`storyteller.orchestrator.session.plan_job.run_plan` (see there how the story
advances by steps; ``--busy-events`` keeps an event's characters busy for that many further
steps). A step whose narrator waits, or whose retries run out, still counts as one of the K
steps (printed as ``wait`` / ``failed``).

``--record T.jsonl`` writes every LLM call to a trace; ``--replay T.jsonl`` serves the calls
from that trace (no model is loaded) and reproduces the printed events byte for byte; a
request that differs from the recorded one (e.g. after a prompt file changed) fails with a
diff naming the node. The describer's on-disk cache is used only for live runs without
``--record``, so a recorded trace always holds the describer call.

Runs are checkpointed in SQLite (``--runs-db``); ``--thread-id ID`` of an interrupted run
resumes it without repeating its finished LLM calls.

``--planner unified|direct`` and ``--description object-list|scene-graph`` run the paper's
ablations (variants of the planning graph, ``storyteller.orchestrator.planning.ablation_graph``) through
the same LLM port, trace, replay and output. A thread is resumed with the options it was
started with (other options start their own thread).
"""

from __future__ import annotations

import json
import sqlite3
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from storyteller.orchestrator.cli.options import (
    Characters,
    Config,
    Description,
    InProcessPrograms,
    Instruction,
    MaxRetries,
    Planner,
    ProgramGrammar,
    SceneArg,
    fail,
)
from storyteller.orchestrator.safe_text import plain
from storyteller.orchestrator.terminal import say

if TYPE_CHECKING:
    from storyteller.agents.messages import ParsedEvent, PlanningFailure
    from storyteller.orchestrator.planning.ablation_graph import Ablation
    from storyteller.orchestrator.session.plan_job import PlanResult
    from storyteller.sim.scene.model import Scene

def format_event_text(index: int, outcome: ParsedEvent | PlanningFailure | None) -> str:
    """Plain-text lines for one step (deterministic: fixed decimals, no timings)."""
    from storyteller.agents.messages import PlanningFailure

    head = f"event {index + 1}:"
    if outcome is None:
        return f"{head} wait"
    if isinstance(outcome, PlanningFailure):
        return f"{head} failed in {outcome.node} after {outcome.attempts} attempts: {plain(outcome.feedback, keep_newlines=True)}"
    lines = [f"{head} {plain(', '.join(outcome.event.characters))}: {plain(outcome.event.activity)}"]
    for p in outcome.plans:
        lines.append(
            f"  {plain(p.character)}: {plain(p.action)} | {plain(p.area)} | position [{p.position[0]:.2f}, {p.position[1]:.2f}]"
            f" | facing [{p.facing[0]:.2f}, {p.facing[1]:.2f}]"
        )
    return "\n".join(lines)


def outcome_json(index: int, outcome: ParsedEvent | PlanningFailure | None) -> dict[str, Any]:
    from storyteller.agents.messages import PlanningFailure

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


def register(app: typer.Typer) -> None:
    app.command("plan")(plan_command)


def plan_command(
    scene: SceneArg,
    characters: Characters = 2,
    instruction: Instruction = "",
    events: Annotated[int, typer.Option("--events", "-k", min=1, max=100, help="Planning steps (K).")] = 1,
    record: Annotated[Path | None, typer.Option("--record", help="Write every LLM call to this trace.")] = None,
    replay: Annotated[Path | None, typer.Option("--replay", help="Serve LLM calls from this trace.")] = None,
    config: Config = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of start positions and sampling.")] = 0,
    busy_events: Annotated[int, typer.Option("--busy-events", min=0, help="Steps an event keeps its characters busy.")] = 0,
    max_retries: MaxRetries = 3,
    program_grammar: ProgramGrammar = True,
    in_process_programs: InProcessPrograms = False,
    runs_db: Annotated[Path | None, typer.Option("--runs-db", help="SQLite file of checkpoints.")] = None,
    thread_id: Annotated[str | None, typer.Option("--thread-id", help="Resume this run.")] = None,
    prompts_dir: Annotated[Path | None, typer.Option("--prompts", help="Use prompt files from this folder.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    planner: Planner = "event",
    description: Description = "describer",
) -> None:
    """Plan K events with the narrator and event parser (or an ablation) and print them."""
    import asyncio

    # The planning stack (langgraph, litellm, clustering) is imported here, not at module
    # level, so that ``storyteller --help`` and the other commands start at once.
    from storyteller.agents.llm_port import LLMError
    from storyteller.agents.prompt_templates import PromptLibrary, PromptTemplateError
    from storyteller.agents.retry_feedback import RetriesExhaustedError
    from storyteller.orchestrator.cache_paths import description_cache_dir
    from storyteller.orchestrator.planning.ablation_graph import Ablation
    from storyteller.orchestrator.planning.checkpoints import default_runs_db
    from storyteller.orchestrator.session.plan_job import run_plan
    from storyteller.orchestrator.session.port_setup import open_port
    from storyteller.orchestrator.session.roster import StartPositionError

    ablation = Ablation(planner=planner, description=description)
    scene_obj = _checked_inputs(scene, instruction, record, replay, prompts_dir, runs_db)
    thread = thread_id or uuid.uuid4().hex[:12]
    try:
        port, describer_model = open_port(config, record, replay, planner=planner)
    except (LLMError, ValueError, OSError) as exc:
        fail(str(exc))
    say(f"thread {thread} (resume with {_resume_options(thread, ablation)})", err=True)
    cache = description_cache_dir() if record is None and replay is None else None

    async def main() -> PlanResult:
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
                on_outcome=None if as_json else _print_outcome,
                ablation=ablation,
                program_grammar=program_grammar,
                in_process_programs=in_process_programs,
            )
        finally:
            port.close()

    try:
        result = asyncio.run(main())
    except StartPositionError as exc:
        fail(str(exc))
    except (LLMError, RetriesExhaustedError, PromptTemplateError) as exc:
        fail(f"{type(exc).__name__}: {exc}", code=1)
    except sqlite3.DatabaseError as exc:  # --runs-db is not a database this can open
        fail(f"--runs-db {runs_db or default_runs_db()}: cannot use the checkpoint database ({exc})")
    if as_json:
        say(json.dumps(_json_report(scene_obj.name, characters, instruction, result, ablation), indent=2))


def _print_outcome(index: int, outcome: ParsedEvent | PlanningFailure | None) -> None:
    say(format_event_text(index, outcome))


def _checked_inputs(
    scene: str, instruction: str, record: Path | None, replay: Path | None, prompts_dir: Path | None,
    runs_db: Path | None,
) -> Scene:
    """The scene ``plan`` runs in, once its options are known good: a bad one (too long an
    instruction, ``--record`` with ``--replay``, an unreadable prompt folder, a ``--runs-db``
    that is not a file, an unknown scene) is one line and exit code 2, before anything runs."""
    from storyteller.agents.prompt_templates import PromptLibrary, PromptTemplateError
    from storyteller.orchestrator.session.instruction_script import MAX_INSTRUCTION_CHARS
    from storyteller.sim.scene.bundled import resolve_scene
    from storyteller.sim.scene.files import SceneFileError

    if len(instruction) > MAX_INSTRUCTION_CHARS:
        fail(f"--instruction: {len(instruction)} characters, at most {MAX_INSTRUCTION_CHARS} allowed")
    if record is not None and replay is not None:
        fail("--record and --replay cannot be used together")
    if prompts_dir is not None and not prompts_dir.is_dir():
        fail(f"--prompts {prompts_dir}: not a folder")
    if prompts_dir is not None:
        try:  # every file read now (bounded, UTF-8): a bad one is one line before anything runs
            _read_prompt_folder(PromptLibrary(prompts_dir))
        except PromptTemplateError as exc:
            fail(f"--prompts {prompts_dir}: {exc}")
    if runs_db is not None and (runs_db.exists() or runs_db.is_symlink()) and not runs_db.is_file():
        fail(f"--runs-db {runs_db}: not a regular file (an SQLite database file is expected)")
    try:
        return resolve_scene(scene)
    except SceneFileError as exc:
        fail(str(exc))


def _resume_options(thread: str, ablation: Ablation) -> str:
    """The options that resume ``thread`` (an ablation's thread is resumed with its options)."""
    if ablation.is_default:
        return f"--thread-id {thread}"
    return f"--thread-id {thread} --planner {ablation.planner} --description {ablation.description}"


def _json_report(scene: str, characters: int, instruction: str, result: PlanResult, ablation: Ablation) -> dict[str, Any]:
    """What ``plan --json`` prints: the scene, the characters, the instruction, every step's outcome."""
    from storyteller.orchestrator.session.roster import character_names

    payload: dict[str, Any] = {
        "scene": scene,
        "characters": character_names(characters),
        "instruction": instruction,
        "events": [outcome_json(i, o) for i, o in result.outcomes],
    }
    if not ablation.is_default:
        payload["ablation"] = {"planner": ablation.planner, "description": ablation.description}
    return payload


def _read_prompt_folder(library: Any) -> None:
    """Read, through ``library`` (a user's ``--prompts`` folder), every prompt file the project
    ships, so a missing, oversized or unreadable one is refused before planning starts."""
    from importlib import resources

    def walk(node: Any, prefix: str) -> None:
        for child in sorted(node.iterdir(), key=lambda c: c.name):
            if child.is_dir() and child.name != "__pycache__":
                walk(child, f"{prefix}{child.name}/")
            elif child.is_file() and not child.name.endswith((".py", ".pyc")):
                library.text(f"{prefix}{child.name}")

    walk(resources.files("storyteller.prompts"), "")


if __name__ == "__main__":  # pragma: no cover
    typer.run(plan_command)

"""``storyteller event-program``: dry-run one ``parse_event()`` program against a scene."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from storyteller.orchestrator.safe_text import markup, plain
from storyteller.orchestrator.terminal import say

if TYPE_CHECKING:  # imported by the command, so that other commands start without it
    from storyteller.tools.character_states import CharacterPlan, WorldView


class _UsageError(Exception):
    """Bad input file: one sentence for stderr, exit code 2."""


def register(app: typer.Typer) -> None:
    app.command("event-program")(event_program)


MAX_STATES_FILE_BYTES = 16 * 1024 * 1024
MAX_STATES_JSON_DEPTH = 64


def _read_json(path: Path, what: str) -> Any:
    """A JSON file read within byte and nesting limits (``storyteller.sim.bounded_files``)."""
    from storyteller.sim.bounded_files import BoundedFileError, load_bounded_json, read_bounded_bytes

    try:
        raw = read_bounded_bytes(path, MAX_STATES_FILE_BYTES, f"{path}: {what} file")
        return load_bounded_json(raw, MAX_STATES_JSON_DEPTH, f"{path}: {what} file")
    except BoundedFileError as exc:
        raise _UsageError(str(exc)) from None


MAX_PROGRAM_FILE_BYTES = 256 * 1024
"""Bytes of a program file: the sandbox takes 20,000 characters of program text at most
(``Budget.source_chars``); a larger file is refused here, before it is read whole or sent."""


def read_program(path: Path) -> str:
    """The program file's text, read within :data:`MAX_PROGRAM_FILE_BYTES`."""
    from storyteller.sim.bounded_files import BoundedFileError, read_bounded_bytes

    try:
        raw = read_bounded_bytes(path, MAX_PROGRAM_FILE_BYTES, f"{path}: program file")
        return raw.decode("utf-8")
    except BoundedFileError as exc:
        raise _UsageError(str(exc)) from None
    except UnicodeDecodeError as exc:
        raise _UsageError(f"{path}: program file is not UTF-8 text (bad byte at offset {exc.start})") from None


def load_states(path: Path, scene: Any) -> tuple[WorldView, list[str] | None]:
    """World view and action labels from a reference test case (``current_states``,
    ``planning_history``, ``action_labels``) or a project ``WorldView`` JSON (``characters``)."""
    from pydantic import ValidationError

    from storyteller.sim.validation_text import user_error
    from storyteller.tools.character_states import ReferenceCaseError, WorldView, world_view_from_reference_case

    data = _read_json(path, "states")
    if not isinstance(data, dict):
        raise _UsageError(f"{path}: expected a JSON object")
    labels = data.get("action_labels")
    if labels is not None and not (
        isinstance(labels, list) and all(isinstance(v, str) for v in labels)
    ):
        raise _UsageError(f"{path}: field 'action_labels': expected a list of strings")
    try:
        if "current_states" in data:
            return world_view_from_reference_case(data, scene), labels
        if "characters" in data:
            return WorldView.model_validate(
                {k: v for k, v in data.items() if k != "action_labels"}
            ), labels
    except ReferenceCaseError as exc:
        raise _UsageError(f"{path}: {exc}") from None
    except ValidationError as exc:
        raise _UsageError(user_error(path, exc)) from None
    raise _UsageError(
        f"{path}: expected a reference test case ('current_states') or a world view ('characters')"
    )


def plans_json(plans: list[CharacterPlan], error: dict[str, Any] | None) -> str:
    """The ``--json`` document: ``{"plans": [...], "error": null | {...}}``."""
    return json.dumps(
        {
            "plans": [
                {
                    "character": p.character,
                    "action": p.action,
                    "position": [round(p.position[0], 4), round(p.position[1], 4)],
                    "facing": [round(p.facing[0], 4), round(p.facing[1], 4)],
                    "area": p.area,
                    "seat": p.seat,
                }
                for p in plans
            ],
            "error": error,
        }
    )


def event_program(
    scene: Annotated[
        str, typer.Argument(help="Bundled scene name or path (reference folder, JSON, mesh).")
    ],
    program: Annotated[Path, typer.Option("--program", help="File with a parse_event() program.")],
    states: Annotated[
        Path | None,
        typer.Option("--states", help="Reference test-case JSON (or a world-view JSON)."),
    ] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the position sampler.")] = 0,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    in_process: Annotated[
        bool,
        typer.Option(
            "--in-process",
            help="Run the program in this process (no worker process and its OS limits).",
        ),
    ] = False,
) -> None:
    """Dry-run a parse_event() program: print each character's action, area, position and facing."""
    from storyteller.sim.scene.bundled import resolve_scene
    from storyteller.sim.scene.files import SceneFileError
    from storyteller.tools.character_states import WorldView
    from storyteller.tools.errors import EventProgramError
    from storyteller.tools.event_program import run_event_program

    try:
        loaded = resolve_scene(scene)
        source = read_program(program)
        world, labels = load_states(states, loaded) if states is not None else (WorldView(), None)
    except (SceneFileError, _UsageError) as exc:
        say(f"error: {plain(exc)}", err=True)
        raise typer.Exit(2) from None

    try:
        if in_process:
            plans = run_event_program(loaded, source, world, seed=seed, action_labels=labels)
        else:
            from storyteller.orchestrator.sandbox_worker import WorkerRunner

            with WorkerRunner() as run:
                plans = run(loaded, source, world, seed=seed, action_labels=labels)
    except EventProgramError as exc:
        error = {
            "kind": exc.kind,
            "type": type(exc).__name__,
            "message": exc.feedback,
            "line": exc.line,
        }
        if as_json:
            say(plans_json([], error))
        else:
            say(f"error ({exc.kind}): {plain(exc.feedback)}", err=True)
        raise typer.Exit(1) from None

    if as_json:
        say(plans_json(plans, None))
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"event program on {markup(loaded.name)} (seed {seed})")
    for column in ("character", "action", "area", "position [x, y]", "facing [dx, dy]"):
        table.add_column(column)
    for p in plans:
        table.add_row(
            markup(p.character),
            markup(p.action),
            markup(p.area),
            f"[{p.position[0]:.2f}, {p.position[1]:.2f}]",
            f"[{p.facing[0]:.2f}, {p.facing[1]:.2f}]",
        )
    say(table, console=Console(emoji=False))  # markup() escapes markup; a ':smile:' stays text too

"""Typer options shared by ``storyteller plan`` and ``storyteller run`` (one help text each)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, NoReturn

import typer

from storyteller.orchestrator.planning.kinds import DescriptionKind, PlannerKind
from storyteller.orchestrator.session.pace import Pace
from storyteller.orchestrator.terminal import say

SceneArg = Annotated[str, typer.Argument(help="Bundled scene name or path to a scene.")]
Characters = Annotated[int, typer.Option("--characters", "-n", min=1, max=24, help="Number of characters.")]
Instruction = Annotated[str, typer.Option("--instruction", "-i", help="What should happen.")]
Config = Annotated[Path | None, typer.Option("--config", help="TOML run config.")]
MaxRetries = Annotated[int, typer.Option("--max-retries", min=0, max=10, help="Retries per LLM role.")]
ProgramGrammar = Annotated[
    bool,
    typer.Option(
        "--program-grammar/--free-programs",
        help="Local models write event programs under a grammar of the API's area functions and the scene's names "
        "(--free-programs: free Python, as the paper).",
    ),
]
InProcessPrograms = Annotated[
    bool,
    typer.Option(
        "--in-process-programs",
        help="Run event programs in this process (default: a worker process with memory, CPU and wall-clock "
        "limits; the plans are the same).",
    ),
]
# Literal-typed options: typer rejects any other value (exit code 2) and lists the choices
Planner = Annotated[
    PlannerKind, typer.Option("--planner", help="event (narrator + event parser), unified (w/o Event) or direct (coordinates).")
]
Description = Annotated[
    DescriptionKind, typer.Option("--description", help="Scene description: describer, object-list or scene-graph.")
]

PaceOption = Annotated[Pace, typer.Option(
    "--pace", help="lockstep (sim waits for the planner), realtime, fast, or offline (each LLM call takes its latency in simulated time)."
)]

LiveOption = Annotated[bool | None, typer.Option(
    "--live/--no-live",
    help="A live view on the terminal: simulated time and speed, each character's state and event, LLM calls in "
    "flight, tokens so far; the story's lines print above it (default: when stdout is a terminal). --no-live: plain "
    "lines only.",
)]


ViewOption = Annotated[bool, typer.Option(
    "--view/--no-view",
    help="Also serve the browser viewer of the run folder (as `storyteller view OUT`), with an instruction box; "
    "its address is printed, and it keeps serving after the story ends until Ctrl-C.",
)]
ViewPortOption = Annotated[int, typer.Option(
    "--port", min=0, max=65535, help="With --view: port to listen on (0: any free port; taken: the next free one).",
)]
ViewHostOption = Annotated[str, typer.Option(
    "--host",
    help="With --view: address to listen on. 127.0.0.1 (the default): this machine only. Any other (0.0.0.0: every "
    "interface) lets other machines connect, with the token in the printed URL.",
)]


def fail(message: str, code: int = 2) -> NoReturn:
    """Print ``error: message`` to stderr and exit (2: a user error). The message names files
    and quotes their content, so it goes through :func:`~storyteller.orchestrator.safe_text.one_line` (one
    line whatever it quoted: its lines joined with spaces; control, format and bidi characters
    shown as escapes)."""
    from storyteller.orchestrator.safe_text import one_line

    say(f"error: {one_line(message)}", err=True)
    raise typer.Exit(code)

"""The ``storyteller`` command. Each command group lives in its own ``cli_*`` module."""

from __future__ import annotations

import typer

from orchestrator import cli_event, cli_model, cli_plan, cli_run, cli_scene

app = typer.Typer(
    name="storyteller",
    help="Event-driven multi-character storytelling in 3D scenes.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)
cli_scene.register(app)
cli_plan.register(app)
cli_event.register(app)
cli_model.register(app)
cli_run.register(app)


def main() -> None:  # pragma: no cover - console entry point
    app()

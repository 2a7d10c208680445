"""The ``storyteller`` command. Each command group lives in its own module of ``orchestrator.cli``."""

from __future__ import annotations

import typer

from orchestrator.cli import event_program as cli_event
from orchestrator.cli import model as cli_model
from orchestrator.cli import plan as cli_plan
from orchestrator.cli import run as cli_run
from orchestrator.cli import scene as cli_scene
from orchestrator.cli import view as cli_view

app = typer.Typer(
    name="storyteller",
    help="Event-driven multi-character storytelling in 3D scenes.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)


@app.callback()
def _setup(
    log_level: str = typer.Option("WARNING", "--log-level", help="Log level (logs go to stderr)."),
) -> None:
    """Configure logging once for every command (structlog to stderr)."""
    from orchestrator.logging_setup import configure_logging

    try:
        configure_logging(log_level)
    except ValueError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None


cli_scene.register(app)
cli_plan.register(app)
cli_event.register(app)
cli_model.register(app)
cli_run.register(app)
cli_view.register(app)


def main() -> None:  # pragma: no cover - console entry point
    app()

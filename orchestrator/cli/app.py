"""The ``storyteller`` command. Each command group lives in its own module of ``orchestrator.cli``.

Command plugins: every entry point of the ``storyteller.commands`` group (``pyproject.toml``;
e.g. ``bench = "benchmark.sweep.cli:register"``) names a ``register(app)`` function that adds
its commands; :func:`register_plugins` calls each one. That is how ``storyteller bench`` joins
without ``orchestrator`` importing ``benchmark``. A plugin module should import only typer at
module level (it is loaded at start-up); one that cannot be loaded is reported on stderr and
skipped, never fatal to the other commands.
"""

from __future__ import annotations

from collections.abc import Iterable
from importlib.metadata import EntryPoint, entry_points

import typer

from orchestrator.cli import event_program as cli_event
from orchestrator.cli import model as cli_model
from orchestrator.cli import plan as cli_plan
from orchestrator.cli import run as cli_run
from orchestrator.cli import scene as cli_scene
from orchestrator.cli import view as cli_view
from orchestrator.safe_text import plain
from orchestrator.terminal import say

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
        say(f"error: {plain(exc)}", err=True)
        raise typer.Exit(2) from None


cli_scene.register(app)
cli_plan.register(app)
cli_event.register(app)
cli_model.register(app)
cli_run.register(app)
cli_view.register(app)

PLUGIN_GROUP = "storyteller.commands"


def register_plugins(target: typer.Typer, plugins: Iterable[EntryPoint] | None = None) -> list[str]:
    """Call ``register(target)`` of every command plugin (default: the installed entry points of
    :data:`PLUGIN_GROUP`); returns the names registered."""
    names = []
    for ep in entry_points(group=PLUGIN_GROUP) if plugins is None else plugins:
        try:
            register = ep.load()
        except (ImportError, AttributeError) as exc:
            say(f"warning: storyteller command plugin {ep.name!r} ({plain(ep.value)}) cannot be loaded: {plain(exc)}",
                err=True)
            continue
        register(target)
        names.append(ep.name)
    return names


register_plugins(app)


def main() -> None:  # pragma: no cover - console entry point
    from orchestrator.cli.collector import skip_final_collection

    try:
        app()
    finally:  # typer ends with SystemExit: the command is done, its files closed
        skip_final_collection()

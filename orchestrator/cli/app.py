"""The ``storyteller`` command. Each command group lives in its own module of ``storyteller.orchestrator.cli``.

Command plugins: every entry point of the ``storyteller.commands`` group (``pyproject.toml``;
e.g. ``bench = "storyteller.benchmark.sweep.cli:register"``) names a ``register(app)`` function that adds
its commands; :func:`register_plugins` calls each one. That is how ``storyteller bench`` joins
without ``orchestrator`` importing ``benchmark``. A plugin module should import only typer at
module level (it is loaded at start-up); one that cannot be loaded is reported on stderr and
skipped, never fatal to the other commands.

What the command prints goes through :func:`storyteller.orchestrator.terminal.say` (every command module
does); click's and typer's own usage errors quote the command line (an unknown option, a value
that is not a number), so :class:`_EscapedUsageErrors` escapes their message before typer
prints it, and :func:`main` says Python warnings the same way (matplotlib's about a glyph its
font lacks quotes the glyph of a scene's name).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator
from importlib.metadata import EntryPoint, entry_points
from typing import Any

import typer
from typer.core import TyperGroup

from storyteller.orchestrator.cli import event_program as cli_event
from storyteller.orchestrator.cli import model as cli_model
from storyteller.orchestrator.cli import plan as cli_plan
from storyteller.orchestrator.cli import run as cli_run
from storyteller.orchestrator.cli import scene as cli_scene
from storyteller.orchestrator.cli import view as cli_view
from storyteller.orchestrator.safe_text import plain
from storyteller.orchestrator.terminal import say, show_warning


@contextlib.contextmanager
def _escaped_usage_errors() -> Iterator[None]:
    try:
        yield
    except typer.TyperException as exc:  # click's usage errors (typer vendors click) and typer's own
        exc.message = plain(exc.message)  # a typed newline or tab too: the message is one line
        raise


class _EscapedUsageErrors(TyperGroup):
    """The root command: a usage error raised while parsing or dispatching any command has its
    message (which quotes what was typed) escaped; typer prints it as before."""

    def make_context(self, info_name: str | None, args: list[str], parent: Any = None, **extra: Any) -> Any:
        with _escaped_usage_errors():
            return super().make_context(info_name, args, parent, **extra)

    def invoke(self, ctx: Any) -> Any:
        with _escaped_usage_errors():
            return super().invoke(ctx)


app = typer.Typer(
    cls=_EscapedUsageErrors,
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
    from storyteller.orchestrator.logging_setup import configure_logging

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


OLD_TOP_LEVEL = frozenset({"sim", "tools", "agents", "orchestrator", "benchmark", "prompts"})
"""The project's import names before they moved under ``storyteller``: a plugin naming one comes
from stale install metadata (an old ``storyteller.egg-info`` beside the sources)."""


def register_plugins(target: typer.Typer, plugins: Iterable[EntryPoint] | None = None) -> list[str]:
    """Call ``register(target)`` of every command plugin (default: the installed entry points of
    :data:`PLUGIN_GROUP`); returns the names registered. A name registers once (the first); a
    plugin under the project's old import names is skipped with a warning saying how to mend
    the install (it would import the old modules beside the new ones)."""
    names: list[str] = []
    for ep in entry_points(group=PLUGIN_GROUP) if plugins is None else plugins:
        if ep.value.split(".", 1)[0].split(":", 1)[0] in OLD_TOP_LEVEL:
            say(f"warning: storyteller command plugin {ep.name!r} ({plain(ep.value)}) comes from stale install "
                "metadata (an old storyteller.egg-info?): skipped; run `pip install -e .` again", err=True)
            continue
        if ep.name in names:
            continue
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
    import warnings

    from storyteller.orchestrator.cli.collector import skip_final_collection

    warnings.showwarning = show_warning  # a warning that quotes data is said escaped
    try:
        app()
    finally:  # typer ends with SystemExit: the command is done, its files closed
        skip_final_collection()

"""What the ``storyteller`` command shows on a terminal goes through :func:`say`.

A line of text (echoed by typer to stdout, stderr or a given stream) or a rich renderable (a
table, a line above a live display, printed on a given console): whatever the caller built,
what reaches the terminal holds no character of
:data:`~storyteller.orchestrator.safe_text.UNSAFE_CATEGORIES` but newline and tab. No terminal escape
sequence, BEL, bidi control, U+061C, U+2028 / U+2029, zero-width character, word joiner or BOM
from a path, a scene name, a label, a model's text or an error message that quotes a file is
written raw; each is shown as its escape (``\\x1b``, ``\\u202e``; :func:`storyteller.orchestrator.safe_text.plain`).

Deliberate formatting stays: the newlines and tabs of a message, rich's own styles (a style is
not text: rich writes its colour sequences after :func:`escaped` has escaped the text of every
segment), box drawing. A string printed on a console is a literal ``rich.text.Text``, never
parsed as markup. The escaping is idempotent (an escape is printable text), so a caller that
already escaped what it interpolated (``plain``, ``one_line``, ``markup``: there a newline
from data must not start a line of its own) prints the same as before.

:func:`show_warning` is the ``warnings.showwarning`` of a command (``storyteller.orchestrator.cli.app``):
a Python warning that quotes data (matplotlib's about a missing glyph quotes the glyph) is said
the same way. The structlog renderer writes its lines itself: every key and value has been
through ``plain`` (``storyteller.orchestrator.logging_setup.escape_controls``) before it adds its colours.

``tests/orchestrator/cli/test_one_output_function.py`` fails if a module the command runs
prints any other way.
"""

from __future__ import annotations

import contextlib
import sys
import warnings
from collections.abc import Iterator
from typing import IO, TYPE_CHECKING

import typer

from storyteller.orchestrator.safe_text import plain

if TYPE_CHECKING:  # rich is imported by the commands that print tables, not at start-up
    from rich.console import Console, ConsoleOptions, RenderableType
    from rich.measure import Measurement
    from rich.segment import Segment


class _Escaped:
    """A rich renderable: ``inner`` rendered, the text of each of its segments escaped."""

    def __init__(self, inner: RenderableType) -> None:
        self.inner = inner

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> Iterator[Segment]:
        from rich.segment import Segment

        for segment in console.render(self.inner, options):
            text, style, control = segment
            if control or text.isprintable():  # rich's own cursor moves; most text is clean
                yield segment
            else:
                yield Segment(plain(text, keep_newlines=True), style)

    def __rich_measure__(self, console: Console, options: ConsoleOptions) -> Measurement:
        from rich.measure import Measurement

        return Measurement.get(console, options, self.inner)


def escaped(renderable: RenderableType) -> RenderableType:
    """``renderable`` with every character of its text that :func:`say` would escape escaped:
    for a display that is updated rather than printed (``rich.live.Live``). A string is taken
    as literal text, never markup."""
    from rich.text import Text

    return _Escaped(Text(renderable) if isinstance(renderable, str) else renderable)


def say(
    message: str | RenderableType, *, err: bool = False, file: IO[str] | None = None,
    console: Console | None = None, soft_wrap: bool = False,
) -> None:
    """Show ``message`` on the terminal with every control, format and separator character
    (but newline and tab) shown as an escape.

    Without ``console``: a string, one echo (a newline added) to stdout, or stderr with
    ``err``, or ``file``. With ``console``: a string or any rich renderable printed there
    (``soft_wrap``: long lines are left to the terminal, as ``Console.print``'s)."""
    if console is None:
        if not isinstance(message, str):
            raise TypeError(f"say: a {type(message).__name__} needs a console")
        typer.echo(plain(message, keep_newlines=True), file=file, err=err)
    else:
        console.print(escaped(message), soft_wrap=soft_wrap)


def show_warning(
    message: Warning | str, category: type[Warning], filename: str, lineno: int,
    file: IO[str] | None = None, line: str | None = None,
) -> None:
    """``warnings.showwarning`` that says the warning (its usual text) on stderr."""
    text = warnings.formatwarning(message, category, filename, lineno, line)
    with contextlib.suppress(OSError):  # as warnings' own: stderr closed or gone
        say(text.removesuffix("\n"), file=file if file is not None else sys.stderr)

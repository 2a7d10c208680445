"""``storyteller.orchestrator.terminal.say``: every control, format and separator character but newline and
tab is shown as an escape, in a line of text and in the text of a rich renderable, while rich's
own styles, the newlines and tabs of a message and a table's layout stay; Python warnings said
through :func:`show_warning` likewise."""

from __future__ import annotations

import io
import re

import pytest
from rich.console import Console
from rich.table import Table
from rich.text import Text

from storyteller.orchestrator.safe_text import plain
from storyteller.orchestrator.terminal import escaped, say, show_warning
from tests.support.hostile_files import unsafe_characters

HOSTILE = "\x1b[31m red \x07 \u202e \u2066 \u061c \u2028 \u2029 \u200b \u2060 \ufeff \x85 \x9b \r \x00"
SHOWN = (
    "\\x1b[31m red \\x07 \\u202e \\u2066 \\u061c \\u2028 \\u2029 \\u200b \\u2060 \\ufeff \\x85 \\x9b \\x0d \\x00"
)
SGR = re.compile(r"\x1b\[[0-9;]*m")  # rich's own colour sequences


def _console(buffer: io.StringIO) -> Console:
    return Console(file=buffer, force_terminal=True, color_system="standard", width=100)


def test_a_line_has_every_unsafe_character_escaped_and_keeps_its_newlines_and_tabs() -> None:
    buffer = io.StringIO()
    say(f"name:\t{HOSTILE}\nsecond line", file=buffer)
    assert buffer.getvalue() == f"name:\t{SHOWN}\nsecond line\n"


def test_stderr_and_stdout(capsys: pytest.CaptureFixture[str]) -> None:
    say(f"out {HOSTILE}")
    say(f"err {HOSTILE}", err=True)
    out, err = capsys.readouterr()
    assert (out, err) == (f"out {SHOWN}\n", f"err {SHOWN}\n")


def test_escaping_is_idempotent() -> None:
    once, twice = io.StringIO(), io.StringIO()
    say(HOSTILE, file=once)
    say(plain(HOSTILE), file=twice)
    assert once.getvalue() == twice.getvalue()


def test_a_table_keeps_rich_styles_and_shows_its_data_escaped() -> None:
    table = Table(title="Objects")
    table.add_column("name", style="bold")
    table.add_row(Text(f"chair{HOSTILE}"))  # a cell a caller forgot to escape
    buffer = io.StringIO()
    say(table, console=_console(buffer))
    out = buffer.getvalue()
    assert SGR.search(out)  # rich's styles are still written
    assert unsafe_characters(SGR.sub("", out)) == []
    assert "chair\\x1b[31m red" in out and "\\u202e \\u2066" in out  # rich itself drops BEL and CR
    assert "┏" in out and out.count("\n") >= 5  # still a table, on several lines


def test_a_string_on_a_console_is_literal_text_not_markup() -> None:
    buffer = io.StringIO()
    say("[bold red]x[/] :smile: \x1b[2J", console=Console(file=buffer, width=100))
    assert buffer.getvalue() == "[bold red]x[/] :smile: \\x1b[2J\n"


def test_a_live_display_renderable_is_escaped() -> None:
    buffer = io.StringIO()
    _console(buffer).print(escaped(Text(HOSTILE, style="green")))
    assert unsafe_characters(SGR.sub("", buffer.getvalue())) == []
    assert "\\x1b[31m red" in buffer.getvalue() and "\\u2028 \\u2029" in buffer.getvalue()


def test_a_renderable_needs_a_console() -> None:
    with pytest.raises(TypeError, match="Table needs a console"):
        say(Table())


def test_a_warning_is_said_in_its_usual_format_escaped() -> None:
    buffer = io.StringIO()
    show_warning(UserWarning(f"Glyph 27 ({HOSTILE}) missing"), UserWarning, "topdown.py", 456, file=buffer,
                 line="fig.savefig(path)")
    assert buffer.getvalue() == f"topdown.py:456: UserWarning: Glyph 27 ({SHOWN}) missing\n  fig.savefig(path)\n"

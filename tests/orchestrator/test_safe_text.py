"""Outside text reaches the terminal as data: the sanitiser, ``scene inspect`` and ``view --export``.

- :func:`storyteller.orchestrator.safe_text.plain` leaves no character of the categories Cc, Cf, Zl, Zp or
  Cs in its output (newline and tab only where the call site keeps lines), for any string
  (hypothesis), and through rich (:func:`~storyteller.orchestrator.safe_text.markup`) the text renders as
  itself;
- ``storyteller scene inspect`` on a scene whose name, object names and labels carry rich
  markup, terminal escape sequences, BEL, a bidi override and U+2028 prints its tables, exit 0,
  with none of those characters on stdout; an error line from such a file is one clean line;
- ``storyteller view --export`` of a run whose recorded activity holds a lone surrogate writes
  the HTML file (no encode error).
"""

from __future__ import annotations

import json
import subprocess
import sys
import unicodedata
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st
from rich.text import Text
from typer.testing import CliRunner

from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.safe_text import markdown, markup, plain
from storyteller.sim.scene.bundled import load_bundled_scene
from tests.support.tiny_run import write_tiny_run

BANNED = frozenset({"Cc", "Cf", "Zl", "Zp", "Cs"})
# every kind the issue names: markup, CSI and OSC sequences, BEL, bidi, separators, zero widths
HOSTILE = ("[/]", "[bold]", "[/bold]", "\x1b[31m", "\x1b]0;pwn\x07", "\x07", "\u202e", "\u2028",
           "\u2029", "\u061c", "\u200b", "\u2060", "\ufeff", "\x85", "\udc80", "\U000e0001")  # fmt: skip


def banned_in(text: str, allowed: str = "") -> list[str]:
    return [
        f"U+{ord(c):04X}" for c in text if c not in allowed and unicodedata.category(c) in BANNED
    ]


# ----- the sanitiser ----------------------------------------------------------------------------
any_text = st.text(st.characters(codec=None, min_codepoint=0, max_codepoint=0x10FFFF), max_size=60)
hostile_text = st.lists(st.sampled_from(HOSTILE) | any_text, max_size=8).map("".join)


@settings(max_examples=300, deadline=None)
@given(any_text | hostile_text)
def test_plain_leaves_no_control_format_separator_or_surrogate(text: str) -> None:
    one_line = plain(text)
    assert banned_in(one_line) == []
    one_line.encode("utf-8")  # no lone surrogate left
    assert banned_in(plain(text, keep_newlines=True), allowed="\n\t") == []
    assert plain(one_line) == one_line  # idempotent: an escaped text is shown as it is
    assert banned_in(markup(text)) == [] and banned_in(markdown(text)) == []


@settings(max_examples=200, deadline=None)
@given(any_text | hostile_text)
def test_markup_renders_as_the_plain_text_inside_rich_markup(text: str) -> None:
    assert Text.from_markup(f"[bold]{markup(text)}[/bold]").plain == plain(text)


def test_the_characters_the_old_hand_list_missed_are_escaped_visibly() -> None:
    assert plain("a\u061cb\u2028c\u2029d\u200be\u2060f\ufeffg") == (
        "a\\u061cb\\u2028c\\u2029d\\u200be\\u2060f\\ufeffg"
    )
    assert plain("\udc80\U000e0001\x85") == "\\udc80\\U000e0001\\x85"
    assert plain("line\n\tnext\r", keep_newlines=True) == "line\n\tnext\\x0d"
    assert plain("tab\tnl\n") == "tab\\x09nl\\x0a"
    assert plain("café [b] 日本 ✓") == "café [b] 日本 ✓"  # printable text is left alone


# ----- scene inspect ----------------------------------------------------------------------------
def hostile_scene(tmp_path: Path) -> Path:
    """The bundled home, its name and first objects' labels (and so names) made of hostile text."""
    data = json.loads(load_bundled_scene("home").model_dump_json())
    data["name"] = "[/]home \x1b]0;pwn\x07 [bold]"
    for i, piece in enumerate(("[/]x", "[bold]b", "\x1b[31mred\x1b[0m", "be\x07ll", "\u202eevil",
                               "l\u2028s", "[/bold]", "tail\\", "a:warning:b")):  # fmt: skip
        obj = data["objects"][i]
        obj["label"] = f"l{i}{piece}"
        obj["name"] = f"{obj['label']}_{obj['idx']}"
    path = tmp_path / "hostile.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    return path


def test_scene_inspect_prints_hostile_names_and_labels_as_data(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-c", "from storyteller.orchestrator.cli.app import app; app()", "scene", "inspect",
         str(hostile_scene(tmp_path))],
        capture_output=True, text=True, encoding="utf-8", timeout=120,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""
    assert banned_in(result.stdout, allowed="\n") == [], result.stdout
    first = result.stdout.splitlines()[0]
    assert first.startswith("[/]home \\x1b]0;pwn\\x07 [bold]: 32 objects"), first
    for shown in ("l0[/]x_1", "l1[bold]b_1", "l2\\x1b[31mred\\x1b[0m", "l3be\\x07ll", "l4\\u202eevil",
                  "l5l\\u2028s", "l6[/bold]_1", "l7tail\\_", "l8a:warning:b"):  # fmt: skip
        assert shown in result.stdout, shown
    assert "l7tail\\\\" not in result.stdout  # the literal label, no doubled backslash


def test_scene_inspect_error_line_from_a_hostile_file_is_one_clean_line(tmp_path: Path) -> None:
    path = hostile_scene(tmp_path)
    data = json.loads(path.read_text(encoding="utf-8"))
    data["objects"][3]["name"] = "l3be\x07ll_99\u202e"  # no longer '<label>_<idx>': a bad file
    path.write_text(json.dumps(data), encoding="utf-8")
    result = CliRunner().invoke(app, ["scene", "inspect", str(path)])
    assert result.exit_code == 2 and result.exception is not None
    assert isinstance(result.exception, SystemExit)  # no traceback
    assert result.stdout == ""
    line = result.stderr
    assert line.startswith("error: ") and line.count("\n") == 1, line
    assert banned_in(line, allowed="\n") == [] and "be\\x07ll" in line, line


# ----- view --export ----------------------------------------------------------------------------
def test_view_export_writes_a_run_whose_activity_holds_a_lone_surrogate(tmp_path: Path) -> None:
    activity = "Ava \udc80 waves \x1b[31m\u202e"  # story.json holds \udc80 as a JSON escape
    folder = write_tiny_run(tmp_path / "run", activity=activity, instruction=activity)
    out = tmp_path / "story.html"
    result = CliRunner().invoke(app, ["view", str(folder), "--export", str(out)])
    assert result.exit_code == 0, result.output
    assert result.exception is None
    html = out.read_text(encoding="utf-8")
    assert "\udc80" not in html and len(html) > 1000

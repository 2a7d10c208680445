"""Text from an LLM or a program is data wherever it is shown: rich markup (``[red]``, ``[/]``),
markdown and HTML, terminal escape sequences and other control characters in names, labels,
activities and error messages are escaped or shown as escapes in

- log lines (structlog, console and JSON rendering): one line, no control character;
- ``story.md``: rendered by a CommonMark renderer with raw HTML on, it holds no tag, link or
  emphasis the model wrote, and no control character;
- the viewer: its panel markdown (viser renders it with raw HTML, unsanitized), its event
  buttons, its 3D labels and caption;
- the lines ``storyteller run`` prints, end to end, from a narrator (the fake OpenAI server)
  whose activity carries all of the above.
"""

from __future__ import annotations

import io
import json
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import structlog
from markdown_it import MarkdownIt
from typer.testing import CliRunner

from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.logging_setup import configure_logging, force_logging_reset
from storyteller.orchestrator.safe_text import markdown, plain
from storyteller.orchestrator.session.run_report import story_markdown
from storyteller.sim.body.skeleton import NUM_JOINTS, heading_to_root
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.files import save_scene_json
from storyteller.sim.world.character_track import CharacterTrack

CONTROL = re.compile("[\x00-\x09\x0b-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")
HOSTILE = "[red]x[/] [/] <img src=x onerror=alert(1)> **bold** [a](javascript:alert(1)) \x1b[31mred\x1b[0m\x07\u202e\r\n# H"
TAGS = re.compile(r"<(?!/?p>)(?!/?h1>)[a-z/][^>]*>")  # any tag but the paragraphs / headings we write


def html_of(md: str) -> str:
    """What a markdown renderer that passes raw HTML through (as viser's does) makes of ``md``."""
    html: str = MarkdownIt("commonmark", {"html": True}).render(md)
    return html


def no_markup_from_the_model(html: str, *, own_bold: int = 0, own_italics: int = 0) -> None:
    """The model's tag, link and emphasis stayed text (the document's own emphasis is counted)."""
    assert "<img" not in html and "<a " not in html, html
    assert html.count("<strong>") == own_bold and html.count("<em>") == own_italics, html
    assert "&lt;img src=x onerror=alert(1)&gt;" in html and "**bold** [a](javascript:alert(1))" in html


# ----- the escaping helpers ---------------------------------------------------------------------
def test_markdown_escape_renders_as_the_literal_text() -> None:
    md = markdown(HOSTILE)
    assert not CONTROL.search(md) and "\n" not in md
    html = html_of(md)
    no_markup_from_the_model(html)
    assert "[red]x[/] [/]" in html and "**bold**" in html and "\\x1b[31mred" in html
    assert html.startswith("<p>") and html.count("<p>") == 1  # one paragraph: the '# H' is no heading


def test_plain_shows_controls_as_escapes_and_keeps_the_rest() -> None:
    assert plain(HOSTILE).startswith("[red]x[/] [/] <img") and not CONTROL.search(plain(HOSTILE))
    assert "\\x1b[31m" in plain(HOSTILE) and "\\u202e" in plain(HOSTILE)


# ----- log lines --------------------------------------------------------------------------------
@pytest.fixture
def log_stream() -> Iterator[io.StringIO]:
    force_logging_reset()
    yield io.StringIO()
    force_logging_reset()


@pytest.mark.parametrize("as_json", [False, True])
def test_a_log_line_carries_model_text_as_data(log_stream: io.StringIO, as_json: bool) -> None:
    configure_logging("INFO", json=as_json, stream=log_stream)
    structlog.get_logger("t").warning("planner_stopped", error=f"ValueError: {HOSTILE}", **{"k\x1b[2J": HOSTILE})
    text = log_stream.getvalue()
    assert text.endswith("\n") and text.count("\n") == 1  # one line
    assert not CONTROL.search(text), repr(text)
    assert "[red]x[/] [/]" in text  # markup stays literal text
    if as_json:
        record = json.loads(text)
        assert record["error"] == f"ValueError: {plain(HOSTILE)}" and record["event"] == "planner_stopped"


# ----- story.md ---------------------------------------------------------------------------------
def test_story_md_escapes_every_model_string() -> None:
    story = {
        "scene": "home", "characters": ["Ava"], "instruction": HOSTILE, "fps": 30, "frames": 90,
        "steps": [{"index": 0, "applied_frame": 3, "kind": "event", "characters": ["Ava"], "activity": HOSTILE,
                   "plans": [{"character": "Ava", "action": HOSTILE, "area": HOSTILE, "position": [1.0, 2.0],
                              "facing": [1.0, 0.0], "seat": HOSTILE}]},
                  {"index": 1, "applied_frame": 60, "kind": "failed", "node": "event_parser", "feedback": HOSTILE}],
        "events": [{"event_id": "event-0000", "index": 0, "characters": ["Ava"], "activity": HOSTILE,
                    "requested_frame": 3, "applied_frame": 3, "state": "failed", "finished_frame": 80,
                    "failure": HOSTILE, "narration": HOSTILE}],
    }  # fmt: skip
    md = story_markdown(story)
    assert not CONTROL.search(md.replace("\n", ""))
    html = html_of(md)
    no_markup_from_the_model(html, own_italics=1)  # the event's id: *(event-0000)*
    assert html.count("<h1>") == 1 and html.count("<h2>") == 1  # the title, what went wrong
    # instruction, the plan sentence's seat and action (no "text": built from the plans), narration,
    # failure, feedback; the narrator's unchecked activity is not shown, the area is no place
    assert html.count("[red]x[/] [/]") == 6


# ----- the viewer -------------------------------------------------------------------------------
def hostile_run_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "run"
    folder.mkdir()
    event = {"event_id": "event-0000", "index": 0, "characters": ["Ava"], "activity": HOSTILE, "text": HOSTILE,
             "requested_frame": 0, "applied_frame": 0, "state": "ongoing", "finished_frame": None, "failure": None}
    story = {"scene": "home", "characters": ["Ava"], "instruction": HOSTILE, "fps": 30, "frames": 20,
             "steps": [], "events": [event]}  # fmt: skip
    (folder / "story.json").write_text(json.dumps(story), encoding="utf-8")
    rot = np.broadcast_to(np.eye(3), (20, NUM_JOINTS, 3, 3)).copy()
    rot[:, 0] = heading_to_root(0.0)
    root = np.column_stack([np.full(20, 1.0), np.full(20, 2.0), np.full(20, 0.92)])
    CharacterTrack(name="Ava", root_positions=root, local_rotations=rot,
                   action_labels=(HOSTILE,) * 20).save(folder / "Ava.track.npz")
    save_scene_json(load_bundled_scene("home"), folder / "scene.json")
    return folder


def test_the_viewer_shows_model_text_as_data(tmp_path: Path) -> None:
    from storyteller.orchestrator.viewer.server import ViewerApp

    viewer = ViewerApp(hostile_run_folder(tmp_path), port=0)
    try:
        assert viewer.reload_if_changed() and viewer.view is not None
        viewer.goto(5)
        panel = viewer.status.content
        assert not CONTROL.search(panel)
        no_markup_from_the_model(html_of(panel), own_bold=1, own_italics=1)  # folder name, instruction
        shown = [b.label for b in viewer._event_buttons] + [viewer.view.labels["Ava"].text, viewer.view.caption.text]
        for text in shown:
            assert not CONTROL.search(text.replace("\n", "")), repr(text)
            assert "[red]x[/] [/] <img src=x onerror=alert(1)>" in text and "\\x1b[31m" in text
        assert viewer.view.caption.text.count("\n") == 1  # the clock, then the one event on
    finally:
        viewer.stop()


# ----- end to end: what `storyteller run` prints and writes -------------------------------------
COFFEE = (
    '```python\ndef parse_event():\n    a = get_character("Ava")\n'
    '    a.set_position(get_area_to_interact_with("coffee_maker_1"))\n'
    '    a.set_orientation("coffee_maker_1")\n    a.set_target_action("use_coffee_maker")\n```'
)


def test_storyteller_run_prints_and_writes_a_hostile_activity_as_data(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FAKE_PROVIDER_KEY", "sk-test-123")
    for var in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL"):
        monkeypatch.delenv(var, raising=False)
    activity = f"make coffee at coffee_maker_1 {HOSTILE}"  # agrees with the plan: story.md shows it
    narration = json.dumps({"reasoning": "r", "event": {"characters": ["Ava"], "activity": activity}})
    out = tmp_path / "out"
    with FakeOpenAI() as fake:
        fake.script["fake-narrator"] = [narration]
        fake.script["fake-parser"] = [COFFEE]
        cfg = tmp_path / "fake.toml"
        cfg.write_text(
            f'[llm]\napi_base = "{fake.base}"\napi_key_env = "FAKE_PROVIDER_KEY"\n[llm.retry]\nmax_attempts = 1\n'
            '[nodes.narrator]\nmodel = "openai/fake-narrator"\n[nodes.event_parser]\nmodel = "openai/fake-parser"\n',
            encoding="utf-8",
        )
        result = CliRunner().invoke(app, ["--log-level", "INFO", "run", "home", "--names", "Ava", "-d", "2",
                                          "--max-events", "1", "--description", "object-list", "--raw-feet",
                                          "--no-interactive", "--config", str(cfg), "--out", str(out)])
    assert result.exit_code == 0, result.stderr
    # the terminal line says what the plan does; the narrator's words are not printed there
    assert "starts: Ava makes coffee at the coffee maker." in result.stdout and "<img" not in result.stdout
    for stream in (result.stdout, result.stderr):
        assert not CONTROL.search(stream), repr(stream)
    html = html_of((out / "story.md").read_text(encoding="utf-8"))
    no_markup_from_the_model(html, own_italics=1)  # the narration, literal text
    assert "make coffee at the coffee maker [red]x[/] [/]" in html
    story = json.loads((out / "story.json").read_text(encoding="utf-8"))
    assert story["events"][0]["activity"] == activity  # the data itself is kept, as JSON

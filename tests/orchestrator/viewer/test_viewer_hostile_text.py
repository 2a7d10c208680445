"""Hostile text through the viewer (issue 22's leftovers): typed in the instruction box, and in the
run files the live page shows.

What is sent: HTML and script (``</script><img src=x onerror=...>``), terminal, bidi and
zero-width controls and a line separator, a lone surrogate (what a websocket client that is not
a browser can put in a string; a browser's encoder replaces it), a megabyte of text, and a
flood of 1,000 instructions from several threads at once (several browsers). What is shown:
``story.json`` event texts, activities and instruction, ``live.json`` planner replies and a
character's activity and place, written hostile into a recorded run's folder.

Targets: nothing runs in the page (``alert`` and ``confirm`` record their calls, and none is
made; no element with an ``onerror`` attribute, no ``img`` pointing at ``x``), hostile text is
shown as its literal characters with every control as a visible escape, text over the limit is
refused with its reason under the box, the instruction file stays one well-formed JSON line per
instruction sent and nothing else, and the viewer keeps serving. The browser is headless
Chromium (``benchmark/support/headless_chromium.py``); the unit tests drive
:class:`~storyteller.orchestrator.viewer.server.ViewerApp` directly.
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, cast

import pytest

from storyteller.benchmark.support.headless_chromium import Chromium, chromium_binary
from storyteller.orchestrator.safe_text import markdown
from storyteller.orchestrator.session.instruction_script import MAX_INSTRUCTION_CHARS
from storyteller.orchestrator.session.run_manifest import RunArguments, RunManifest, write_manifest
from storyteller.orchestrator.session.viewer_instructions import INBOX_FILE, InstructionInbox, ViewerInstruction
from storyteller.orchestrator.viewer.server import InstructionRefused, ViewerApp
from tests.support.story_planner import interact_program, recorded_home_run

THREAD = "run-0123456789ab@unified+object-list"
SCRIPT = "</script><img src=x onerror=alert(1)><script>alert(2)</script>"
CONTROLS = "\u202e\u2066\x1b[31m\x07\u200b\u2028"
CONTROL_CHARS = "\u202e\u2066\x1b\x07\u200b\u2028"  # the characters of CONTROLS that must never be shown raw
MEGABYTE = "A" * (1 << 20)
needs_chromium = pytest.mark.skipif(chromium_binary() is None, reason="chromium not installed (apt-get install chromium)")


def _manifest(folder: Path) -> None:
    folder.mkdir(exist_ok=True)
    args = RunArguments(scene="home", names=("Zoe", "Max"), duration=20.0)
    write_manifest(folder, RunManifest(thread_id=THREAD, scene_name="home", seed=0, config=None, arguments=args))


def _inbox_lines(folder: Path) -> list[dict[str, Any]]:
    """Every line of the instruction file, each parsed as the run parses it (fails on any other)."""
    raw = (folder / INBOX_FILE).read_bytes() if (folder / INBOX_FILE).exists() else b""
    assert raw == b"" or raw.endswith(b"\n")
    lines = raw.splitlines()
    for line in lines:
        ViewerInstruction.model_validate_json(line)
        line.decode("ascii")  # ASCII escapes only: no raw control, bidi or separator byte in the file
    return [json.loads(line) for line in lines]


@pytest.fixture
def viewer(tmp_path: Path) -> Iterator[ViewerApp]:
    _manifest(tmp_path / "run")
    app = ViewerApp(tmp_path / "run", port=0)
    yield app
    app.stop()


# ----- the box, without a browser ----------------------------------------------------------
def test_hostile_instructions_are_sent_as_data_or_refused_with_a_reason(viewer: ViewerApp) -> None:
    box = viewer.server.gui.add_text("Instruction", "")
    note = viewer.server.gui.add_markdown("")
    for typed in (f"Ben waves {SCRIPT}", f"Ben sits {CONTROLS} down"):
        cast(Any, box).value = typed  # viser declares the setter on a subclass mypy does not see
        viewer._send(box, note)
        assert note.content.startswith("Sent:"), note.content
        assert "<" not in note.content.replace("\\<", "")  # every tag character escaped
        assert not any(c in note.content for c in CONTROL_CHARS)  # shown as escapes (\u202e ...)
    for typed, reason in ((MEGABYTE, f"at most {MAX_INSTRUCTION_CHARS}"), ("Ben \ud800 waves", "not text")):
        cast(Any, box).value = typed  # viser declares the setter on a subclass mypy does not see
        viewer._send(box, note)  # a lone surrogate was a pydantic ValidationError out of the callback
        assert note.content.startswith("**Not sent:**") and markdown(reason) in note.content, note.content
        assert box.value == typed  # kept, to correct
    sent = _inbox_lines(viewer.folder)
    assert [s["text"] for s in sent] == [f"Ben waves {SCRIPT}", " ".join(f"Ben sits {CONTROLS} down".split())]
    assert [i.text for i in InstructionInbox(viewer.folder / INBOX_FILE, THREAD).poll()] == [s["text"] for s in sent]


def test_a_flood_of_1000_instructions_from_several_browsers_is_1000_whole_lines(viewer: ViewerApp) -> None:
    texts = [f"step {i}: {SCRIPT if i % 2 else CONTROLS} {'x' * (i % 300)}" for i in range(1000)]
    with ThreadPoolExecutor(max_workers=8) as pool:
        list(pool.map(viewer.send_instruction, texts))
    sent = _inbox_lines(viewer.folder)
    assert len(sent) == 1000 and len({s["id"] for s in sent}) == 1000
    expected = sorted(" ".join(t.split()) for t in texts)
    assert sorted(s["text"] for s in sent) == expected
    assert len(InstructionInbox(viewer.folder / INBOX_FILE, THREAD).poll()) == 1000
    (viewer.folder / "story.json").write_text("{}", encoding="utf-8")
    with pytest.raises(InstructionRefused, match="ended"):
        viewer.send_instruction("one more")
    assert len(_inbox_lines(viewer.folder)) == 1000


# ----- in the browser ----------------------------------------------------------------------
TRAPS = (  # before any script of the page: alert, confirm and prompt record their calls instead of
    # opening a dialog
    "window.__calls = []; for (const f of ['alert', 'confirm', 'prompt'])"
    " window[f] = (...a) => { window.__calls.push([f, ...a.map(String)]); };"
)
INJECTED = (  # what an injection would have added to the page, as HTML
    "[...document.querySelectorAll('[onerror], iframe, object, embed'), ...[...document.scripts].filter(e => e.textContent.includes('alert(')),"
    " ...[...document.images].filter(i => (i.getAttribute('src') || '') === 'x')].map(e => e.outerHTML.slice(0, 300))"
)
FOCUS_BOX = (
    "(() => { const label = [...document.querySelectorAll('label')].find(l => l.innerText.trim() === 'Instruction');"
    " let row = label; while (row && !row.querySelector('input.mantine-TextInput-input')) row = row.parentElement;"
    " const box = row.querySelector('input.mantine-TextInput-input'); box.focus(); box.select(); return true; })()"
)


def _text(browser: Chromium) -> str:
    return str(browser.evaluate("document.body.innerText"))


def _wait_page(browser: Chromium, what: str, js: str, timeout_s: float = 60) -> None:
    try:
        browser.wait_for(js, timeout_s=timeout_s)
    except TimeoutError:
        raise AssertionError(f"{what}; the page says: {_text(browser)[-3000:]}") from None


def _open(browser: Chromium, url: str) -> None:
    browser.call("Page.enable")  # its events are dropped by Chromium.call
    browser.call("Page.addScriptToEvaluateOnNewDocument", source=TRAPS)
    browser.navigate(url)
    _wait_page(browser, "no instruction box", "document.body.innerText.includes('Direct the story')")
    assert browser.evaluate("window.__calls") == []  # the traps are set


def _type_and_send(browser: Chromium, text: str) -> None:
    browser.evaluate(FOCUS_BOX)
    browser.call("Input.insertText", text=text)
    time.sleep(0.6)  # the page sends the field's value at most every 50 ms
    browser.evaluate("[...document.querySelectorAll('button')].find(b => b.innerText.trim() === 'Send').click()")


def _nothing_ran(browser: Chromium) -> None:
    assert browser.evaluate("window.__calls") == [], "a dialog was asked for"
    assert browser.evaluate(INJECTED) == [], "an element was injected"
    shown = _text(browser)
    assert not any(c in shown for c in CONTROL_CHARS), "a control character reached the page"


@needs_chromium
@pytest.mark.slow
def test_hostile_text_typed_in_the_box_is_shown_as_text_and_nothing_runs(viewer: ViewerApp, tmp_path: Path) -> None:
    viewer.start()
    (tmp_path / "profile").mkdir()
    with Chromium(tmp_path / "profile") as browser:
        _open(browser, viewer.url)
        _type_and_send(browser, f"Ben waves {SCRIPT}")
        _wait_page(browser, "not sent", f"document.body.innerText.includes({json.dumps('Sent: Ben waves ' + SCRIPT)})", 30)
        _type_and_send(browser, f"Ben sits {CONTROLS} down")
        _wait_page(browser, "controls not shown as escapes", "document.body.innerText.includes('\\\\u202e\\\\u2066\\\\x1b[31m')", 30)
        _nothing_ran(browser)
        _type_and_send(browser, MEGABYTE)
        _wait_page(browser, "the megabyte not refused", f"document.body.innerText.includes('at most {MAX_INSTRUCTION_CHARS}')", 60)
        _type_and_send(browser, "Ben sits after the megabyte")  # the page and its websocket still work
        _wait_page(browser, "the connection lost", "document.body.innerText.includes('Sent: Ben sits after the megabyte')", 30)
        _nothing_ran(browser)
    texts = [s["text"] for s in _inbox_lines(viewer.folder)]
    assert texts == [f"Ben waves {SCRIPT}", " ".join(f"Ben sits {CONTROLS} down".split()), "Ben sits after the megabyte"]


HOSTILE = f"{SCRIPT} *bold* [link](javascript:alert(3)) {CONTROLS} &lt;b&gt;"


@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 6-second run of two characters in ``home`` with one planned event."""
    tmp = tmp_path_factory.mktemp("hostile-view")
    return recorded_home_run(tmp, [interact_program("Ava", "coffee_maker_1", "use_coffee_maker")], seconds=6, max_events=1)


def _poison(run: Path, folder: Path) -> None:
    """A copy of ``run`` whose story and live state carry hostile text."""
    shutil.copytree(run, folder)
    story = json.loads((folder / "story.json").read_text(encoding="utf-8"))
    story["instruction"] = f"instruction {HOSTILE}"
    for event in story["events"]:
        event.update(text=f"event text {HOSTILE}", activity=f"activity {HOSTILE}")
    (folder / "story.json").write_text(json.dumps(story), encoding="utf-8")
    live = json.loads((folder / "live.json").read_text(encoding="utf-8"))
    for role in live["roles"]:
        role["last_reply"] = f"reply {HOSTILE}\n```python\n{SCRIPT}\n```"
    for character in live["characters"]:
        character.update(activity=f"doing {HOSTILE}", place=f"at {HOSTILE}")
    (folder / "live.json").write_text(json.dumps(live), encoding="utf-8")


@needs_chromium
@pytest.mark.slow
def test_hostile_text_in_the_run_files_is_shown_as_text_and_nothing_runs(recorded_run: Path, tmp_path: Path) -> None:
    folder = tmp_path / "poisoned"
    _poison(recorded_run, folder)
    viewer = ViewerApp(folder, port=0)
    viewer.start()
    (tmp_path / "profile").mkdir()
    try:
        with Chromium(tmp_path / "profile") as browser:
            _open(browser, viewer.url)
            _wait_page(browser, "no event text", "document.body.innerText.includes('event text </script><img')")
            _wait_page(browser, "no planner reply", "document.body.innerText.includes('reply </script><img')", 30)
            browser.evaluate("[...document.querySelectorAll('button')].find(b => b.innerText.trim() === 'Ava').click()")
            _wait_page(browser, "no character panel", "document.body.innerText.includes('doing </script><img')", 30)
            shown = _text(browser)
            assert f"instruction {SCRIPT} *bold* [link](javascript:alert(3))" in shown
            assert "&lt;b&gt;" in shown  # an entity is shown as typed, not decoded
            assert "\\u202e\\u2066\\x1b[31m\\x07\\u200b\\u2028" in shown
            assert browser.evaluate("document.querySelectorAll('a[href^=\"javascript\"]').length") == 0  # no link
            assert not browser.evaluate("[...document.querySelectorAll('strong, em')].some(s => s.innerText.trim() === 'bold')")
            _nothing_ran(browser)
            time.sleep(1.0)  # a late script or image error would record its call by now
            _nothing_ran(browser)
            assert viewer.server.get_clients()  # still connected
    finally:
        viewer.stop()


def test_a_hostile_live_json_is_one_note_and_the_panels_stay(tmp_path: Path) -> None:
    _manifest(tmp_path / "run")
    (tmp_path / "run" / "live.json").write_bytes(b'{"thread": "\xff\xfe\x1b[31m' + b"[" * 100_000 + b"}")
    app = ViewerApp(tmp_path / "run", port=0)
    try:
        app.panels.poll_live()  # not UTF-8, deep, malformed: refused by the bounded reader, said in the note
        note = app.panels.note.content
        assert markdown("live.json") in note and "\n" not in note, note
        assert not any(c in note for c in CONTROL_CHARS), note
        assert app.panels.live is None and app.panels.run_status.content.startswith("**Run**")
    finally:
        app.stop()


def test_a_huge_live_json_is_refused_unread(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Found by the hostile corpus: a sparse 3 GB live.json was read whole (``Path.read_bytes``)
    by every poll of ``storyteller view`` (4.2 GB RSS); now its size is refused and said in the note."""
    _manifest(tmp_path / "run")
    with open(tmp_path / "run" / "live.json", "wb") as f:
        f.truncate(3 << 30)  # sparse: nothing on disk
    app = ViewerApp(tmp_path / "run", port=0)
    try:

        def read_whole(self: Path) -> bytes:
            raise AssertionError(f"{self} read whole")

        monkeypatch.setattr(Path, "read_bytes", read_whole)
        app.panels.poll_live()
        monkeypatch.undo()
        assert "more than" in app.panels.note.content and app.panels.live is None, app.panels.note.content
    finally:
        app.stop()

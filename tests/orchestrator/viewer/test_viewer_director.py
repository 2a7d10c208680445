"""Directing a live story from the browser: the viewer's instruction box and its channel to the run.

The channel is ``viewer_instructions.jsonl`` in the run folder
(``storyteller.orchestrator.session.viewer_instructions``): the unit tests write and read it directly (order,
ids applied once, other runs' lines, torn, malformed, oversized and linked files) and drive
:meth:`ViewerApp.send_instruction` for its refusals. The command-line tests run ``storyteller
run`` against the fake OpenAI server with a planner that follows the instruction
(``tests/support/directed_planner.py``): lines put in the file reach the story as ``viewer``
instructions and a replay reproduces it. The browser tests type into the box of a live ``run
--view``, and into a ``view`` process that is killed and started again while the run is killed
and resumed, in headless Chromium; their screenshots go to ``$STORYTELLER_TEST_OUTPUT/viewer/``
(else the test's temporary folder).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.benchmark.support.headless_chromium import Chromium, chromium_binary
from storyteller.orchestrator.llm.traces import read_trace
from storyteller.orchestrator.session.instruction_script import MAX_INSTRUCTION_CHARS
from storyteller.orchestrator.session.run_manifest import RunArguments, RunManifest, write_manifest
from storyteller.orchestrator.session.viewer_instructions import (
    INBOX_FILE,
    MAX_LINE_BYTES,
    InstructionInbox,
    ViewerInstruction,
    send_instruction,
)
from storyteller.orchestrator.viewer.server import InstructionRefused, ViewerApp
from tests.support.directed_planner import TOAST, TOASTER, directed
from tests.support.story_planner import RUN, write_config

THREAD = "run-0123456789ab@unified+object-list"


def _line(text: str, *, thread: str = THREAD, id_: str = "a" * 32) -> bytes:
    record = {"id": id_, "thread": thread, "text": text, "sent_unix": 1.0}
    return (json.dumps(record) + "\n").encode()


# ----- the file ---------------------------------------------------------------------------
def test_lines_are_read_once_in_order_and_only_for_this_run(tmp_path: Path) -> None:
    first = send_instruction(tmp_path, THREAD, "  Ben   waves\n at Ava ", sent_unix=1.0)
    inbox = InstructionInbox(tmp_path / INBOX_FILE, THREAD)
    assert [i.text for i in inbox.poll()] == ["Ben waves at Ava"]
    assert inbox.poll() == []  # read from its last offset: nothing new
    with (tmp_path / INBOX_FILE).open("ab") as f:
        f.write(_line("an earlier run's line", thread="run-old"))
        f.write(_line("the same line again", id_=first.id))  # a writer that sent it twice
        f.write(b'{"id": 1, "text": "not a line"}\n')
        f.write(b"\xff\xfe not JSON\n")
        f.write(_line("Ava sits down", id_="b" * 32))
        f.write(_line("Ava stands", id_="c" * 32)[:-10])  # a write in progress: no newline yet
    assert [i.text for i in inbox.poll()] == ["Ava sits down"]
    with (tmp_path / INBOX_FILE).open("ab") as f:
        f.write(_line("Ava stands", id_="c" * 32)[-10:])
    assert [i.text for i in inbox.poll()] == ["Ava stands"]
    # a second reader (a resumed run) reads the file from its start and skips what the trace has
    again = InstructionInbox(tmp_path / INBOX_FILE, THREAD, applied=["Ben waves at Ava"])
    assert [i.text for i in again.poll()] == ["Ava sits down", "Ava stands"]


def test_a_line_too_long_is_skipped_in_pieces_and_the_next_one_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import storyteller.orchestrator.session.viewer_instructions as channel

    monkeypatch.setattr(channel, "READ_BYTES", 4096)  # the long line arrives over several polls
    monkeypatch.setattr(channel, "MAX_LINE_BYTES", 1024)
    path = tmp_path / INBOX_FILE
    inbox = InstructionInbox(path, THREAD)
    with path.open("ab") as f:
        f.write(_line("Ben waves") + b'{"id": "' + b"x" * 40_000)
    assert [i.text for i in inbox.poll()] == ["Ben waves"]
    for _ in range(40_000 // 4096 + 2):
        assert inbox.poll() == []
    assert inbox.offset == path.stat().st_size  # read past, not held
    with path.open("ab") as f:
        f.write(b'"}\n' + _line("Ben reads", id_="b" * 32))
    assert [i.text for i in inbox.poll()] == ["Ben reads"]


def test_a_link_or_a_fifo_in_place_of_the_file_is_neither_read_nor_written_through(tmp_path: Path) -> None:
    outside = tmp_path / "outside.jsonl"
    outside.write_bytes(_line("planted"))
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / INBOX_FILE).symlink_to(outside)
    assert InstructionInbox(folder / INBOX_FILE, THREAD).poll() == []
    with pytest.raises(OSError, match="symbolic link"):
        send_instruction(folder, THREAD, "Ben waves", sent_unix=1.0)
    assert outside.read_bytes() == _line("planted")
    (folder / INBOX_FILE).unlink()
    os.mkfifo(folder / INBOX_FILE)
    assert InstructionInbox(folder / INBOX_FILE, THREAD).poll() == []  # opened without blocking, not read
    with pytest.raises(OSError, match="regular file"):
        send_instruction(folder, THREAD, "Ben waves", sent_unix=1.0)


def test_empty_and_overlong_instructions_are_refused_before_writing(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="empty"):
        send_instruction(tmp_path, THREAD, " \n\t", sent_unix=1.0)
    with pytest.raises(ValueError, match=f"at most {MAX_INSTRUCTION_CHARS}"):
        send_instruction(tmp_path, THREAD, "a" * (MAX_INSTRUCTION_CHARS + 1), sent_unix=1.0)
    assert not (tmp_path / INBOX_FILE).exists()
    longest = send_instruction(tmp_path, THREAD, "\U0001f600" * MAX_INSTRUCTION_CHARS, sent_unix=1.0)
    assert len((tmp_path / INBOX_FILE).read_bytes()) <= MAX_LINE_BYTES  # the worst escaping fits a line
    assert InstructionInbox(tmp_path / INBOX_FILE, THREAD).poll() == [longest]
    with pytest.raises(ValueError):
        ViewerInstruction.model_validate({"id": "z" * 32, "thread": THREAD, "text": "x", "sent_unix": 1.0})


class _World:
    frame = 0


class _Session:
    """What the reader thread uses of a session: its world's frame and ``instruct_nowait``."""

    def __init__(self) -> None:
        self.world = _World()
        self.said: list[tuple[int, str, str]] = []

    def instruct_nowait(self, text: str, source: str = "stdin") -> bool:
        self.said.append((self.world.frame, text, source))
        return True


def test_a_resumed_run_holds_new_lines_until_it_is_past_its_last_recorded_instruction(tmp_path: Path) -> None:
    import threading

    from storyteller.orchestrator.session.viewer_instructions import start_inbox_reader

    send_instruction(tmp_path, THREAD, "Zoe waves", sent_unix=1.0)  # applied at frame 120 before a kill
    send_instruction(tmp_path, THREAD, "Max makes toast", sent_unix=2.0)  # sent while the run was down
    session, stop = _Session(), threading.Event()
    reader = start_inbox_reader(session, tmp_path / INBOX_FILE, THREAD, ["Zoe waves"], stop=stop,
                                after_frame=120)
    try:
        time.sleep(0.5)
        assert session.said == []  # the resume replays frames up to 120, where "Zoe waves" comes again
        session.world.frame = 121
        _wait("the held line", lambda: session.said, timeout_s=10)
        assert session.said == [(121, "Max makes toast", "viewer")]
    finally:
        stop.set()
        reader.join(timeout=5)


# ----- the viewer's side ------------------------------------------------------------------

def _manifest(folder: Path) -> None:
    folder.mkdir(exist_ok=True)
    args = RunArguments(scene="home", names=("Zoe", "Max"), duration=20.0)
    write_manifest(folder, RunManifest(thread_id=THREAD, scene_name="home", seed=0, config=None, arguments=args))


def test_the_viewer_sends_to_a_live_run_and_says_why_it_does_not(tmp_path: Path, viewer: ViewerApp) -> None:
    folder = tmp_path / "run"
    with pytest.raises(InstructionRefused, match="not started"):
        viewer.send_instruction("Ben waves")
    _manifest(folder)
    with pytest.raises(InstructionRefused, match="empty"):
        viewer.send_instruction("   ")
    with pytest.raises(InstructionRefused, match="at most"):
        viewer.send_instruction("x" * (MAX_INSTRUCTION_CHARS + 1))
    sent = viewer.send_instruction("Ben waves <img src=x onerror=alert(1)> *now*")
    assert InstructionInbox(folder / INBOX_FILE, THREAD).poll() == [sent]
    (folder / "story.json").write_text("{}", encoding="utf-8")  # the run has ended
    with pytest.raises(InstructionRefused, match="ended"):
        viewer.send_instruction("Ben sits")
    assert len(InstructionInbox(folder / INBOX_FILE, THREAD).poll()) == 1


def test_the_note_under_the_box_shows_typed_text_as_data(tmp_path: Path, viewer: ViewerApp) -> None:
    from storyteller.orchestrator.safe_text import markdown

    _manifest(tmp_path / "run")
    box = viewer.server.gui.add_text("Instruction", "Ben waves <img src=x onerror=alert(1)> *now*")
    note = viewer.server.gui.add_markdown("")
    viewer._send(box, note)
    assert markdown("<img src=x onerror=alert(1)> *now*") in note.content
    assert "<" not in note.content.replace("\\<", "")  # every tag character escaped (text, not markup)
    assert box.value == ""  # sent: the box is empty again
    box.value = "x" * (MAX_INSTRUCTION_CHARS + 5)  # type: ignore[misc]  # viser's setter
    viewer._send(box, note)
    assert note.content.startswith("**Not sent:**") and box.value  # kept, to shorten


# ----- the run's side -----------------------------------------------------------------------
def _cli(*args: str) -> list[str]:
    return [sys.executable, "-c", "from storyteller.orchestrator.cli.app import app; app()", *args]


def _env(tmp_path: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL", "STORYTELLER_PLANNER_MODEL")}  # fmt: skip
    env.update(FAKE_PROVIDER_KEY="sk-test-123", STORYTELLER_CACHE_DIR=str(tmp_path / "cache"))
    return env


def _wait(what: str, ok: Callable[[], object], *, timeout_s: float, log: Path | None = None) -> None:
    """Poll ``ok()`` every 0.2 s until it is true (a failure names ``what`` and the log's tail)."""
    deadline = time.monotonic() + timeout_s
    while not ok():
        tail = log.read_text(errors="replace")[-3000:] if log is not None and log.exists() else ""
        assert time.monotonic() < deadline, f"{what}: not within {timeout_s} s\n{tail}"
        time.sleep(0.2)


def _viewer_instructions(run: Path) -> list[tuple[int, str, str]]:
    return [(r.sim_frame, r.source, r.text) for r in read_trace(run / "trace.jsonl").instructions()]


def _toast_events(run: Path, after: int) -> list[dict[str, Any]]:
    """The events of ``story.json`` in which Max uses the toaster, applied after frame ``after``."""
    story = json.loads((run / "story.json").read_text(encoding="utf-8"))
    toasting = {s["index"] for s in story["steps"] if s["kind"] == "event"
                and any((p["character"], p["action"]) == ("Max", TOASTER[1]) for p in s["plans"])}  # fmt: skip
    return [e for e in story["events"] if e["index"] in toasting and e["applied_frame"] > after]


def _same_story(run: Path, again: Path) -> None:
    for name in ("story.json", "story.md", "Zoe.track.npz", "Max.track.npz"):
        assert (again / name).read_bytes() == (run / name).read_bytes(), name


@pytest.mark.slow
def test_lines_in_the_file_become_viewer_instructions_and_a_replay_repeats_them(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    thread = "directed@unified+object-list"  # run --thread-id directed: the lines can be there first
    with (out / INBOX_FILE).open("wb") as f:
        f.write(_line("an earlier run's line", thread="another@unified+object-list"))
        f.write(_line(TOAST, thread=thread, id_="d" * 32))
        f.write(_line(TOAST, thread=thread, id_="d" * 32))  # the same line twice: applied once
    log = tmp_path / "run.log"
    with FakeOpenAI(responder=directed) as fake:
        cfg = write_config(tmp_path, fake.base)
        with log.open("w") as sink:
            code = subprocess.call(_cli(*RUN, "-d", "20", "--thread-id", "directed", "--config", str(cfg),
                                        "--out", str(out)), env=_env(tmp_path), stdout=sink, stderr=subprocess.STDOUT)  # fmt: skip
        assert code == 0, log.read_text()
    ((frame, source, text),) = _viewer_instructions(out)
    assert (source, text) == ("viewer", TOAST)
    story = json.loads((out / "story.json").read_text(encoding="utf-8"))
    assert story["instructions"] == [{"frame": frame, "time_s": round(frame / 30, 3), "source": "viewer", "text": TOAST}]
    assert _toast_events(out, frame), "no event for the instruction"
    again = tmp_path / "again"
    with log.open("w") as sink:  # no provider: the trace serves every call
        code = subprocess.call(_cli("replay", str(out), "--out", str(again)), env=_env(tmp_path), stdout=sink,
                               stderr=subprocess.STDOUT)
    assert code == 0, log.read_text()
    _same_story(out, again)
    assert _viewer_instructions(again) == _viewer_instructions(out)


# ----- in the browser -----------------------------------------------------------------------
needs_chromium = pytest.mark.skipif(chromium_binary() is None, reason="chromium not installed (apt-get install chromium)")



def _url(log: Path, proc: subprocess.Popen[bytes]) -> str:
    import re

    found: list[str] = []

    def seen() -> bool:
        assert proc.poll() is None, log.read_text()
        found[:] = re.findall(r"viewing .* at (http://127\.0\.0\.1:\d+)", log.read_text())
        return bool(found)

    _wait("the viewer's address", seen, timeout_s=120, log=log)
    return found[-1]


def _type_instruction(browser: Chromium, text: str) -> None:
    """Type ``text`` into the box as a person does (focus, keys), then press Send."""
    browser.wait_for("document.body.innerText.includes('Direct the story')")
    browser.wait_for("[...document.querySelectorAll('label')].some(l => l.innerText.trim() === 'Instruction')")
    _type_and_send(browser, text)
    try:
        browser.wait_for(f"document.body.innerText.includes('Sent: ' + {json.dumps(text)})", timeout_s=30)
    except TimeoutError:
        raise AssertionError(f"not sent; the page says: {browser.evaluate('document.body.innerText')}") from None


def _wait_live(browser: Chromium) -> None:
    """Until the page shows a run in progress (what it says otherwise in the failure)."""
    try:
        browser.wait_for("document.body.innerText.includes('the run is still going')", timeout_s=120)
    except TimeoutError:
        raise AssertionError(f"no live run; the page says: {browser.evaluate('document.body.innerText')}") from None


FOCUS_BOX = (  # the text field next to the label 'Instruction' (viser's label does not point at it)
    "(() => { const label = [...document.querySelectorAll('label')].find(l => l.innerText.trim() === 'Instruction');"
    " let row = label; while (row && !row.querySelector('input.mantine-TextInput-input')) row = row.parentElement;"
    " row.querySelector('input.mantine-TextInput-input').focus(); return true; })()"
)


def _type_and_send(browser: Chromium, text: str) -> None:
    browser.evaluate(FOCUS_BOX)
    browser.call("Input.insertText", text=text)
    time.sleep(0.5)  # the page sends the field's value at most every 50 ms
    browser.evaluate("[...document.querySelectorAll('button')].find(b => b.innerText.trim() === 'Send').click()")


@needs_chromium
@pytest.mark.slow
def test_an_instruction_typed_in_the_box_of_run_view_directs_the_story(tmp_path: Path, shots: Path) -> None:
    out, log = tmp_path / "run", tmp_path / "run.log"
    with FakeOpenAI(responder=directed) as fake:
        cfg = write_config(tmp_path, fake.base)
        args = [*RUN, "-d", "60", "--pace", "realtime", "--speed", "2", "--config", str(cfg), "--out", str(out),
                "--view", "--port", "0"]  # fmt: skip
        with log.open("w") as sink:
            run = subprocess.Popen(_cli(*args), env=_env(tmp_path), stdout=sink, stderr=subprocess.STDOUT)
        (tmp_path / "profile").mkdir()
        try:
            with Chromium(tmp_path / "profile") as browser:
                browser.navigate(_url(log, run))
                _wait_live(browser)
                _type_instruction(browser, TOAST)
                browser.screenshot(shots / "director-sent.png")
                _wait("the instruction in the trace", lambda: (out / "trace.jsonl").is_file() and any(
                    s == "viewer" for _, s, _ in _viewer_instructions(out)), timeout_s=30, log=log)
                _wait("the story's end", lambda: "the story has ended" in log.read_text(), timeout_s=240, log=log)
                assert run.poll() is None, "the viewer stopped with the story"
                _type_instruction_refused(browser, "Max makes more toast")
                browser.screenshot(shots / "director-ended.png")
            run.send_signal(signal.SIGINT)
            assert run.wait(timeout=60) == 0, log.read_text()
        finally:
            if run.poll() is None:
                run.kill()
                run.wait()
    ((frame, source, text),) = _viewer_instructions(out)
    assert (source, text) == ("viewer", TOAST)
    story = json.loads((out / "story.json").read_text(encoding="utf-8"))
    assert [(i["frame"], i["source"], i["text"]) for i in story["instructions"]] == [(frame, "viewer", TOAST)]
    assert _toast_events(out, frame), "no event for the instruction"
    assert f"instruction (viewer): {TOAST}" in log.read_text()
    again = tmp_path / "again"
    with log.open("w") as sink:
        code = subprocess.call(_cli("replay", str(out), "--out", str(again)), env=_env(tmp_path), stdout=sink,
                               stderr=subprocess.STDOUT)
    assert code == 0, log.read_text()
    _same_story(out, again)
    print(f"screenshots: {shots / 'director-sent.png'} {shots / 'director-ended.png'}")


def _type_instruction_refused(browser: Chromium, text: str) -> None:
    _type_and_send(browser, text)
    browser.wait_for("document.body.innerText.includes('Not sent:') && document.body.innerText.includes('ended')",
                     timeout_s=30)


@needs_chromium
@pytest.mark.slow
def test_nothing_sent_is_lost_when_the_view_and_the_run_are_killed_and_started_again(tmp_path: Path, shots: Path) -> None:
    out, log, view_log = tmp_path / "run", tmp_path / "run.log", tmp_path / "view.log"
    waves = "Zoe waves at Max"
    procs: list[subprocess.Popen[bytes]] = []

    def start(args: list[str], sink: Path) -> subprocess.Popen[bytes]:
        with sink.open("a") as f:
            proc = subprocess.Popen(_cli(*args), env=_env(tmp_path), stdout=f, stderr=subprocess.STDOUT)
        procs.append(proc)
        return proc

    def kill(proc: subprocess.Popen[bytes]) -> None:
        proc.kill()  # SIGKILL: no clean-up of any kind
        proc.wait()

    with FakeOpenAI(responder=directed) as fake:
        cfg = write_config(tmp_path, fake.base)
        # 120 s of story at twice real time: a minute of wall time, so a busy machine's slow browser start
        # cannot let the run end before the kill (it did with 40 s at load 5: the second line was refused)
        run = start([*RUN, "-d", "120", "--pace", "realtime", "--speed", "2", "--config", str(cfg), "--out", str(out)], log)
        view = start(["view", str(out), "--port", "0"], view_log)
        (tmp_path / "profile").mkdir()
        try:
            with Chromium(tmp_path / "profile") as browser:
                browser.navigate(_url(view_log, view))
                _wait_live(browser)
                _type_instruction(browser, waves)
                _wait("the first instruction in the trace", lambda: any(
                    t == waves for _, _, t in _viewer_instructions(out)), timeout_s=30, log=log)
                kill(view)
                kill(run)  # both gone: the run resumes from its last checkpoint
                view_log = tmp_path / "view-again.log"
                view = start(["view", str(out), "--port", "0"], view_log)
                browser.navigate(_url(view_log, view))
                _wait_live(browser)
                _type_instruction(browser, TOAST)  # the run is not there: the line waits in the file
                browser.screenshot(shots / "director-restarted.png")
                kill(view)
            resumed = start(["resume", str(out), "--no-interactive"], log)
            assert resumed.wait(timeout=300) == 0, log.read_text()[-3000:]
        finally:
            for proc in procs:
                if proc.poll() is None:
                    kill(proc)
    said = _viewer_instructions(out)
    assert [(s, t) for _, s, t in said] == [("viewer", waves), ("viewer", TOAST)], said  # each once, in order
    story = json.loads((out / "story.json").read_text(encoding="utf-8"))
    assert [(i["frame"], i["source"], i["text"]) for i in story["instructions"]] == said
    assert _toast_events(out, said[1][0]), "no event for the instruction sent while the run was down"
    again = tmp_path / "again"
    with log.open("a") as sink:
        code = subprocess.call(_cli("replay", str(out), "--out", str(again)), env=_env(tmp_path), stdout=sink,
                               stderr=subprocess.STDOUT)
    assert code == 0, log.read_text()[-3000:]
    _same_story(out, again)


# ----- run --view: the viewer's process -------------------------------------------------------
@pytest.mark.slow
def test_run_view_on_an_address_it_cannot_listen_on_is_one_error_line(tmp_path: Path) -> None:
    result = subprocess.run(_cli(*RUN, "-d", "5", "--out", str(tmp_path / "run"), "--view", "--port", "0", "--host",
                                 "203.0.113.9"), env=_env(tmp_path), capture_output=True, text=True, timeout=300)  # fmt: skip
    assert result.returncode == 2, result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in result.stderr, result.stderr
    assert "--view" in errors[0] and "203.0.113.9" in errors[0] and "cannot listen" in errors[0]
    assert not (tmp_path / "run" / "run.json").exists()  # refused before the story started


@pytest.mark.slow
def test_the_viewer_process_ends_when_the_run_that_started_it_is_killed(tmp_path: Path) -> None:
    script = ("import sys, time; from pathlib import Path; from storyteller.orchestrator.viewer.child import spawn_viewer; "
              "v = spawn_viewer(Path(sys.argv[1]), port=0, host='127.0.0.1'); print(v.proc.pid, flush=True); "
              "time.sleep(600)")  # fmt: skip
    parent = subprocess.Popen([sys.executable, "-c", script, str(tmp_path / "run")], env=_env(tmp_path),
                              stdout=subprocess.PIPE, text=True)
    try:
        assert parent.stdout is not None
        child = int(parent.stdout.readline())
        os.kill(child, 0)  # serving
        parent.kill()  # SIGKILL: the parent cleans nothing up
        parent.wait()

        def gone() -> bool:
            try:
                os.kill(child, 0)
            except ProcessLookupError:
                return True
            with open(f"/proc/{child}/stat") as f:  # exited, not yet reaped by init: a zombie is gone too
                return f.read().split(") ", 1)[1].startswith("Z")

        _wait("the viewer's end", gone, timeout_s=30)
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        if parent.stdout is not None:
            parent.stdout.close()

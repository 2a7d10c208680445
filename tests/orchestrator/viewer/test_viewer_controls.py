"""A director's controls: pause, resume and speed of a realtime run, the planner, characters, story.

The channel is ``viewer_controls.jsonl`` (``storyteller.orchestrator.session.viewer_controls``) and the run's
state for the viewer is ``live.json`` (``storyteller.orchestrator.session.live_state``). Unit tests: the
file's lines (ids once, other runs' lines, malformed lines), the fold into pause and speed, the
hold at a frame boundary, the panels' text escaped. Command-line tests run ``storyteller run``
against the fake OpenAI server (``tests/support/directed_planner.py``, each reply a second late,
so steps are in flight while the run is paused): a paused run's frame stays where it is, an
instruction sent while paused takes effect at the frame the run resumes at, and ``storyteller
replay`` of the paused, resumed and sped-up run is byte-identical; a lockstep run refuses them
with its reason in ``live.json``. The browser test pauses a live ``run --view`` from the page,
resumes it, changes its speed, clicks a character and reads its panel, and sees the story panel
grow; its screenshots go to ``$STORYTELLER_TEST_OUTPUT/viewer/``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, cast

import anyio
import pytest

from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.benchmark.support.headless_chromium import Chromium, chromium_binary
from storyteller.orchestrator.llm.traces import read_trace
from storyteller.orchestrator.safe_text import markdown
from storyteller.orchestrator.session.live_state import LIVE_FILE, LiveState, RoleNow, read_live_state
from storyteller.orchestrator.session.viewer_controls import (
    CONTROLS_FILE,
    ControlInbox,
    DirectorControls,
    ViewerControl,
    controls_refusal,
    send_control,
)
from storyteller.orchestrator.session.viewer_instructions import send_instruction
from storyteller.orchestrator.viewer.panels import planner_text, run_line
from tests.support.directed_planner import TOAST, directed
from tests.support.story_planner import RUN, write_config

THREAD = "run-0123456789ab@unified+object-list"


# ----- the file and the fold ----------------------------------------------------------------
def test_control_lines_are_read_once_in_order_and_only_for_this_run(tmp_path: Path) -> None:
    first = send_control(tmp_path, THREAD, "pause", sent_unix=1.0)
    inbox = ControlInbox(tmp_path / CONTROLS_FILE, THREAD)
    assert [c.kind for c in inbox.poll()] == ["pause"]
    with (tmp_path / CONTROLS_FILE).open("ab") as f:
        again = first.model_dump(mode="json")
        f.write((json.dumps(again) + "\n").encode())  # the same line twice: once
        f.write((json.dumps({**again, "id": "b" * 32, "thread": "run-old"}) + "\n").encode())
        f.write((json.dumps({**again, "id": "c" * 32, "kind": "speed"}) + "\n").encode())  # no speed: refused
        f.write((json.dumps({**again, "id": "d" * 32, "kind": "speed", "speed": 1e9}) + "\n").encode())
        f.write(b"\xff not JSON\n")
    send_control(tmp_path, THREAD, "speed", 2.0, sent_unix=2.0)
    send_control(tmp_path, THREAD, "resume", sent_unix=3.0)
    assert [(c.kind, c.speed) for c in inbox.poll()] == [("speed", 2.0), ("resume", None)]
    with pytest.raises(ValueError, match="speed between"):
        send_control(tmp_path, THREAD, "speed", float("nan"), sent_unix=1.0)
    with pytest.raises(ValueError):
        ViewerControl.model_validate({"id": "e" * 32, "thread": THREAD, "kind": "pause", "speed": 2.0, "sent_unix": 1})


def test_the_fold_holds_at_a_frame_boundary_until_resumed() -> None:
    controls = DirectorControls(1.0)

    def line(kind: str, speed: float | None = None) -> ViewerControl:
        return ViewerControl.model_validate(
            {"id": os.urandom(16).hex(), "thread": THREAD, "kind": kind, "speed": speed, "sent_unix": 1.0})

    async def main() -> tuple[float, int | None]:
        assert await controls.hold(5) == 0.0  # not paused: no wait
        controls.take([line("pause"), line("speed", 4.0)])
        seen: list[int | None] = []

        async def resume_later() -> None:
            await anyio.sleep(0.2)
            seen.append(controls.paused_at)
            controls.take([line("resume")])

        async with anyio.create_task_group() as tg:
            tg.start_soon(resume_later)
            held = await controls.hold(7)
        return held, seen[0]

    held, paused_at = anyio.run(main)
    assert held > 0 and paused_at == 7 and controls.paused_at is None
    assert controls.speed(1.0) == 4.0 and controls.applied == 3 and controls.paused_s == held
    assert controls_refusal("realtime") is None
    assert "lockstep" in (controls_refusal("lockstep") or "")


def test_the_panels_show_text_from_the_run_as_data() -> None:
    hostile = "<img src=x onerror=alert(1)> *bold* [link](http://x) $x$"
    live = LiveState(thread=THREAD, frame=120, frames=600, fps=30, pace="realtime", speed=2.0, paused=True,
                     pausing=True, updated_unix=time.time(),
                     roles=(RoleNow(role="narrator", thinking_s=1.5, in_flight=1, calls=3,
                                    last_reply=f"line one {hostile}\nline two", last_reply_s=0.8),))  # fmt: skip
    text = planner_text(live)
    assert "thinking for 1.5 s" in text and markdown(hostile) in text
    assert "<" not in text.replace("\\<", "")  # every tag character escaped (text, not markup)
    assert "**paused** at frame 120" in run_line(live, now_unix=time.time(), ended=False)


def test_a_picked_speed_is_sent_though_the_run_writes_its_old_speed_meanwhile(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """viser stores a person's pick, then calls the callback from a thread pool; the live poll
    in between once put the run's old speed back, the callback read that and sent nothing (a
    clean-clone CI run: the browser test's speed 4 never reached the run)."""
    import viser

    from storyteller.orchestrator.viewer.panels import DirectorPanels

    def live(speed: float, thinking: float) -> None:
        state = LiveState(thread=THREAD, frame=120, frames=600, fps=30, pace="realtime", speed=speed, paused=True,
                          updated_unix=time.time(), roles=(RoleNow(role="narrator", thinking_s=thinking, in_flight=1),))
        (tmp_path / LIVE_FILE).write_text(state.model_dump_json())

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        panels = DirectorPanels(server, tmp_path, threading.RLock(), order=0.0, later=1.0)
        sent: list[tuple[str, float | None]] = []
        monkeypatch.setattr(panels, "send_control", lambda kind, speed=None: sent.append((kind, speed)))
        live(2.0, 1.0)
        panels.poll_live()
        assert panels.speed.value == "2"
        panels.speed._impl.value = "4"  # what viser does with the page's pick before the callback
        live(2.0, 1.5)  # the run still thinks, at its old speed
        panels.poll_live()
        assert panels.speed.value == "4"  # the pick stays
        panels._on_speed(viser.GuiEvent(client=cast(Any, object()), client_id=1, target=panels.speed))
        assert sent == [("speed", 4.0)]
        live(4.0, 2.0)  # applied
        panels.poll_live()
        assert panels.speed.value == "4" and not panels._pick_pending()
        live(1.0, 2.5)  # the run's speed changed from elsewhere: shown
        panels.poll_live()
        assert panels.speed.value == "1"
    finally:
        server.stop()


# ----- runs --------------------------------------------------------------------------------
def _cli(*args: str) -> list[str]:
    return [sys.executable, "-c", "from storyteller.orchestrator.cli.app import app; app()", *args]


def _env(tmp_path: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL", "STORYTELLER_PLANNER_MODEL")}  # fmt: skip
    env.update(FAKE_PROVIDER_KEY="sk-test-123", STORYTELLER_CACHE_DIR=str(tmp_path / "cache"))
    return env


def _wait(what: str, ok: Any, *, timeout_s: float, log: Path | None = None) -> Any:
    """Poll ``ok()`` every 0.1 s until it is truthy; returns its value."""
    deadline = time.monotonic() + timeout_s
    while not (value := ok()):
        tail = log.read_text(errors="replace")[-3000:] if log is not None and log.exists() else ""
        assert time.monotonic() < deadline, f"{what}: not within {timeout_s} s\n{tail}"
        time.sleep(0.1)
    return value


def _live(out: Path) -> LiveState | None:
    return read_live_state(out)  # never half-written: renamed over the old one whole


class _Slow:
    """The directed planner, a second late until :attr:`fast` is set: steps are in flight while
    the run is paused. After it, answers come at once, so no step is left in flight when the
    story ends (a replay would ask for it and find no answer: see the test's note)."""

    def __init__(self) -> None:
        self.fast = threading.Event()

    def __call__(self, body: dict[str, Any]) -> str:
        if not self.fast.is_set():  # known limit: a step still in flight when a realtime story ends has
            # no answer in the trace, and its replay asks for it and stops with a replay miss (exit 1)
            time.sleep(1.0)
        return directed(body)


def _thread(out: Path) -> str:
    return str(json.loads((out / "run.json").read_text(encoding="utf-8"))["thread_id"])


def _same_story(run: Path, again: Path) -> None:
    for name in ("story.json", "story.md", "Zoe.track.npz", "Max.track.npz"):
        assert (again / name).read_bytes() == (run / name).read_bytes(), name


@pytest.mark.slow
def test_a_paused_resumed_and_sped_up_run_replays_byte_identically(tmp_path: Path) -> None:
    out, log = tmp_path / "run", tmp_path / "run.log"
    slow = _Slow()
    with FakeOpenAI(responder=slow) as fake:
        cfg = write_config(tmp_path, fake.base)
        args = [*RUN, "-d", "30", "--pace", "realtime", "--speed", "2", "--config", str(cfg), "--out", str(out)]
        with log.open("w") as sink:
            run = subprocess.Popen(_cli(*args), env=_env(tmp_path), stdout=sink, stderr=subprocess.STDOUT)
        try:
            live = _wait("a frame past 2 s with the planner thinking", lambda: (s := _live(out)) is not None
                         and s.frame > 60 and any(r.thinking_s is not None for r in s.roles) and s, timeout_s=120, log=log)  # fmt: skip
            assert live.controls is None and live.speed == 2.0
            thread = _thread(out)
            send_control(out, thread, "pause", sent_unix=time.time())
            paused = _wait("the run paused", lambda: (s := _live(out)) is not None and s.paused and s, timeout_s=30, log=log)
            send_instruction(out, thread, TOAST, sent_unix=time.time())  # taken at the frame the run resumes at
            time.sleep(2.5)  # the planner's reply (1 s) arrives meanwhile; the frame stays
            still = _live(out)
            assert still is not None and still.paused and still.frame == paused.frame
            send_control(out, thread, "speed", 4.0, sent_unix=time.time())
            send_control(out, thread, "resume", sent_unix=time.time())
            slow.fast.set()
            _wait("the run going on", lambda: (s := _live(out)) is not None and s.frame > paused.frame, timeout_s=30, log=log)
            assert run.wait(timeout=300) == 0, log.read_text()[-3000:]
        finally:
            if run.poll() is None:
                run.kill()
                run.wait()
    end = read_live_state(out)
    assert end is not None and not end.running and end.controls_applied == 3 and end.speed == 4.0
    said = [(r.sim_frame, r.source, r.text) for r in read_trace(out / "trace.jsonl").instructions()]
    assert said == [(paused.frame, "viewer", TOAST)], said  # the first frame after the pause
    again = tmp_path / "again"
    with log.open("a") as sink:  # no provider: the trace serves every call
        code = subprocess.call(_cli("replay", str(out), "--out", str(again)), env=_env(tmp_path), stdout=sink,
                               stderr=subprocess.STDOUT)
    assert code == 0, log.read_text()[-3000:]
    _same_story(out, again)
    applied = [e["applied_frame"] for e in json.loads((out / "story.json").read_text(encoding="utf-8"))["events"]]
    print(f"paused at frame {paused.frame}; events applied at frames {applied}")


@pytest.mark.slow
def test_a_lockstep_run_refuses_pause_with_its_reason(tmp_path: Path) -> None:
    out, log = tmp_path / "run", tmp_path / "run.log"
    with FakeOpenAI(responder=directed) as fake:
        cfg = write_config(tmp_path, fake.base)
        (out).mkdir()
        with log.open("w") as sink:
            code = subprocess.call(_cli(*RUN, "-d", "5", "--pace", "lockstep", "--config", str(cfg), "--out", str(out)),
                                   env=_env(tmp_path), stdout=sink, stderr=subprocess.STDOUT)
        assert code == 0, log.read_text()
    end = read_live_state(out)
    assert end is not None and not end.running and end.frame == 150
    assert end.controls is not None and "realtime" in end.controls and "lockstep" in end.controls
    assert {c.name for c in end.characters} == {"Zoe", "Max"} and end.roles


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


def _text(browser: Chromium) -> str:
    return str(browser.evaluate("document.body.innerText"))


def _page_frame(browser: Chromium) -> int:
    """The run's sim frame as the run panel says it."""
    import re

    found = re.search(r"Run: sim frame (\d+)", _text(browser))
    assert found, _text(browser)
    return int(found.group(1))


def _click(browser: Chromium, label: str) -> None:
    browser.evaluate(f"[...document.querySelectorAll('button')].find(b => b.innerText.trim() === {json.dumps(label)}).click()")


def _wait_page(browser: Chromium, what: str, js: str, timeout_s: float = 60) -> None:
    try:
        browser.wait_for(js, timeout_s=timeout_s)
    except TimeoutError:
        raise AssertionError(f"{what}; the page says: {_text(browser)}") from None


def _tall_page(browser: Chromium) -> None:
    """A page tall enough for the whole panel (every folder open) in one screenshot."""
    browser.call("Emulation.setDeviceMetricsOverride", width=1280, height=2000, deviceScaleFactor=1, mobile=False)


def _pick_speed(browser: Chromium, value: str) -> None:
    """Open the 'Run speed' dropdown and pick ``value`` as a person does."""
    browser.evaluate(
        "(() => { const label = [...document.querySelectorAll('label')].find(l => l.innerText.trim() === 'Run speed');"
        " let row = label; while (row && !row.querySelector('input')) row = row.parentElement;"
        " row.querySelector('input').click(); return true; })()"
    )
    _wait_page(browser, "the speed options", f"[...document.querySelectorAll('[role=option]')].some(o => o.innerText.trim() === {json.dumps(value)})", 10)
    browser.evaluate(f"[...document.querySelectorAll('[role=option]')].find(o => o.innerText.trim() === {json.dumps(value)}).click()")


@needs_chromium
@pytest.mark.slow
def test_a_director_pauses_resumes_speeds_and_follows_from_the_page(tmp_path: Path, shots: Path) -> None:
    out, log = tmp_path / "run", tmp_path / "run.log"
    slow = _Slow()
    with FakeOpenAI(responder=slow) as fake:
        cfg = write_config(tmp_path, fake.base)
        args = [*RUN, "-d", "60", "--pace", "realtime", "--speed", "2", "--config", str(cfg), "--out", str(out),
                "--view", "--port", "0"]  # fmt: skip
        with log.open("w") as sink:
            run = subprocess.Popen(_cli(*args), env=_env(tmp_path), stdout=sink, stderr=subprocess.STDOUT)
        (tmp_path / "profile").mkdir()
        try:
            with Chromium(tmp_path / "profile") as browser:
                browser.navigate(_url(log, run))
                _wait_page(browser, "no live run", "document.body.innerText.includes('the run is still going')", 120)
                _wait_page(browser, "no run panel", "document.body.innerText.includes('Run: sim frame')")
                _wait_page(browser, "no story event yet", "document.body.innerText.includes('(e')", 60)
                story_before = browser.evaluate("document.body.innerText.split('Story in').length")
                events_before = _text(browser).count("\u2014")
                _click(browser, "Pause the run")
                _wait_page(browser, "not paused", "document.body.innerText.includes('paused at frame')", 30)
                frame = _page_frame(browser)
                _wait_page(browser, "the planner not shown", "document.body.innerText.includes('last reply')", 30)
                browser.screenshot(shots / "director-paused.png")
                time.sleep(2.0)  # paused: the frame the page shows stays
                assert _page_frame(browser) == frame
                live = read_live_state(out)
                assert live is not None and live.paused and live.frame == frame
                # the speed is picked while paused: a paused run cannot end before the control is read
                # (picked after resuming, a loaded machine could finish the story first)
                _pick_speed(browser, "4")
                _wait("the run at speed 4", lambda: (s := read_live_state(out)) is not None and s.speed == 4.0, timeout_s=30, log=log)
                _wait_page(browser, "speed not shown", "document.body.innerText.includes('speed 4\u00d7')", 30)
                assert _page_frame(browser) == frame  # still paused
                _click(browser, "Resume the run")
                slow.fast.set()
                _wait_page(browser, "not resumed", f"(() => {{ const m = document.body.innerText.match(/Run: sim frame (\\d+)/); return m && +m[1] > {frame}; }})()", 30)
                _click(browser, "Max")
                _wait_page(browser, "no character panel", "document.body.innerText.includes('events so far')", 30)
                text = _text(browser)
                assert "in the run now" in text and "at the frame shown" in text, text
                _tall_page(browser)
                browser.screenshot(shots / "director-character.png")
                _wait("the story panel growing", lambda: _text(browser).count("\u2014") > events_before, timeout_s=120, log=log)
                assert story_before == browser.evaluate("document.body.innerText.split('Story in').length")
                browser.screenshot(shots / "director-story.png")
                _wait("the story's end", lambda: "the story has ended" in log.read_text(), timeout_s=300, log=log)
                _wait_page(browser, "the ended run", "document.body.innerText.includes('Run: ended at')", 30)
                _click(browser, "Pause the run")
                browser.screenshot(shots / "director-run-ended.png")
            run.send_signal(signal.SIGINT)
            assert run.wait(timeout=60) == 0, log.read_text()[-3000:]
        finally:
            if run.poll() is None:
                run.kill()
                run.wait()
    assert not [c for c in read_trace(out / "trace.jsonl").instructions()]  # controls are not instructions
    print(f"screenshots: {sorted(str(p) for p in shots.glob('director-*.png'))}")

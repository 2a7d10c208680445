"""The live view of ``storyteller run``: what it shows, that model text shows literally, the
status it is fed from a real session and a watched LLM port, and the run command with the view
forced on and off (the LLM is the scripted OpenAI-compatible server of ``tests/orchestrator/session/test_run_folder.py``).
"""

from __future__ import annotations

import io
import json
import re
import sys
from collections.abc import Callable
from pathlib import Path

import anyio
import pytest
from anyio import wait_all_tasks_blocked
from rich.console import Console
from rich.text import Text
from typer.testing import CliRunner

from storyteller.agents.llm_port import LLMError, LLMRequest, LLMResponse, NodeName, TokenUsage
from storyteller.benchmark.support.fake_openai_server import PROMPT_TOKENS, FakeOpenAI
from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.cli.live_view import live_view
from storyteller.orchestrator.cli.run import live_and_interactive
from storyteller.orchestrator.llm.watched_port import WatchedPort
from storyteller.orchestrator.session.run_status import CharacterRow, RoleCalls, RunSnapshot, RunStatus
from storyteller.orchestrator.session.runtime import Session
from storyteller.orchestrator.session.session_types import SessionSettings
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.event_book import EventStatus
from storyteller.sim.world.step import World
from tests.support.cli_run import RUN, Planner, write_config
from tests.support.session_world import FPS, ScriptedPlanner, make_world

HOSTILE = "[bold red]x[/] [link=https://evil.example]click[/link] \x1b[2J\x1b]8;;https://evil.example\x07"


def rendered(snapshot: RunSnapshot) -> tuple[str, str]:
    """(the terminal output of the view, its text without styles)."""
    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=120)
    console.print(live_view(snapshot, console.width))
    raw = out.getvalue()
    return raw, Text.from_ansi(raw).plain


def snapshot(**changes: object) -> RunSnapshot:
    base = RunSnapshot(
        frame=1269, frames=3600, fps=30, pace="realtime", wall_s=41.0, speed=1.03, started=True,
        characters=(
            CharacterRow("Ava", "acting", "event-0003", "Ava makes coffee", "use_coffee_maker", "kitchen counter"),
            CharacterRow("Ben", "walking", "event-0004", "Ben goes to read", "sit_read", "living room (on sofa_1)"),
            CharacterRow("Cleo", "idle"),
        ),
        roles=(RoleCalls("narrator", 1, 3.2, 7, 1, 12_000, 800), RoleCalls("event_parser", 2, 1.5, 6, 0, 20_500, 3_100)),
        events=(("ongoing", 2), ("completed", 5), ("failed", 1)),
        steps=9,
        instruction="Ben leaves the kitchen",
    )
    return RunSnapshot(**{**base.__dict__, **changes})


def line_with(text: str, word: str) -> str:
    found = [line for line in text.splitlines() if line.startswith(word)]
    assert len(found) == 1, (word, text)
    return found[0]


# ----- what the view shows ------------------------------------------------------------------
def test_the_view_shows_the_clock_each_character_the_calls_in_flight_and_the_tokens() -> None:
    _, text = rendered(snapshot())
    assert text.startswith("00:42.3 / 02:00.0 (35%)  speed x1.03 sim s/wall s  wall 41.0 s  pace realtime\n")
    ava = line_with(text, "Ava")
    for part in ("acting", "event-0003", "Ava makes coffee", "use_coffee_maker", "kitchen counter"):
        assert part in ava, (part, ava)
    ben = line_with(text, "Ben")
    assert re.search(r"walking\s+event-0004\s+Ben goes to read\s+sit_read\s+living room \(on sofa_1\)", ben), ben
    assert line_with(text, "Cleo").split() == ["Cleo", "idle"]
    assert line_with(text, "narrator").split() == ["narrator", "1", "3.2", "s", "7", "1", "12,000", "800"]
    assert line_with(text, "event_parser").split() == ["event_parser", "2", "1.5", "s", "6", "0", "20,500", "3,100"]
    assert line_with(text, "all").split() == ["all", "3", "13", "1", "32,500", "3,900"]
    assert "events 2 under way, 5 done, 1 failed  planning steps 9" in text
    assert "instruction Ben leaves the kitchen" in text


def test_an_idle_role_shows_no_time_and_before_the_first_frame_the_view_says_it_is_starting() -> None:
    _, text = rendered(snapshot(roles=(RoleCalls("planner", 0, 0.0, 4, 0, 44, 20),)))
    assert line_with(text, "planner").split() == ["planner", "0", "-", "4", "0", "44", "20"]
    assert not [line for line in text.splitlines() if line.startswith("all ")]  # one role: no total row
    _, text = rendered(RunSnapshot())
    assert "starting" in text and "no call yet" in text and "character" not in text


def test_text_from_a_model_or_the_user_shows_literally() -> None:
    raw, text = rendered(snapshot(
        characters=(CharacterRow("[i]Eve[/i]", "acting", "event-0001", HOSTILE, "[blink]act", "[u]room"),),
        instruction=HOSTILE,
    ))
    assert "[i]Eve[/i]" in text and "[blink]act" in text and "[u]room" in text
    assert "[bold red]x[/] [link=https://evil.example]click[/link]" in line_with(text, "instruction")
    assert "\x1b[2J" not in raw and "\x1b]8;" not in raw  # no escape sequence and no hyperlink reached the terminal
    assert "\\x1b[2J" in text  # the control character is shown as an escape


# ----- the status, fed by a session and a watched port ----------------------------------------
class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class FakePort:
    trace = None

    def __init__(self) -> None:
        self.gate = anyio.Event()

    async def complete(self, request: LLMRequest) -> LLMResponse:
        text = request.messages[-1].content
        if text == "fail":
            raise LLMError("no answer")
        if text == "hang":
            await self.gate.wait()
        return LLMResponse(text="ok", model="fake", usage=TokenUsage(prompt_tokens=11, completion_tokens=5))

    def close(self) -> None:
        pass


def request(node: NodeName, text: str) -> LLMRequest:
    return LLMRequest.model_validate({"node": node, "messages": [{"role": "user", "content": text}]})


def test_a_watched_port_reports_calls_in_flight_answers_failures_and_cancellations() -> None:
    clock = Clock()
    status = RunStatus(clock=clock)
    port = WatchedPort(FakePort(), status)
    seen: list[RunSnapshot] = []

    async def main() -> None:
        assert (await port.complete(request("narrator", "hi"))).text == "ok"
        with pytest.raises(LLMError):
            await port.complete(request("narrator", "fail"))
        async with anyio.create_task_group() as tg:
            tg.start_soon(port.complete, request("event_parser", "hang"))
            tg.start_soon(port.complete, request("event_parser", "hang"))
            await wait_all_tasks_blocked()
            clock.now += 2.5
            seen.append(status.snapshot())
            tg.cancel_scope.cancel()

    anyio.run(main)
    during, after = seen[0], status.snapshot()
    assert during.roles == (RoleCalls("narrator", 0, 0.0, 2, 1, 11, 5), RoleCalls("event_parser", 2, 2.5, 0, 0, 0, 0))
    # the cancelled calls are no longer in flight and count neither as calls nor as failures
    assert after.roles == (RoleCalls("narrator", 0, 0.0, 2, 1, 11, 5),) and after.in_flight == 0
    assert (after.calls, after.prompt_tokens, after.completion_tokens, after.started) == (2, 11, 5, False)


def test_a_session_feeds_the_status_characters_events_and_places(home: Scene, motion: MotionMatcher) -> None:
    clock = Clock()
    status = RunStatus(clock=clock)
    world = make_world(home, motion, ["Ava", "Ben"])
    rows: list[CharacterRow] = []

    def frame(w: World) -> None:
        status.frame(w)
        clock.now += 0.5 / FPS  # twice the simulated speed
        if w.frame % 15 == 0:
            rows.extend(status.snapshot().characters)

    settings = SessionSettings(frames=40 * FPS, pace="lockstep")
    session = Session(world, ScriptedPlanner(home), settings, on_event=status.event, on_outcome=status.outcome,
                      on_frame=frame)
    status.started(session.world, frames=settings.frames, pace="lockstep", instruction="be busy")
    result = anyio.run(session.run)
    end = status.snapshot()
    assert (end.frame, end.frames, end.pace, end.instruction) == (40 * FPS, 40 * FPS, "lockstep", "be busy")
    assert end.speed == pytest.approx(2.0)
    assert [c.name for c in end.characters] == ["Ava", "Ben"]
    assert end.steps == result.steps
    def by_state(count: Callable[[EventStatus], int]) -> tuple[int, int, int]:  # (under way, completed, failed)
        return count("ongoing") + count("looping"), count("completed"), count("failed")

    states = by_state(lambda state: sum(e.state == state for e in result.events))
    assert by_state(end.count) == states and sum(states) == len(result.events) > 0 and states[1] > 0
    assert {"walking", "acting"} <= {r.state for r in rows}
    activities = {e.event_id: e.text for e in result.events}  # the plan sentence, not the narrator's words
    busy = [r for r in rows if r.event_id]
    assert busy and all(r.activity == activities[r.event_id] and r.action in ("use_smartphone", "drink")
                        and r.place == "near a free spot" for r in busy)
    assert all((r.event_id, r.activity, r.action, r.place) == ("", "", "", "") for r in rows if not r.event_id)


# ----- the run command ----------------------------------------------------------------------
class _Tty(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


@pytest.mark.parametrize(
    ("stdin_tty", "stdout_tty", "live", "interactive", "expected"),
    [
        (True, True, None, None, (True, True)),  # a terminal: the live view, its last line the typed instruction
        (False, True, None, None, (True, False)),
        (True, False, None, None, (False, True)),  # output piped: plain lines, typing as before
        (False, False, None, None, (False, False)),
        (True, True, False, None, (False, True)),
        (True, True, None, False, (True, False)),
        (False, False, True, True, (True, True)),  # forced on a pipe
    ],
)
def test_live_and_interactive_defaults(monkeypatch: pytest.MonkeyPatch, stdin_tty: bool, stdout_tty: bool,
                                       live: bool | None, interactive: bool | None, expected: tuple[bool, bool]) -> None:
    monkeypatch.setattr(sys, "stdin", _Tty(stdin_tty))
    monkeypatch.setattr(sys, "stdout", _Tty(stdout_tty))
    assert live_and_interactive(live, interactive, reads_stdin=True) == expected
    # a replay never reads stdin
    assert live_and_interactive(live, interactive, reads_stdin=False) == (expected[0], False)


EVENT_LINE = re.compile(r"^\[ *\d+\.\ds\] event-\d{4} (starts|loops|done|failed): ")


@pytest.mark.slow
def test_run_with_the_live_view_forced_and_without_it(env: None, tmp_path: Path) -> None:
    run = [*RUN, "-d", "20", "--max-events", "2"]
    with FakeOpenAI(responder=Planner()) as fake:
        cfg = write_config(tmp_path, fake.base)
        plain_run = CliRunner().invoke(app, [*run, "--config", str(cfg), "--out", str(tmp_path / "plain")],
                                       catch_exceptions=False)
        calls = len(fake.requests)
        shown = CliRunner().invoke(app, [*run, "--live", "--config", str(cfg), "--out", str(tmp_path / "live")],
                                   catch_exceptions=False)
    assert plain_run.exit_code == 0, plain_run.stderr
    assert shown.exit_code == 0, shown.stderr
    # not a terminal: the plain lines, nothing else
    lines = plain_run.stdout.splitlines()
    assert lines[-1].startswith("600 frames (20.0 s), 2 planning steps, ") and lines[-1].endswith(str(tmp_path / "plain"))
    events = lines[:-1]
    assert len(events) >= 2 and all(EVENT_LINE.match(line) for line in events), lines
    assert "\x1b" not in plain_run.stdout
    # live: the same story lines, each once, above the view; the summary line after it
    text = Text.from_ansi(shown.stdout).plain
    assert [line for line in text.splitlines() if EVENT_LINE.match(line)] == events
    assert all(shown.stdout.count(line) == 1 for line in events)
    assert text.rstrip().splitlines()[-1] == lines[-1].replace("plain", "live")
    assert "\x1b[" in shown.stdout and "LLM role" in text
    # the last state drawn: the clock at the end, every call done, its tokens as in metrics.json
    final = text[text.rindex("00:20.0 / 00:20.0 (100%)"):]
    metrics = json.loads((tmp_path / "live" / "metrics.json").read_text(encoding="utf-8"))
    planner = metrics["llm"]["roles"]["planner"]
    assert planner["calls"] == calls == 2 and planner["prompt_tokens"] == PROMPT_TOKENS * calls
    row = line_with(final, "planner").split()
    assert row[:5] == ["planner", "0", "-", str(calls), "0"] and row[5] == f"{planner['prompt_tokens']:,}"
    assert row[6] == f"{planner['completion_tokens']:,}"
    assert "planning steps 2" in final
    # the run folders tell the same story
    for name in ("story.json", "story.md"):
        assert (tmp_path / "live" / name).read_bytes() == (tmp_path / "plain" / name).read_bytes(), name


def test_a_run_that_fails_stops_the_live_view_before_its_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.jsonl"
    bad.write_text("not a trace\n", encoding="utf-8")
    result = CliRunner().invoke(app, ["run", "home", "--live", "--replay", str(bad), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and result.stderr.startswith(f"error: {bad}"), result.stderr
    assert "\x1b[?25l" in result.stdout and result.stdout.endswith("\x1b[?25h")  # the cursor hidden, then shown again

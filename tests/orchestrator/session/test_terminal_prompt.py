"""Instructions typed under the live view: the line editor (keys in, lines out), the prompt on a
real pseudo-terminal (no echo while it reads, the mode restored after), the typed line drawn on
the view's last line, literally.
"""

from __future__ import annotations

import io
import os
import pty
import queue
import subprocess
import termios
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from rich.console import Console
from rich.text import Text

from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.orchestrator.cli.live_view import live_view
from storyteller.orchestrator.llm.traces import read_trace
from storyteller.orchestrator.session.run_status import RunSnapshot
from storyteller.orchestrator.session.session_types import InstructionSource
from storyteller.orchestrator.session.terminal_prompt import MAX_LINE, LineEditor, TerminalPrompt
from tests.support.cli_run import ROOT, RUN, Planner, cli, write_config


def test_the_editor_gives_out_lines_and_keeps_the_one_being_typed() -> None:
    ed = LineEditor()
    assert ed.feed(b"Ben waves") == [] and ed.text == "Ben waves"
    assert ed.feed(b" at Ava\r\nnext") == ["Ben waves at Ava"] and ed.text == "next"  # CR LF: one Enter
    assert ed.feed(b"\n\n") == ["next", ""] and ed.text == ""


def test_the_editor_edits_and_drops_controls_and_escape_sequences() -> None:
    ed = LineEditor()
    ed.feed("Zoë".encode()[:3])  # cut in the middle of a character
    assert ed.text == "Zo"
    ed.feed("Zoë".encode()[3:] + b"x\x7f")  # the rest of it, then Backspace
    assert ed.text == "Zoë"
    ed.feed(b" walks\x1b[D\x1b[1;5C\x1bOA home\x07\x00\tnow")  # arrows, bell, NUL: dropped; Tab: a space
    assert ed.text == "Zoë walks home now"
    ed.feed(b"\x17")  # Ctrl-W: the last word
    assert ed.text == "Zoë walks home "
    ed.feed(b"\x15")  # Ctrl-U: the whole line
    assert ed.text == ""
    ed.feed(b"\x1b]8;;http://x\x07")  # an OSC: its ESC and ']' dropped, the rest is plain text at worst
    assert "\x1b" not in ed.text and "\x07" not in ed.text
    ed.feed(b"\x15" + b"y" * (MAX_LINE + 50))
    assert len(ed.text) == MAX_LINE


class Taker:
    def __init__(self) -> None:
        self.lines: queue.Queue[tuple[str, InstructionSource]] = queue.Queue()

    def instruct_nowait(self, text: str, source: InstructionSource = "stdin") -> bool:
        self.lines.put((text, source))
        return True


@pytest.fixture
def terminal() -> Iterator[tuple[int, int]]:
    master, slave = pty.openpty()
    yield master, slave
    os.close(master)
    os.close(slave)


def test_the_prompt_reads_keys_without_echo_and_restores_the_terminal(terminal: tuple[int, int]) -> None:
    master, slave = terminal
    before = termios.tcgetattr(slave)
    changed = threading.Event()
    prompt = TerminalPrompt(slave, on_change=changed.set)
    taker = Taker()
    prompt.start(taker)
    mode = termios.tcgetattr(slave)
    assert not mode[3] & (termios.ECHO | termios.ICANON) and mode[3] & termios.ISIG  # Ctrl-C still signals
    os.write(master, b"Ava sits\x7f\x7fts")
    assert changed.wait(10)
    os.write(master, b"\r# a comment\r\rBen reads\r")
    assert [taker.lines.get(timeout=10) for _ in range(2)] == [("Ava sits", "stdin"), ("Ben reads", "stdin")]
    assert prompt.text == "" and taker.lines.empty()
    prompt.close()
    prompt.close()
    assert termios.tcgetattr(slave) == before


def test_the_typed_line_is_the_view_s_last_line_shown_literally() -> None:
    def last_line(typed: str | None, width: int = 80) -> str:
        out = io.StringIO()
        Console(file=out, force_terminal=True, width=width).print(live_view(RunSnapshot(), width, typed))
        return Text.from_ansi(out.getvalue()).plain.rstrip("\n").splitlines()[-1]

    assert last_line("") == "instruction> type a new instruction, Enter gives it"
    assert last_line("[red]Ben[/] \x1b[2J") == "instruction> [red]Ben[/] \\x1b[2J\u2588"
    long = "word " * 40 + "END"
    shown = last_line(long, width=60)
    assert shown.startswith("instruction> \u2026") and shown.endswith("END\u2588") and len(shown) <= 60
    assert last_line(None).startswith("events ")  # not typed here: no prompt line


# ----- storyteller run on a terminal: the live view and typed instructions by default ----------
class GatedPlanner:
    """The run folder tests' planner, holding its second answer until ``release`` is set."""

    def __init__(self) -> None:
        self.planner = Planner()
        self.asked = threading.Event()
        self.release = threading.Event()
        self.count = 0

    def __call__(self, body: dict[str, Any]) -> str:
        self.count += 1
        if self.count == 2:
            self.asked.set()
            self.release.wait(120)
        return self.planner(body)


class TerminalOutput:
    """Everything a child writes to the master side of its terminal, read in a thread."""

    def __init__(self, master: int) -> None:
        self.master = master
        self.data = bytearray()
        self.grew = threading.Condition()
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        while True:
            try:
                chunk = os.read(self.master, 65536)
            except OSError:  # the child closed its side
                chunk = b""
            with self.grew:
                self.data += chunk
                self.grew.notify_all()
            if not chunk:
                return

    def wait_for(self, text: bytes, timeout: float = 120.0) -> None:
        with self.grew:
            assert self.grew.wait_for(lambda: text in self.data, timeout), bytes(self.data[-2000:])


@pytest.mark.slow
def test_run_on_a_terminal_shows_the_live_view_and_takes_typed_instructions(
    env: None, tmp_path: Path, terminal: tuple[int, int]
) -> None:
    master, slave = terminal
    before = termios.tcgetattr(slave)
    gate = GatedPlanner()
    with FakeOpenAI(responder=gate) as fake:
        cfg = write_config(tmp_path, fake.base)
        out = tmp_path / "out"
        child = subprocess.Popen(cli(*RUN, "-d", "20", "--max-events", "2", "--config", str(cfg), "--out", str(out)),
                                 cwd=ROOT, env=os.environ.copy(), stdin=slave, stdout=slave, stderr=slave,
                                 start_new_session=True)
        screen = TerminalOutput(master)
        try:
            assert gate.asked.wait(240), bytes(screen.data[-2000:])  # the first event is on; the second waits
            mode = termios.tcgetattr(slave)
            assert not mode[3] & (termios.ECHO | termios.ICANON)  # the prompt reads the keys, the view draws them
            os.write(master, b"Zoe waves at Mxa\x7f\x7fax")
            screen.wait_for(b"Zoe waves at Max")  # drawn on the view's last line as it is typed
            os.write(master, b"\r")  # given to the session at once; it takes effect at the next frame,
            gate.release.set()  # which comes when the second answer is in (lockstep pace)
            screen.wait_for(b"instruction (stdin): Zoe waves at Max")  # printed above the view
        finally:
            gate.release.set()
            returncode = child.wait(240)
    assert returncode == 0, bytes(screen.data[-2000:])
    assert termios.tcgetattr(slave) == before  # the terminal as it was
    said = [(r.text, r.source) for r in read_trace(out / "trace.jsonl").instructions()]
    assert said == [("Zoe waves at Max", "stdin")]
    text = Text.from_ansi(bytes(screen.data).decode("utf-8", "replace")).plain
    assert "LLM role" in text and "600 frames (20.0 s), 2 planning steps, 2 events completed" in text

"""Instruction scripts and stdin instructions are bounded: a time must be a finite number of
seconds within a week (400 nines became infinity, and a run.json that resume refused; 5,000
digits was a traceback), an instruction has at most ``MAX_INSTRUCTION_CHARS`` characters, a
script at most ``MAX_SCRIPT_BYTES`` bytes and ``MAX_SCRIPT_INSTRUCTIONS`` lines. A bad script
is one line naming the file and the line, exit code 2, through ``storyteller run``. Stdin is
read in pieces of the instruction limit: a 1 GiB line never sits in memory whole."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.session.instruction_script import (
    MAX_INSTRUCTION_CHARS,
    MAX_SCRIPT_BYTES,
    MAX_SCRIPT_INSTRUCTIONS,
    MAX_SCRIPT_TIME_S,
    InstructionScriptError,
    parse_instruction_script,
    read_instruction_script,
)
from storyteller.orchestrator.session.stdin_instructions import (
    bounded_lines,
    start_stdin_reader,
    typed_instruction,
)
from tests.support.finished_run import one_error_line


def run_with_script(path: Path, tmp_path: Path) -> str:
    result = CliRunner().invoke(app, ["run", "home", "--instructions", str(path), "--out", str(tmp_path / "out")])
    return one_error_line(result, str(path))


@pytest.mark.parametrize(
    ("line", "words"),
    [
        ("9" * 400 + " Ben waves", "too large"),
        ("9" * 5_000 + " Ben waves", "too large"),
        ("1:" + "9" * 40 + ":00 Ben waves", "too large"),
        ("999999999 Ben waves", "too late"),
        ("00:30 " + "x" * (MAX_INSTRUCTION_CHARS + 1), f"at most {MAX_INSTRUCTION_CHARS}"),
    ],
)
def test_a_bad_line_is_one_line_naming_the_file_and_the_line(tmp_path: Path, line: str, words: str) -> None:
    path = tmp_path / "script.txt"
    path.write_text(f"00:05 Ava sits down\n# a comment\n{line}\n", encoding="utf-8")
    with pytest.raises(InstructionScriptError, match=words):
        read_instruction_script(path)
    assert "line 3" in run_with_script(path, tmp_path)


def test_the_limits_themselves_are_accepted() -> None:
    week = int(MAX_SCRIPT_TIME_S // 3600)
    lines = parse_instruction_script(f"{week}:00:00 {'x' * MAX_INSTRUCTION_CHARS}\n00:01 go")
    assert [s.time_s for s in lines] == [1.0, MAX_SCRIPT_TIME_S] and len(lines[1].text) == MAX_INSTRUCTION_CHARS


def test_too_many_instructions(tmp_path: Path) -> None:
    text = "".join(f"{i} go\n" for i in range(MAX_SCRIPT_INSTRUCTIONS + 1))
    with pytest.raises(InstructionScriptError, match=f"more than {MAX_SCRIPT_INSTRUCTIONS}"):
        parse_instruction_script(text, "s.txt")


def test_oversized_binary_and_device_scripts(tmp_path: Path) -> None:
    big = tmp_path / "big.txt"
    with big.open("wb") as f:  # sparse: the 1 GiB line of issue 22, without the disk
        f.truncate(2**30)
    assert f"{MAX_SCRIPT_BYTES}" in run_with_script(big, tmp_path)
    latin = tmp_path / "latin.txt"
    latin.write_bytes(b"00:01 caf\xe9\n")
    assert "UTF-8" in run_with_script(latin, tmp_path)
    with pytest.raises(InstructionScriptError, match="not a regular file"):
        read_instruction_script(Path("/dev/zero"))


# ----- stdin ---------------------------------------------------------------------------------------
class MeasuredStream(io.StringIO):
    """A text stream that records how many characters each readline asked for at most."""

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self.asked: list[int] = []

    def readline(self, size: int = -1, /) -> str:  # type: ignore[override]  # a stream stand-in with io's positional-only signature
        self.asked.append(size)
        return super().readline(size)


def test_stdin_is_read_in_bounded_pieces_and_a_long_line_is_skipped() -> None:
    long = "y" * (50 * MAX_INSTRUCTION_CHARS + 7)
    stream = MeasuredStream(f"Ava waves\n{long}\nBen sits\n{'z' * (MAX_INSTRUCTION_CHARS + 1)}")
    assert list(bounded_lines(stream)) == ["Ava waves\n", None, "Ben sits\n", None]
    assert stream.asked and all(0 < size <= MAX_INSTRUCTION_CHARS + 1 for size in stream.asked)


def test_a_line_of_exactly_the_limit_is_kept() -> None:
    exact = "x" * MAX_INSTRUCTION_CHARS
    assert list(bounded_lines(io.StringIO(f"{exact}\n{exact}"))) == [exact + "\n", exact]
    assert typed_instruction(exact) == exact and typed_instruction(exact + "x") is None


def test_the_stdin_reader_hands_over_only_bounded_instructions() -> None:
    got: list[tuple[str, Any]] = []

    class Taker:
        def instruct_nowait(self, text: str, source: Any = "stdin") -> bool:
            got.append((text, source))
            return True

    stream = io.StringIO(f"Ava waves\n{'q' * (3 * MAX_INSTRUCTION_CHARS)}\n# note\nBen sits\n")
    start_stdin_reader(Taker(), stream).join(timeout=30)
    assert got == [("Ava waves", "stdin"), ("Ben sits", "stdin")]


@pytest.mark.parametrize("command", ["run", "plan"])
def test_a_long_instruction_option_is_one_line(tmp_path: Path, command: str) -> None:
    args = [command, "home", "--instruction", "x" * (MAX_INSTRUCTION_CHARS + 1)]
    if command == "run":
        args += ["--out", str(tmp_path / "out")]
    one_error_line(CliRunner().invoke(app, args), "--instruction", f"at most {MAX_INSTRUCTION_CHARS}")


def test_a_session_takes_a_bounded_number_of_live_instructions() -> None:
    """Found by the second hostile corpus: a viewer's inbox of a million valid lines made a resume
    take each one (100,000 lines: 12 s and 100,000 trace records; a million: killed). A session
    takes at most ``MAX_LIVE_INSTRUCTIONS``; then ``instruct_nowait`` says no, and the reader stops."""
    from storyteller.orchestrator.session.instruction_queue import MAX_LIVE_INSTRUCTIONS, InstructionQueue

    queue = InstructionQueue([], live=True)
    assert all(queue.instruct_nowait(f"go {i}", "viewer") for i in range(MAX_LIVE_INSTRUCTIONS))
    assert not queue.instruct_nowait("one too many", "viewer")
    assert not queue.instruct_nowait("and another", "stdin")
    due = queue.due(5)
    assert len(due) == MAX_LIVE_INSTRUCTIONS and due[-1][0].text == f"go {MAX_LIVE_INSTRUCTIONS - 1}"

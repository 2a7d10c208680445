"""What a command prints about a failure is one line, and nothing from a file reaches the terminal
raw: ``fail()`` joins a message's lines; a ``run`` prints its thread id (given on the command line,
or read back from ``run.json``) with control and bidi characters as escapes; a crafted checkpoint
whose dataclass field has the wrong type is one ``error:`` line and exit 2 on ``resume``, not a
run that stops with exit 1; a script line past the end of the run is said, not silently dropped.
"""

from __future__ import annotations

import hashlib
import pickletools
import shutil
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.cli.options import fail
from storyteller.orchestrator.safe_text import one_line
from tests.support.finished_run import one_error_line, resume
from tests.support.hostile_files import unsafe_characters
from tests.support.story_planner import RUN, Planner, write_config


def test_one_line_joins_every_kind_of_line_break_and_escapes_controls() -> None:
    assert one_line("a\n  b\r\nc\u2028d\u2029e\x85f\x0bg\n\n") == "a b c d e f g"
    assert one_line("red \x1b[31m\u202e") == "red \\x1b[31m\\u202e"


def test_fail_prints_one_line_whatever_the_message_holds() -> None:
    tiny = typer.Typer()

    @tiny.command()
    def go() -> None:
        fail("file.json: line 3:\n  expected a number,\n\u2028got '\x1b[2J'")

    result = CliRunner().invoke(tiny, [])
    assert result.exit_code == 2
    assert result.stderr == "error: file.json: line 3: expected a number, got '\\x1b[2J'\n"



def _with_steps(snapshot: bytes, value: bytes) -> bytes:
    """``snapshot`` with its checkpoint's ``steps`` (an int) replaced by the pickled ``value``, the
    checksum made to match: a crafted file, not a damaged one."""
    payload = snapshot[snapshot.index(b"\n") + 1:]
    frames = [pos for op, _, pos in pickletools.genops(payload) if op.name == "FRAME" and pos is not None]
    for pos in reversed(frames):
        payload = payload[:pos] + payload[pos + 9:]
    key = b"\x8c\x05steps\x94"
    at = payload.index(key) + len(key)
    assert payload[at:at + 1] == b"K"  # BININT1: the step count
    payload = payload[:at] + value + payload[at + 2:]
    return b"storyteller-snapshot 6 sha256=%s\n" % hashlib.sha256(payload).hexdigest().encode() + payload


@pytest.mark.parametrize(("value", "named"), [(b"\x8c\x04many", "str"), (b"N", "NoneType"), (b"]", "list")],
                         ids=["str", "None", "list"])
@pytest.mark.slow
def test_resume_refuses_a_checkpoint_with_a_wrong_typed_dataclass_field(finished_run: Path, tmp_path: Path,
                                                                       value: bytes, named: str) -> None:
    run = Path(shutil.copytree(finished_run, tmp_path / "run", symlinks=True))
    snapshot = run / "session.snapshot"
    snapshot.write_bytes(_with_steps(snapshot.read_bytes(), value))
    line = one_error_line(resume(run), str(snapshot), "SessionCheckpoint whose field steps is a")
    assert f"is a {named}, not int" in line


def test_resume_of_the_checkpoint_with_the_right_type_goes_on(finished_run: Path, tmp_path: Path) -> None:
    """The splice itself keeps a checkpoint that loads (so the refusals above are the type's)."""
    run = Path(shutil.copytree(finished_run, tmp_path / "run", symlinks=True))
    snapshot = run / "session.snapshot"
    snapshot.write_bytes(_with_steps(snapshot.read_bytes(), b"K\x02"))
    result = resume(run)
    assert result.exit_code == 0, result.stderr


@pytest.mark.slow
def test_a_run_warns_of_script_lines_past_its_end_and_prints_its_thread_id_escaped(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    script = tmp_path / "script.txt"
    script.write_text("00:00.5 Zoe sits down\n00:01 Max waves\n00:30 Zoe leaves\n", encoding="utf-8")
    monkeypatch.setenv("FAKE_PROVIDER_KEY", "sk-test-123")
    for var in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL"):
        monkeypatch.delenv(var, raising=False)
    with FakeOpenAI(responder=Planner()) as fake:
        cfg = write_config(tmp_path, fake.base)
        result = CliRunner().invoke(app, [*RUN, "-d", "1", "--max-events", "1", "--config", str(cfg),
                                          "--instructions", str(script), "--thread-id", "t\x1b]0;x\x07\u202e",
                                          "--out", str(tmp_path / "run"), "--no-live"])
    assert result.exit_code == 0, result.stderr
    assert not unsafe_characters(result.stdout + result.stderr), result.stderr
    warnings = [line for line in result.stderr.splitlines() if line.startswith("warning: ")]
    assert warnings == [
        f"warning: {script}: 2 instruction(s) at or after 1 s, the end of the run (--duration), never take effect "
        "(the first: 1 s 'Max waves')"
    ]
    assert any(line.startswith("thread t\\x1b]0;x\\x07\\u202e") for line in result.stderr.splitlines()), result.stderr
    assert "[    0.5s] instruction (script): Zoe sits down" in result.stdout

"""A damaged run folder is one line naming the damaged file, never a traceback.

One short run (fake OpenAI server on 127.0.0.1) makes a folder; each test copies it and
damages one file: ``runs.sqlite`` (garbage, cut in half), ``trace.jsonl`` (a bad line in the
middle, binary garbage, a last line cut short), ``session.snapshot``. ``storyteller resume``
and ``storyteller replay`` then exit with code 2 and one ``error:`` line naming the file; only
``resume`` goes on from a trace whose last line was cut (what a kill -9 leaves), without that
line (a replay would tell a shorter story, so it refuses).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner, Result

from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.orchestrator.cli.app import app
from tests.support.finished_run import one_error_line
from tests.support.story_planner import RUN, Planner, write_config


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    tmp = tmp_path_factory.mktemp("finished")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FAKE_PROVIDER_KEY", "sk-test-123")
        for var in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL"):
            mp.delenv(var, raising=False)
        with FakeOpenAI(responder=Planner()) as fake:
            cfg = write_config(tmp, fake.base)
            result = CliRunner().invoke(app, [*RUN, "-d", "3", "--max-events", "2", "--config", str(cfg),
                                              "--out", str(tmp / "run")])
            assert result.exit_code == 0, result.stderr
        yield tmp / "run"



def resume(run_dir: Path) -> Result:
    return CliRunner().invoke(app, ["resume", str(run_dir), "--no-interactive"])


def replay(run_dir: Path, out: Path) -> Result:
    return CliRunner().invoke(app, ["replay", str(run_dir), "--out", str(out)])


def test_garbage_runs_sqlite_on_resume(run_dir: Path) -> None:
    (run_dir / "runs.sqlite").write_bytes(b"this is not a database\n" * 100)
    one_error_line(resume(run_dir), str(run_dir / "runs.sqlite"), "not a readable checkpoint database")


def test_runs_sqlite_cut_in_half_on_resume(run_dir: Path) -> None:
    db = run_dir / "runs.sqlite"
    data = db.read_bytes()
    db.write_bytes(data[: len(data) // 2])
    one_error_line(resume(run_dir), str(db))


def test_runs_sqlite_with_a_damaged_page_on_resume(run_dir: Path) -> None:
    db = run_dir / "runs.sqlite"
    data = bytearray(db.read_bytes())
    page = 4096
    data[page: 2 * page] = b"\xff" * page  # the second page (a b-tree page) overwritten
    db.write_bytes(bytes(data))
    one_error_line(resume(run_dir), str(db))


def corrupt_middle_line(trace: Path) -> int:
    lines = trace.read_bytes().splitlines(keepends=True)
    lines[2] = b'{"kind": "attempt", "seq": "not a number"}\n'
    trace.write_bytes(b"".join(lines))
    return 3


@pytest.mark.parametrize("command", ["resume", "replay"])
def test_a_corrupt_trace_line(run_dir: Path, tmp_path: Path, command: str) -> None:
    line = corrupt_middle_line(run_dir / "trace.jsonl")
    result = resume(run_dir) if command == "resume" else replay(run_dir, tmp_path / "again")
    one_error_line(result, f"{run_dir / 'trace.jsonl'}: line {line}: corrupt trace record")


@pytest.mark.parametrize("command", ["resume", "replay"])
def test_a_binary_trace(run_dir: Path, tmp_path: Path, command: str) -> None:
    (run_dir / "trace.jsonl").write_bytes(bytes(range(256)) * 8 + b"\n")
    result = resume(run_dir) if command == "resume" else replay(run_dir, tmp_path / "again")
    one_error_line(result, f"{run_dir / 'trace.jsonl'}: line 1")


def test_a_garbage_session_snapshot_on_resume(run_dir: Path) -> None:
    (run_dir / "session.snapshot").write_bytes(b"\x80\x04garbage")
    one_error_line(resume(run_dir), str(run_dir / "session.snapshot"), "cannot read the session checkpoint")


def test_a_garbage_run_json(run_dir: Path, tmp_path: Path) -> None:
    (run_dir / "run.json").write_text("{not json", encoding="utf-8")
    one_error_line(resume(run_dir), str(run_dir / "run.json"))
    one_error_line(replay(run_dir, tmp_path / "again"), str(run_dir / "run.json"))


def test_a_trace_cut_mid_line_is_what_a_kill_leaves_and_resume_goes_on(run_dir: Path) -> None:
    trace = run_dir / "trace.jsonl"
    data = trace.read_bytes()
    trace.write_bytes(data + data.splitlines(keepends=True)[1][:50])  # a record cut short at the end
    result = resume(run_dir)
    assert result.exit_code == 0, result.stderr
    assert "trace_tail_truncated" in result.stderr and str(trace) in result.stderr  # said so, in one log line
    assert trace.read_bytes().startswith(data) and trace.read_bytes().endswith(b"\n")


def test_replay_of_a_trace_cut_mid_line_is_refused_not_shortened(run_dir: Path, tmp_path: Path) -> None:
    trace = run_dir / "trace.jsonl"
    lines = trace.read_bytes().splitlines(keepends=True)
    trace.write_bytes(b"".join(lines[:-2]) + lines[-2][:40])  # the last record lost, the one before cut
    one_error_line(replay(run_dir, tmp_path / "again"), f"{trace}: line {len(lines) - 1} is cut short")

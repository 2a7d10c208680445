"""Program files are bounded before the worker: ``storyteller event-program`` refuses a program
file above ``MAX_PROGRAM_FILE_BYTES`` (a 400 MiB file used 1.3 GB and ended in "worker process
died"), and ``WorkerRunner`` refuses a text above the sandbox's ``source_chars`` before
framing it for a worker (none is started)."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.cli.event_program import MAX_PROGRAM_FILE_BYTES
from storyteller.orchestrator.sandbox_worker import WorkerRunner
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.tools.character_states import WorldView
from storyteller.tools.sandbox import Budget, BudgetExceededError
from tests.support.finished_run import one_error_line


def test_a_400_mib_program_file_is_one_line(tmp_path: Path) -> None:
    program = tmp_path / "huge.py"
    with program.open("wb") as f:  # sparse: no disk used
        f.truncate(400 * 2**20)
    result = CliRunner().invoke(app, ["event-program", "home", "--program", str(program)])
    assert f"{MAX_PROGRAM_FILE_BYTES}" in one_error_line(result, "program file")


def test_a_program_file_that_is_not_utf8_or_not_a_file(tmp_path: Path) -> None:
    program = tmp_path / "latin1.py"
    program.write_bytes(b"def parse_event():\n    x = '\xff'\n")
    one_error_line(CliRunner().invoke(app, ["event-program", "home", "--program", str(program)]), "UTF-8")
    one_error_line(CliRunner().invoke(app, ["event-program", "home", "--program", str(tmp_path)]), "folder")


def test_states_nested_too_deep_is_one_line(tmp_path: Path) -> None:
    program = tmp_path / "p.py"
    program.write_text("def parse_event():\n    pass\n", encoding="utf-8")
    states = tmp_path / "states.json"
    states.write_text("[" * 100_000 + "]" * 100_000, encoding="utf-8")
    result = CliRunner().invoke(app, ["event-program", "home", "--program", str(program), "--states", str(states)])
    one_error_line(result, "nested")


def test_the_worker_runner_refuses_a_text_above_the_budget_before_starting_a_worker() -> None:
    runner = WorkerRunner()
    source = "def parse_event():\n" + "    x = 1\n" * (Budget().source_chars // 10 + 1)
    with pytest.raises(BudgetExceededError, match="characters"):
        runner(load_bundled_scene("home"), source, WorldView(), seed=0)
    assert runner.process is None and runner.starts == 0

"""``storyteller plan``'s own files are untrusted input too (issue 22), found by
``benchmark/hostile_inputs.py``: a ``--runs-db`` that is a FIFO was a ``sqlite3`` traceback, and
a ``--prompts`` folder was read file by file as planning needed them (after the ``thread`` line:
two lines, exit 1; a prompt file of bytes that are not UTF-8 a traceback; its size unbounded).
Now the folder's files are all read first, bounded (``storyteller.agents.prompt_templates.MAX_PROMPT_BYTES``),
and either is one ``error:`` line, exit 2, before anything runs."""

from __future__ import annotations

import os
import shutil
from importlib import resources
from pathlib import Path

from typer.testing import CliRunner, Result

from storyteller.agents.prompt_templates import MAX_PROMPT_BYTES
from storyteller.orchestrator.cli.app import app
from tests.support.finished_run import one_error_line


def _plan(*args: str) -> Result:
    return CliRunner().invoke(app, ["plan", "home", *args])


def _prompts(tmp_path: Path) -> Path:
    folder = tmp_path / "prompts"
    shutil.copytree(str(resources.files("storyteller.prompts")), folder, ignore=shutil.ignore_patterns("__pycache__", "*.py"))
    return folder


def test_a_prompt_folder_with_a_bad_file_is_one_line_before_planning(tmp_path: Path) -> None:
    folder = _prompts(tmp_path)
    system = folder / "narrator" / "system.md"
    system.write_bytes(b"\xff\xfe rules")
    one_error_line(_plan("--prompts", str(folder), "--runs-db", ":memory:"), "narrator/system.md", "not UTF-8")
    system.unlink()
    os.mkfifo(system)  # never opened for reading: no hang
    one_error_line(_plan("--prompts", str(folder), "--runs-db", ":memory:"), "narrator/system.md", "not found")
    system.unlink()
    system.write_bytes(b"a" * (MAX_PROMPT_BYTES + 1))
    one_error_line(_plan("--prompts", str(folder), "--runs-db", ":memory:"), "narrator/system.md", "more than")
    system.unlink()
    one_error_line(_plan("--prompts", str(folder), "--runs-db", ":memory:"), "narrator/system.md", "not found")


def test_a_runs_db_that_is_not_a_database_is_one_line(tmp_path: Path) -> None:
    fifo = tmp_path / "runs.sqlite"
    os.mkfifo(fifo)
    one_error_line(_plan("--runs-db", str(fifo)), "--runs-db", "not a regular file")
    fifo.unlink()
    fifo.write_bytes(b"not a database\n" * 100)
    replay = Path(__file__).resolve().parents[3] / "traces" / "plan_home_2events.jsonl"
    result = _plan("--runs-db", str(fifo), "--replay", str(replay))
    assert "Traceback" not in result.stderr and result.exit_code == 2, result.stderr
    assert "cannot use the checkpoint database" in result.stderr

"""The event-program worker's stderr is data (issue 22): what it writes never reaches the
terminal's stderr raw; it is drained (a worker writing a megabyte is not blocked), bounded, and
logged escaped when the worker stops, whether it crashed while starting or ran programs.

The worker is made to write hostile bytes (ESC[31m, BEL, U+202E, U+2028, bytes that are not
UTF-8, a fake traceback) by a ``sitecustomize`` module on its ``PYTHONPATH`` (which it inherits).
Before the worker's stderr was a pipe, both tests failed: the bytes reached the test's own
stderr (file descriptor 2) raw.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from pathlib import Path
from typing import Any

import pytest
from structlog.testing import capture_logs

from storyteller.orchestrator.sandbox_worker import WorkerRunner
from storyteller.orchestrator.stderr_tail import KEPT_BYTES
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.tools.character_states import WorldView
from storyteller.tools.errors import EventProgramError
from tests.support.hostile_files import unsafe_characters

HOSTILE = "x\x1b[31my\x07z\u202ew\u2028v".encode() + b"\xff\xfe"
SHOWN = "x\\x1b[31my\\x07z\\u202ew\\u2028v\\xff\\xfe"
LAST = b"Traceback (most recent call last):\nRuntimeError: the end \x1b]0;title\x07\n"
PLACE = "def parse_event():\n    get_character('Mia').set_position(get_area_adjacent_to('fridge_1'))\n"
WRITTEN = 20_000 * len(HOSTILE) + len(LAST)  # over a megabyte: more than a pipe holds


def _worker_writes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, *, then_exit: bool) -> None:
    """The next worker writes ``HOSTILE`` 20,000 times and ``LAST`` to stderr as it starts
    (and exits with status 3, if ``then_exit``)."""
    (tmp_path / "sitecustomize.py").write_text(
        "import os\n"
        f"os.write(2, {HOSTILE!r} * 20_000 + {LAST!r})\n"
        + ("os._exit(3)\n" if then_exit else ""),
        encoding="utf-8",
    )
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in (str(tmp_path), os.environ.get("PYTHONPATH")) if p))


def _logged(logs: list[MutableMapping[str, Any]]) -> MutableMapping[str, Any]:
    (record,) = [r for r in logs if r["event"] == "the event-program worker wrote to stderr"]
    text = str(record["text"])
    assert unsafe_characters(text) == [], text[-200:]
    assert SHOWN in text and text.endswith("RuntimeError: the end \\x1b]0;title\\x07\n"), text[-200:]
    assert record["bytes_written"] == WRITTEN
    assert record["bytes_shown"] == KEPT_BYTES
    assert len(text) < 4 * KEPT_BYTES  # bounded: the tail only, each byte at most \xNN
    return record


def test_a_worker_that_writes_to_stderr_runs_programs_and_its_stderr_is_logged_escaped(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    _worker_writes(tmp_path, monkeypatch, then_exit=False)
    scene = load_bundled_scene("home")
    with capture_logs() as logs, WorkerRunner() as run:  # the worker stops (and is logged) first
        assert len(run(scene, PLACE, WorldView(), seed=0)) == 1
    captured = capfd.readouterr()
    assert "\x1b" not in captured.err + captured.out and "\u202e" not in captured.err
    assert _logged(logs)["exit_code"] == -9  # stopped by close()


def test_a_worker_that_crashes_while_starting_is_one_error_and_its_stderr_is_logged_escaped(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    _worker_writes(tmp_path, monkeypatch, then_exit=True)
    scene = load_bundled_scene("home")
    with capture_logs() as logs, WorkerRunner() as run, pytest.raises(EventProgramError, match="did not start"):
        run(scene, PLACE, WorldView(), seed=0)
    captured = capfd.readouterr()
    assert "\x1b" not in captured.err + captured.out and "\u202e" not in captured.err
    assert _logged(logs)["exit_code"] == 3

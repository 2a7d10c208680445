"""An attack that declares ``Spec.stdin`` gets it: ``run_command`` gives the attacked command
those bytes on its stdin (and ``/dev/null`` when an attack declares none).

The attacked command is replaced by a small Python program that echoes what it read on stdin.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from storyteller.benchmark.hostile import judging

ECHO = [sys.executable, "-c", "import sys; data = sys.stdin.buffer.read(); print(len(data), data[:64].hex())"]


@pytest.fixture
def echo(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(judging, "CLI", ECHO)


def _env() -> dict[str, str]:
    return {name: os.environ[name] for name in ("PATH", "HOME") if name in os.environ}


@pytest.mark.usefixtures("echo")
@pytest.mark.parametrize("data", [b"sit down\n\xff\x00" + "\u202e".encode(), b"x" * (4 << 20)])
def test_an_attack_s_stdin_reaches_the_command(tmp_path: Path, data: bytes) -> None:
    run = judging.run_command([], 120.0, _env(), tmp_path, data)
    assert run.code == 0, run.stderr
    assert run.stdout.split() == [str(len(data)), data[:64].hex()]


@pytest.mark.usefixtures("echo")
def test_no_stdin_is_an_empty_one(tmp_path: Path) -> None:
    run = judging.run_command([], 120.0, _env(), tmp_path)
    assert run.code == 0, run.stderr
    assert run.stdout.split() == ["0"]

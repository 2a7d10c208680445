"""A short finished ``storyteller run`` folder (the scripted story against the fake OpenAI
server on 127.0.0.1) and the commands and checks that tests of damaged or hostile run folders
share: ``resume`` / ``replay`` through the CLI, and "one ``error:`` line, exit 2, no traceback".
"""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner, Result

from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.orchestrator.cli.app import app
from tests.support.story_planner import RUN, Planner, write_config


def make_finished_run(tmp: Path, *, seconds: int = 3, max_events: int = 2) -> Path:
    """Run the scripted story into ``tmp / "run"`` and return that folder."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FAKE_PROVIDER_KEY", "sk-test-123")
        for var in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL"):
            mp.delenv(var, raising=False)
        with FakeOpenAI(responder=Planner()) as fake:
            cfg = write_config(tmp, fake.base)
            result = CliRunner().invoke(app, [*RUN, "-d", str(seconds), "--max-events", str(max_events),
                                              "--config", str(cfg), "--out", str(tmp / "run")])
            assert result.exit_code == 0, result.stderr
    return tmp / "run"


def resume(run_dir: Path) -> Result:
    return CliRunner().invoke(app, ["resume", str(run_dir), "--no-interactive"])


def replay(source: Path, out: Path) -> Result:
    return CliRunner().invoke(app, ["replay", str(source), "--out", str(out)])


def one_error_line(result: Result, *needles: str, code: int = 2) -> str:
    """The command exited with ``code`` after exactly one ``error:`` line holding ``needles``."""
    assert result.exit_code == code, (result.exit_code, result.stderr)
    assert isinstance(result.exception, SystemExit), result.exception  # exited, did not crash
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in result.stderr, result.stderr
    for needle in needles:
        assert needle in errors[0], errors[0]
    return errors[0]

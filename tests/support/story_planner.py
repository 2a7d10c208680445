"""A scripted planner for whole ``storyteller run`` tests against the fake OpenAI server
(``benchmark/support/fake_openai_server.py``): the unified planner (``--planner unified
--description object-list``, one LLM role) is answered by request content, so a stopped and
resumed run gets the same answers as an uninterrupted one, and faults are injected by request
number. Used by ``tests/orchestrator/session/test_run_faults.py`` and ``tests/orchestrator/session/test_run_corrupt_files.py``.
"""

from __future__ import annotations

import re
import threading
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.orchestrator.cli.app import app

RUN = ["run", "home", "--names", "Zoe,Max", "--planner", "unified", "--description", "object-list", "--raw-feet",
       "--no-interactive"]
"""``storyteller run`` arguments of the scripted story (add ``-d``, ``--max-events``, ``--config``, ``--out``)."""

TASKS = {"Zoe": ("coffee_maker_1", "use_coffee_maker"), "Max": ("microwave_1", "use_microwave")}


def interact_program(name: str, obj: str, action: str, var: str = "a") -> str:
    """The reply of a model placing ``name`` to interact with ``obj`` doing ``action``."""
    return (
        f'```python\ndef parse_event():\n    {var} = get_character("{name}")\n'
        f'    {var}.set_position(get_area_to_interact_with("{obj}"))\n'
        f'    {var}.set_orientation("{obj}")\n    {var}.set_target_action("{action}")\n```'
    )


def program(name: str) -> str:
    obj, action = TASKS[name]
    return interact_program(name, obj, action)


def first_free(body: dict[str, Any]) -> str:
    """The program for the first free character of the request (a retry's feedback comes after it)."""
    asked = [m["content"] for m in body["messages"] if "Free characters: " in m["content"]]
    free = re.findall(r"Free characters: (.*)", asked[-1])
    return program(free[-1].split(",")[0].strip())


class Planner:
    """Answers by content. ``faults`` maps a 1-based request number to an action played
    instead (``("status", 500)``, ``("sleep", s)``); request ``block_at`` waits until
    ``release`` is set (``arrived`` tells the test it came in)."""

    def __init__(self, faults: dict[int, Any] | None = None, block_at: int | None = None) -> None:
        self.faults = faults or {}
        self.block_at = block_at
        self.count = 0
        self.arrived = threading.Event()
        self.release = threading.Event()

    def __call__(self, body: dict[str, Any]) -> Any:
        self.count += 1
        if self.count in self.faults:
            return self.faults[self.count]
        if self.block_at is not None and self.count == self.block_at:
            self.arrived.set()
            self.release.wait(60)  # the client is stopped meanwhile; nobody reads this answer
        return first_free(body)


def write_config(tmp_path: Path, api_base: str, *, attempts: int = 1, timeout_s: float = 20.0) -> Path:
    path = tmp_path / "fake.toml"
    path.write_text(
        f'[llm]\nmodel = "openai/fake"\napi_base = "{api_base}"\napi_key_env = "FAKE_PROVIDER_KEY"\n'
        f"timeout_s = {timeout_s}\n[llm.retry]\nmax_attempts = {attempts}\nbackoff_base_s = 0.05\n"
        "backoff_max_s = 0.1\n",
        encoding="utf-8",
    )
    return path


def recorded_home_run(tmp: Path, programs: list[str], *, seconds: int, max_events: int) -> Path:
    """A ``run`` of two characters in ``home`` (unified planner, object-list description) whose
    planner replies are ``programs`` from a scripted provider on 127.0.0.1; its run folder."""
    with pytest.MonkeyPatch.context() as mp, FakeOpenAI(default='{"error": "no script"}') as fake:
        mp.setenv("FAKE_PROVIDER_KEY", "sk-test-123")
        mp.setenv("STORYTELLER_CACHE_DIR", str(tmp / "cache"))
        for var in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL", "STORYTELLER_PLANNER_MODEL"):
            mp.delenv(var, raising=False)
        cfg = tmp / "fake.toml"
        cfg.write_text(
            f'[llm]\napi_base = "{fake.base}"\napi_key_env = "FAKE_PROVIDER_KEY"\ntimeout_s = 10.0\n'
            '[llm.retry]\nmax_attempts = 1\n[nodes.planner]\nmodel = "openai/fake-planner"\n',
            encoding="utf-8",
        )
        fake.script["fake-planner"] = list(programs)
        args = ["run", "home", "-n", "2", "-d", str(seconds), "--max-events", str(max_events), "--planner", "unified",
                "--description", "object-list", "--config", str(cfg), "--out", str(tmp / "run")]  # fmt: skip
        result = CliRunner().invoke(app, args, catch_exceptions=False)
    assert result.exit_code == 0, result.stderr
    return tmp / "run"

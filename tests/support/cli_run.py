"""The CLI run of the run-folder tests: the command line, the scripted planner answering the
fake OpenAI-compatible server by content, and its config file."""

from __future__ import annotations

import re
import sys
import threading
import time
from pathlib import Path
from typing import Any

from tests.support.story_planner import interact_program

ROOT = Path(__file__).resolve().parents[2]
TASKS = {"Zoe": ("coffee_maker_1", "use_coffee_maker"), "Max": ("toaster_1", "use_toaster")}


def program(name: str) -> str:
    obj, action = TASKS[name]
    return interact_program(name, obj, action)


class Planner:
    """Answers the unified planner by content: the first free character uses its appliance.
    ``delay_s`` slows every answer; ``arrived`` is set when request ``kill_at`` (1-based) comes in."""

    def __init__(self, delay_s: float = 0.0, kill_at: int | None = None) -> None:
        self.delay_s = delay_s
        self.kill_at = kill_at
        self.count = 0
        self.arrived = threading.Event()

    def __call__(self, body: dict[str, Any]) -> str:
        self.count += 1
        if self.kill_at is not None and self.count >= self.kill_at:
            self.arrived.set()
            time.sleep(5.0)  # the client is killed meanwhile; nobody reads this answer
        elif self.delay_s:
            time.sleep(self.delay_s)
        text = body["messages"][-1]["content"]
        free = re.search(r"Free characters: (.*)", text)
        assert free is not None, text
        first = free.group(1).split(",")[0].strip()
        return program(first)


def write_config(tmp_path: Path, api_base: str) -> Path:
    path = tmp_path / "fake.toml"
    path.write_text(
        f'[llm]\nmodel = "openai/fake"\napi_base = "{api_base}"\napi_key_env = "FAKE_PROVIDER_KEY"\ntimeout_s = 20.0\n'
        "[llm.retry]\nmax_attempts = 1\n",
        encoding="utf-8",
    )
    return path


RUN = ["run", "home", "--names", "Zoe,Max", "-d", "30", "--planner", "unified", "--description", "object-list"]


def cli(*args: str) -> list[str]:
    return [sys.executable, "-c", "from storyteller.orchestrator.cli.app import main; main()", *args]

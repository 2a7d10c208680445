"""A scripted unified planner for the benchmarks that time a story without a model
(``bench_frame_interval``, ``bench_replay``): served by ``benchmark/support/fake_openai_server.py``,
it answers every call after a fixed latency with an event program for the first free character
the prompt lists."""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from typing import Any


class ScriptedPlanner:
    """After ``latency_s`` seconds (the model's latency), ``answer(name, calls)``: the reply for
    ``name``, the first character after "Free characters:" in the last message (``default`` when
    there is none), on the ``calls``-th call."""

    def __init__(self, latency_s: float, answer: Callable[[str, int], str], default: str) -> None:
        self.latency_s = latency_s
        self.answer = answer
        self.default = default
        self.calls = 0

    def __call__(self, body: dict[str, Any]) -> str:
        self.calls += 1
        time.sleep(self.latency_s)
        free = re.search(r"Free characters: (.*)", body["messages"][-1]["content"])
        name = free.group(1).split(",")[0].strip() if free else self.default
        return self.answer(name, self.calls)

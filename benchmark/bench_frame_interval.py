"""Frame intervals of a real-time story while the planner works: off the loop vs on the loop.

A ``realtime`` run (speed 1) of 20 characters in the home scene, planned by a fake
OpenAI-compatible provider on 127.0.0.1 (``tests/support/fake_openai_server.py``) that takes
``--latency`` seconds (default 5) per call and answers every call with an event program for the
first free character. Event programs run in the worker process, as in ``storyteller run``.

Two runs, same arguments: ``off-loop`` (the product: event programs, the parser's input and
position sampling run in a worker thread, ``orchestrator.planning.graph.off_loop``) and
``on-loop`` (the baseline: the same work called inline on the event loop, as before). Prints the
p50 / p99 / max wall-clock interval between frames of each (target at 30 fps: 33.3 ms; the
goal is p99 < 40 ms) and their ratio. Not a test: timings depend on the machine and its load.

    python -m benchmark.bench_frame_interval [--duration 40] [--latency 5]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import re
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from tests.support.fake_openai_server import FakeOpenAI

_T = TypeVar("_T")
SPOTS = ("bookshelf_1", "couch_1", "tv_1", "coffee_maker_1", "toaster_1", "fridge_1")


def program(name: str, k: int) -> str:
    return (
        f'```python\ndef parse_event():\n    c = get_character("{name}")\n'
        f'    c.set_position(get_area_close_to("{SPOTS[k % len(SPOTS)]}"))\n'
        '    c.set_target_action("use_smartphone")\n```'
    )


class Responder:
    """Unified planner: the first free character uses a smartphone near one of a few objects."""

    def __init__(self, latency_s: float) -> None:
        self.latency_s = latency_s
        self.count = 0

    def __call__(self, body: dict[str, Any]) -> str:
        import time

        self.count += 1
        time.sleep(self.latency_s)
        text = body["messages"][-1]["content"]
        free = re.search(r"Free characters: (.*)", text)
        first = free.group(1).split(",")[0].strip() if free else "Ava"
        return program(first, self.count)


async def _inline(fn: Callable[[], _T]) -> _T:
    return fn()


def run_once(mode: str, duration: float, latency: float, tmp: Path) -> tuple[np.ndarray, int]:
    from orchestrator.planning import graph
    from orchestrator.session.roster import character_names
    from orchestrator.session.run_job import run_story
    from orchestrator.session.run_manifest import RunArguments
    from sim.scene.bundled import resolve_scene

    os.environ["FAKE_PROVIDER_KEY"] = "sk-bench"
    responder = Responder(latency)
    original = graph.off_loop
    with FakeOpenAI(responder=responder) as fake:
        cfg = tmp / f"{mode}.toml"
        cfg.write_text(
            f'[llm]\nmodel = "openai/fake"\napi_base = "{fake.base}"\napi_key_env = "FAKE_PROVIDER_KEY"\n'
            "timeout_s = 60.0\n[llm.retry]\nmax_attempts = 1\n",
            encoding="utf-8",
        )
        args = RunArguments(
            scene="home", names=tuple(character_names(20)), duration=duration, pace="realtime", speed=1.0,
            config=str(cfg), planner="unified", description="object-list", planners=1,
        )
        out = tmp / mode
        out.mkdir()
        if mode == "on-loop":
            graph.off_loop = _inline  # the baseline: work on the event loop
        try:
            result = asyncio.run(run_story(resolve_scene("home"), args, out=out, trace_path=out / "trace.jsonl",
                                           replay=None)).result
        finally:
            graph.off_loop = original
    return np.asarray(result.frame_intervals_s[1:]) * 1000.0, result.steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=40.0, help="Simulated (= wall) seconds per run.")
    parser.add_argument("--latency", type=float, default=5.0, help="Seconds the fake provider takes per call.")
    ns = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rows = {}
        for mode in ("on-loop", "off-loop"):
            ms, steps = run_once(mode, ns.duration, ns.latency, Path(tmp))
            rows[mode] = (np.percentile(ms, 50), np.percentile(ms, 99), ms.max(), steps, len(ms))
    print(f"realtime, 20 characters, {ns.latency:g} s per LLM call, {ns.duration:g} s per run")
    print(f"{'mode':9} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'steps':>6} {'frames':>7}")
    for mode, (p50, p99, mx, steps, n) in rows.items():
        print(f"{mode:9} {p50:8.1f} {p99:8.1f} {mx:8.1f} {steps:6d} {n:7d}")
    base, new = rows["on-loop"], rows["off-loop"]
    print(f"p99 off-loop / on-loop: {new[1] / base[1]:.2f}; max: {new[2] / base[2]:.2f}; "
          f"target p99 < 40 ms: {'met' if new[1] < 40.0 else 'not met'}")


if __name__ == "__main__":
    main()

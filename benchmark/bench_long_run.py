"""A long story at fast pace with a fake provider: does memory stay bounded?

Runs ``storyteller run``'s job in this process (``run_story``, then optionally
``write_outputs``) on the bundled home scene with four characters, the unified planner and an
OpenAI-compatible fake provider on 127.0.0.1 (``benchmark/support/fake_openai_server.py``) that
answers every request at once, forever: each free character in turn walks to an appliance
and uses it, so events keep coming for as long as the story runs. Every simulated
``--every`` minutes (at the first story event after the mark) it prints the simulated time,
events so far, the process's current RSS and its peak RSS (``ru_maxrss``), then the same at
the end of the story. The motion streams to ``motion/*.chunks`` in the output folder, which
is what keeps the world's memory flat; a story that kept every frame in memory would grow by
about 0.85 KB per character-frame (4 characters: ~6 MB per simulated minute).

    nice -n 19 python -m storyteller.benchmark.bench_long_run --minutes 120          # the 2-hour story
    nice -n 19 python -m storyteller.benchmark.bench_long_run --minutes 20 --export  # and write the exports

Target (issue 11): peak RSS < 1 GiB over a 2-hour story, and flat after the first minutes.
``--export`` also writes the run's files (``story.json`` ... npz, BVH, GLB, top-down PNG) and
prints the peak after them: the exporters read the chunk files one character at a time.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import re
import resource
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

# Per character, the appliances it uses in turn (object, action).
ERRANDS: dict[str, tuple[tuple[str, str], ...]] = {
    "Zoe": (("coffee_maker_1", "use_coffee_maker"), ("fridge_1", "open_fridge")),
    "Max": (("toaster_1", "use_toaster"), ("tv_1", "turn_on_tv")),
    "Ivy": (("microwave_1", "use_microwave"), ("record_player_1", "turn_on_record_player")),
    "Leo": (("dishwasher_1", "use_dishwasher"), ("cabinet_2", "open_cabinet")),
}


class Responder:
    """The fake provider's answer to the unified planner: the first free character does its next
    errand (a program for the event parser's sandbox)."""

    def __init__(self) -> None:
        self.turns: dict[str, int] = {}
        self.requests = 0

    def __call__(self, body: dict[str, Any]) -> str:
        self.requests += 1
        text = body["messages"][-1]["content"]
        free = re.search(r"Free characters: (.*)", text)
        if free is None:
            raise ValueError("the request names no free characters")
        name = free.group(1).split(",")[0].strip()
        turn = self.turns.get(name, 0)
        self.turns[name] = turn + 1
        obj, action = ERRANDS[name][turn % len(ERRANDS[name])]
        return (
            f'```python\ndef parse_event():\n    a = get_character("{name}")\n'
            f'    a.set_position(get_area_to_interact_with("{obj}"))\n'
            f'    a.set_orientation("{obj}")\n    a.set_target_action("{action}")\n```'
        )


def rss_mib() -> tuple[float, float]:
    """(current RSS, peak RSS) of this process in MiB."""
    current = 0.0
    with open("/proc/self/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                current = int(line.split()[1]) / 1024.0
    return current, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=120.0, help="simulated minutes of story (default 120)")
    parser.add_argument("--every", type=float, default=10.0, help="simulated minutes between two reports")
    parser.add_argument("--export", action="store_true", help="also write the run's files and report after them")
    parser.add_argument("--out", type=Path, default=None, help="run folder (default: a temporary one)")
    parser.add_argument("--pace", choices=("fast", "offline", "lockstep"), default="fast",
                        help="fast (default, as the issue measures it), or offline / lockstep: the same events "
                             "whatever the machine's speed")
    opts = parser.parse_args(argv)
    if opts.minutes <= 0 or opts.every <= 0:
        parser.error("--minutes and --every must be > 0")

    from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
    from storyteller.orchestrator.session.run_job import run_story
    from storyteller.orchestrator.session.run_manifest import RunArguments
    from storyteller.orchestrator.session.run_outputs import write_outputs
    from storyteller.orchestrator.session.session_types import StoryEvent
    from storyteller.sim.scene.bundled import load_bundled_scene

    with tempfile.TemporaryDirectory(prefix="bench_long_run_") as tmp:
        out = opts.out if opts.out is not None else Path(tmp) / "run"
        out.mkdir(parents=True, exist_ok=True)
        responder = Responder()
        scene = load_bundled_scene("home")
        rows: list[tuple[float, int, float, float]] = []
        start = time.perf_counter()
        next_mark = opts.every
        events = 0
        print(f"{'simulated':>10} {'events':>7} {'wall s':>8} {'RSS MiB':>8} {'peak MiB':>9}", flush=True)

        def report(sim_min: float, label: str = "") -> None:
            cur, peak = rss_mib()
            rows.append((sim_min, events, cur, peak))
            print(f"{sim_min:8.1f} m {events:7d} {time.perf_counter() - start:8.1f} {cur:8.1f} {peak:9.1f}{label}",
                  flush=True)

        def on_event(e: StoryEvent, fps: int) -> None:
            nonlocal events, next_mark
            if e.state == "ongoing":
                events += 1
            sim_min = e.applied_frame / fps / 60.0 if e.finished_frame is None else e.finished_frame / fps / 60.0
            while sim_min >= next_mark:
                report(next_mark)
                next_mark += opts.every

        os.environ.setdefault("BENCH_LONG_RUN_KEY", "sk-bench")
        with FakeOpenAI(responder=responder) as fake:
            cfg = out.parent / "fake_provider.toml"
            cfg.write_text(
                f'[llm]\nmodel = "openai/fake"\napi_base = "{fake.base}"\napi_key_env = "BENCH_LONG_RUN_KEY"\n'
                "timeout_s = 30.0\n[llm.retry]\nmax_attempts = 1\n",
                encoding="utf-8",
            )
            args = RunArguments(scene="home", names=tuple(ERRANDS), duration=opts.minutes * 60.0, pace=opts.pace,
                                config=str(cfg), planner="unified", description="object-list")
            story = asyncio.run(run_story(
                scene, args, out=out, trace_path=out / "trace.jsonl", replay=None, on_event=on_event,
                in_process_programs=True,
            ))
            result, names, fps, world = story.result, story.names, story.fps, story.world
        report(result.frames / fps / 60.0, "  (end of story)")
        peak_story = rows[-1][3]
        if opts.export:
            write_outputs(out, scene, world, result, names, "", fps, gif=False, trace_path=out / "trace.jsonl")
            report(result.frames / fps / 60.0, "  (after the exports)")
        held = world.buffers.held
        print(f"{result.frames} frames, {result.steps} planning steps, {responder.requests} provider requests; "
              f"frames in memory at the end: {held} per character (window {world.buffers.window})")
        if result.planner_error is not None:
            print(f"planner stopped: {type(result.planner_error).__name__}: {result.planner_error}", file=sys.stderr)
            return 1
        # flat: the peak after the first report grows by less than 64 MiB to the end of the story
        first = rows[0][3]
        flat = peak_story - first < 64.0
        print(f"peak RSS {peak_story:.1f} MiB (< 1024: {'yes' if peak_story < 1024 else 'NO'}); "
              f"growth after the first report {peak_story - first:+.1f} MiB (flat: {'yes' if flat else 'NO'})")
        return 0


if __name__ == "__main__":
    raise SystemExit(main())

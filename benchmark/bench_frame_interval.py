"""Frame intervals of a real-time story while the planner works, and where the slow frames went.

A ``realtime`` run (speed 1) of 20 characters in the home scene, planned by a fake
OpenAI-compatible provider on 127.0.0.1 (``benchmark/support/fake_openai_server.py``) that takes
``--latency`` seconds (default 5) per call and answers every call with an event program for the
first free character. Event programs run in the worker process, as in ``storyteller run``.

Two runs per repeat, same arguments, alternating so both see the same machine state, each in
a fresh interpreter (cold imports and compiled kernels, as a ``storyteller run``):
``baseline`` writes each session checkpoint on the event loop (``save_checkpoint`` inline in
the frame, as before ``storyteller.orchestrator.session.checkpoint_writer``: fsyncs of every motion chunk
file and the snapshot), ``product`` is ``storyteller run`` as it is (the checkpoint writer
thread). For each mode it prints the p50 / p95 / p99 / max wall-clock interval between frames
(target at 30 fps: 33.3 ms; the goal is p99 < 40 ms), the share of frames over 33.3 ms and over
40 ms, how far the realtime schedule slipped after stalls, and, of the frames over 40 ms, which
part of the frame took longest (``storyteller.orchestrator.session.frame_profile``): the world step, the
checkpoint, settling news and outcomes (trace and story records), asking the planner, or
``late`` (the sleep ended late: other work on the event loop, such as a planning step or the
LLM client's trace writes, or the machine). Not a test: timings depend on the machine and its
load; compare the two modes of the same run.

``--viewer`` adds a third mode, ``viewer``: ``product`` with the browser viewer started as
``storyteller run --view`` starts it (``storyteller.orchestrator.viewer.child``: a process of its own,
playing, following the live run) and a headless Chromium (``benchmark/support/headless_chromium.py``,
software WebGL, on this machine) connected to it for the whole run (the run starts once the page
shows the instruction box: its websocket is open).

    python -m storyteller.benchmark.bench_frame_interval [--duration 40] [--latency 5] [--repeat 1] [--viewer]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import multiprocessing
import os
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np

from storyteller.benchmark.scripted_planner import ScriptedPlanner
from storyteller.benchmark.support.fake_openai_server import FakeOpenAI

SPOTS = ("bookshelf_1", "couch_1", "tv_1", "coffee_maker_1", "toaster_1", "fridge_1")
MODES = ("baseline", "product")
PERIOD_MS = 1000.0 / 30
SLOW_MS = 40.0
CAUSES = {"step": "world step", "checkpoint": "checkpoint", "settle": "settle", "ask": "ask", "late": "late"}


def program(name: str, k: int) -> str:
    return (
        f'```python\ndef parse_event():\n    c = get_character("{name}")\n'
        f'    c.set_position(get_area_close_to("{SPOTS[k % len(SPOTS)]}"))\n'
        '    c.set_target_action("use_smartphone")\n```'
    )


class InlineCheckpoints:
    """The baseline's checkpoint writer: every checkpoint written in the frame that took it."""

    def __init__(self, path: Path, write: Any = None) -> None:
        self.path = path  # ``write`` (the run's trace barrier, then the write) is the threaded writer's

    def submit(self, world: Any, checkpoint: Any) -> None:
        from storyteller.orchestrator.session.snapshot_file import save_checkpoint

        save_checkpoint(self.path, world, checkpoint)

    def flush(self) -> None:
        return None

    def close(self, *, raise_errors: bool = True) -> None:
        return None


@dataclass
class Run:
    intervals_ms: np.ndarray
    parts_ms: dict[str, np.ndarray]
    steps: int
    slipped_s: float


def run_once(mode: str, duration: float, latency: float, tmp: Path) -> Run:
    from storyteller.orchestrator.session import checkpoint_writer
    from storyteller.orchestrator.session.frame_profile import PARTS
    from storyteller.orchestrator.session.roster import character_names
    from storyteller.orchestrator.session.run_job import run_story
    from storyteller.orchestrator.session.run_manifest import RunArguments
    from storyteller.sim.scene.bundled import resolve_scene

    os.environ["FAKE_PROVIDER_KEY"] = "sk-bench"
    responder = ScriptedPlanner(latency, program, "Ava")  # a smartphone near one of a few objects
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
        watching = _watch(out, tmp) if mode == "viewer" else contextlib.nullcontext()
        # the baseline swaps in an inline checkpoint writer for its run only
        inline = (mock.patch.object(checkpoint_writer, "CheckpointWriter", InlineCheckpoints) if mode == "baseline"
                  else contextlib.nullcontext())
        with inline, watching:
            result = asyncio.run(run_story(resolve_scene("home"), args, out=out, trace_path=out / "trace.jsonl",
                                           replay=None)).result
    profile = result.frame_profile
    parts = {name: np.asarray(profile.part(name), dtype=float)[1:] * 1000.0 for name in PARTS}
    return Run(np.asarray(result.frame_intervals_s[1:]) * 1000.0, parts, result.steps, result.slipped_s)


@contextlib.contextmanager
def _watch(out: Path, tmp: Path) -> Iterator[None]:
    """The viewer of ``out`` as ``run --view`` starts it (its own process, playing), with a
    headless Chromium on it."""
    from storyteller.benchmark.support.headless_chromium import Chromium
    from storyteller.orchestrator.viewer.child import spawn_viewer

    viewer = spawn_viewer(out, port=0, host="127.0.0.1")
    profile = tmp / "chromium-profile"
    profile.mkdir(exist_ok=True)
    try:
        with Chromium(profile) as browser:
            browser.navigate(viewer.url)
            # connected: the instruction box is added per browser when its websocket opens
            browser.wait_for("document.body.innerText.includes('Direct the story')", timeout_s=120)
            yield
    finally:
        viewer.stop()


def merge(runs: list[Run]) -> Run:
    return Run(
        np.concatenate([r.intervals_ms for r in runs]),
        {k: np.concatenate([r.parts_ms[k] for r in runs]) for k in runs[0].parts_ms},
        sum(r.steps for r in runs),
        sum(r.slipped_s for r in runs),
    )


def slow_causes(run: Run, over_ms: float) -> dict[str, float]:
    """Of the frames over ``over_ms``, the share whose longest part (sleep aside) was each cause."""
    slow = run.intervals_ms > over_ms
    if not slow.any():
        return dict.fromkeys(CAUSES, 0.0)
    stacked = np.stack([run.parts_ms[k][slow] for k in CAUSES])
    top = np.argmax(stacked, axis=0)
    return {name: float(np.mean(top == i)) for i, name in enumerate(CAUSES)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=40.0, help="Simulated (= wall) seconds per run.")
    parser.add_argument("--latency", type=float, default=5.0, help="Seconds the fake provider takes per call.")
    parser.add_argument("--repeat", type=int, default=1, help="Runs per mode, alternating baseline and product.")
    parser.add_argument("--viewer", action="store_true",
                        help="Also the 'viewer' mode: product with the browser viewer and a headless Chromium on it.")
    ns = parser.parse_args()
    modes = (*MODES, "viewer") if ns.viewer else MODES
    runs: dict[str, list[Run]] = {mode: [] for mode in modes}
    spawn = multiprocessing.get_context("spawn")  # each run in a fresh interpreter: cold, as `storyteller run`
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(ns.repeat):
            for mode in modes:
                folder = Path(tmp) / str(k)
                folder.mkdir(exist_ok=True)
                with spawn.Pool(1) as pool:
                    runs[mode].append(pool.apply(run_once, (mode, ns.duration, ns.latency, folder)))
    rows = {mode: merge(r) for mode, r in runs.items()}
    print(f"realtime, 20 characters, {ns.latency:g} s per LLM call, {ns.duration:g} s per run, {ns.repeat} run(s) per mode")
    print(f"{'mode':9} {'p50 ms':>7} {'p95 ms':>7} {'p99 ms':>7} {'max ms':>7} {'>33.3ms':>8} {'>40ms':>7} "
          f"{'steps':>6} {'frames':>7} {'slip s':>7}")
    for mode, r in rows.items():
        p50, p95, p99 = np.percentile(r.intervals_ms, [50, 95, 99])
        print(f"{mode:9} {p50:7.1f} {p95:7.1f} {p99:7.1f} {r.intervals_ms.max():7.1f} "
              f"{np.mean(r.intervals_ms > PERIOD_MS):8.1%} {np.mean(r.intervals_ms > SLOW_MS):7.1%} "
              f"{r.steps:6d} {len(r.intervals_ms):7d} {r.slipped_s:7.2f}")
    for over in (PERIOD_MS, SLOW_MS):
        print(f"frames over {over:.1f} ms by their longest part (sleep aside):")
        for mode, r in rows.items():
            causes = slow_causes(r, over)
            n = int(np.sum(r.intervals_ms > over))
            print(f"  {mode:9} {n:4d} frames: " + ", ".join(f"{CAUSES[k]} {v:.0%}" for k, v in causes.items()))
    base, new = (np.percentile(rows[m].intervals_ms, 99) for m in MODES)
    print(f"p99 product / baseline: {new / base:.2f}; target p99 < 40 ms: {'met' if new < 40.0 else 'not met'}")
    if ns.viewer:
        watched = np.percentile(rows["viewer"].intervals_ms, 99)
        print(f"p99 viewer / product: {watched / new:.2f}; with a browser attached, target p99 < 40 ms: "
              f"{'met' if watched < 40.0 else 'not met'}")


if __name__ == "__main__":
    main()

"""Per-program overhead of running event programs in the worker process vs in-process.

Runs the same small ``parse_event()`` program on a bundled scene ``--runs`` times in-process
(``run_event_program`` with a prebuilt scene graph, as the planning graph calls it) and
through ``storyteller.orchestrator.sandbox_worker.WorkerRunner`` (one reused worker, started and given the
scene before timing), and prints the median time of each and their difference: the cost of
the process boundary per program (target: under 20 ms). Plans are checked to be equal.

Run: python -m storyteller.benchmark.bench_sandbox_worker [--runs 50] [--scene home]
"""

from __future__ import annotations

import argparse
import statistics
import time

from storyteller.orchestrator.sandbox_worker import WorkerRunner
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.tools.character_states import WorldView
from storyteller.tools.event_program import run_event_program
from storyteller.tools.scene_graph import build_scene_graph

PROGRAM = (
    "def parse_event():\n"
    "    get_character('Mia').set_position(get_area_adjacent_to('fridge_1'))\n"
    "    get_character('Ava').set_position(get_area_to_sit_on('chair_2'))\n"
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--scene", default="home")
    args = parser.parse_args()
    scene = load_bundled_scene(args.scene)
    graph = build_scene_graph(scene)
    world = WorldView()

    inproc: list[float] = []
    for seed in range(args.runs):
        t = time.perf_counter()
        run_event_program(scene, PROGRAM, world, seed=seed, graph=graph)
        inproc.append(time.perf_counter() - t)

    worker: list[float] = []
    with WorkerRunner() as run:
        t = time.perf_counter()
        run(scene, PROGRAM, world, seed=0)
        start_ms = (time.perf_counter() - t) * 1000
        for seed in range(args.runs):
            t = time.perf_counter()
            plans = run(scene, PROGRAM, world, seed=seed)
            worker.append(time.perf_counter() - t)
            assert plans == run_event_program(scene, PROGRAM, world, seed=seed, graph=graph)

    a, b = statistics.median(inproc) * 1000, statistics.median(worker) * 1000
    print(f"worker start + first scene: {start_ms:.1f} ms (once per worker)")
    print(f"in-process median:          {a:.2f} ms per program")
    print(f"worker median:              {b:.2f} ms per program")
    print(f"overhead per program:       {b - a:.2f} ms (target < 20 ms)")


if __name__ == "__main__":
    main()

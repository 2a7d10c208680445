"""The worker process: same plans as in-process, typed errors, OS limits, restarts.

No test asserts a time: the parent's CPU-time kill is triggered by a program that never ends
on its own, its wall-clock backstop by a worker that is stopped (SIGSTOP), and the CPU and
memory limits by programs whose interpreter budget is set so high that only the OS can stop
them.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from storyteller.orchestrator.sandbox_worker import WorkerRunner
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.model import Scene
from storyteller.tools.character_states import WorldView
from storyteller.tools.errors import UnknownObjectError
from storyteller.tools.event_program import run_event_program
from storyteller.tools.sandbox import Budget, BudgetExceededError

PLACE = (
    "def parse_event():\n    get_character('Mia').set_position(get_area_adjacent_to('fridge_1'))\n"
)
FOREVER = "def parse_event():\n    while True:\n        pass\n"
UNLIMITED = Budget(
    steps=10**12, loop_iterations=10**12, wall_time=10**6, str_len=10**11, memory_bytes=10**13
)


@pytest.fixture(scope="module")
def scene() -> Scene:
    return load_bundled_scene("home")


def test_worker_plans_equal_in_process_plans(scene: Scene) -> None:
    with WorkerRunner() as run:
        for seed in (0, 1):
            assert run(scene, PLACE, WorldView(), seed=seed) == run_event_program(
                scene, PLACE, WorldView(), seed=seed
            )
        assert run.starts == 1  # reused, not one process per program


def test_typed_errors_cross_the_boundary(scene: Scene) -> None:
    bad = "def parse_event():\n    get_area_to_sit_on('sofa_99')\n"
    with WorkerRunner() as run, pytest.raises(UnknownObjectError) as info:
        run(scene, bad, WorldView(), seed=0)
    assert info.value.line == 2


@pytest.mark.slow
def test_cpu_time_kill_then_the_next_program_runs(scene: Scene) -> None:
    """The parent stops an endless loop at its CPU time (``run_seconds``), long before the
    wall-clock backstop and the worker's own limits."""
    with WorkerRunner(budget=UNLIMITED, run_seconds=1.0, wall_seconds=120.0, cpu_seconds=1000) as run:
        with pytest.raises(BudgetExceededError, match=r"\(CPU time\) and was stopped"):
            run(scene, FOREVER, WorldView(), seed=0)
        assert run.process is None  # killed
        assert run(scene, PLACE, WorldView(), seed=0)[0].character == "Mia"
        assert run.starts == 2


@pytest.mark.slow
def test_a_worker_that_is_never_scheduled_is_killed_at_the_wall_clock_backstop(scene: Scene) -> None:
    """A stopped worker (SIGSTOP: it uses no CPU, as one that blocks) never reaches its CPU limit;
    the wall-clock backstop ends it, and the next program runs on a new worker."""
    with WorkerRunner(budget=UNLIMITED, run_seconds=600.0, wall_seconds=120.0, cpu_seconds=1000) as run:
        run(scene, PLACE, WorldView(), seed=0)
        assert run.process is not None
        os.kill(run.process.pid, signal.SIGSTOP)
        run.wall_seconds = 1.0  # only while it is stopped: a busy machine does not fail the others
        with pytest.raises(BudgetExceededError, match="did not answer within 1 s and was stopped"):
            run(scene, PLACE, WorldView(), seed=1)
        assert run.process is None  # killed
        run.wall_seconds = 120.0
        assert run(scene, PLACE, WorldView(), seed=0)[0].character == "Mia"
        assert run.starts == 2


@pytest.mark.slow
def test_cpu_limit_stops_what_the_budget_lets_through(scene: Scene) -> None:
    with WorkerRunner(budget=UNLIMITED, run_seconds=120.0, wall_seconds=120.0, cpu_seconds=1) as run:
        with pytest.raises(BudgetExceededError, match="operating-system limit"):
            run(scene, FOREVER, WorldView(), seed=0)
        assert run(scene, PLACE, WorldView(), seed=0)[0].character == "Mia"


def test_memory_bomb_only_the_os_limit_catches(scene: Scene) -> None:
    bomb = "def parse_event():\n    x = 'x' * (2 ** 31)\n    return len(x)\n"
    with WorkerRunner(budget=UNLIMITED, address_space_bytes=768 * 2**20) as run:
        with pytest.raises(BudgetExceededError):
            run(scene, bomb, WorldView(), seed=0)
        assert run(scene, PLACE, WorldView(), seed=0)[0].character == "Mia"


def test_a_worker_killed_between_programs_is_restarted(scene: Scene) -> None:
    with WorkerRunner() as run:
        run(scene, PLACE, WorldView(), seed=0)
        assert run.process is not None
        run.process.kill()
        run.process.wait()
        assert run(scene, PLACE, WorldView(), seed=0)[0].character == "Mia"
        assert run.starts == 2


FIRST_PROGRAM_PROBE = """
import json, sys
from storyteller.orchestrator.sandbox_worker import load_scene
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.tools.character_states import WorldView
from storyteller.tools.event_program import run_event_program
from storyteller.tools.position_sampling import scene_nav_grid

scene, graph = load_scene(load_bundled_scene("home").model_dump_json())
modules, built = set(sys.modules), scene_nav_grid.cache_info().misses
run_event_program(scene, sys.argv[1], WorldView(), seed=0, graph=graph)
print("FIRST " + json.dumps({"imported": sorted(set(sys.modules) - modules),
                             "grids_built": scene_nav_grid.cache_info().misses - built}))
"""


def test_the_first_program_on_a_new_worker_imports_and_builds_nothing() -> None:
    """Loading a scene in the worker (``load_scene``) builds the navigation grid and imports the
    compiled kernels the sampler uses, so none of it is paid inside the first program's budget
    (a fresh interpreter, like a new worker: the test session has imported everything)."""
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", FIRST_PROGRAM_PROBE, PLACE], capture_output=True,
                          text=True, cwd=root, env=env, timeout=300)
    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("FIRST ")), None)
    assert line is not None, proc.stderr[-2000:]
    assert json.loads(line.removeprefix("FIRST ")) == {"imported": [], "grids_built": 0}


WORKER_IMPORTS_PROBE = """
import json, sys
from storyteller.orchestrator.sandbox_worker import load_scene

load_scene(sys.stdin.read())  # the scene's JSON, as the parent sends it
print("MODULES " + json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in
      ("matplotlib", "langgraph", "langsmith", "litellm", "sklearn", "torch"))))
"""


def test_a_worker_with_its_scene_loaded_imports_no_plotting_or_planning_module(scene: Scene) -> None:
    """The worker's start-up (imports and ``load_scene``, paid by every run and replay) loads
    what programs run on (the scene graph, the navigation grid and its compiled kernels) and no
    plotting, LLM or planning-graph package."""
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", WORKER_IMPORTS_PROBE], input=scene.model_dump_json(),
                          capture_output=True, text=True, cwd=root, env=env, timeout=300)
    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("MODULES ")), None)
    assert line is not None, proc.stderr[-2000:]
    assert json.loads(line.removeprefix("MODULES ")) == []


def test_a_prestarted_worker_runs_the_first_program(scene: Scene) -> None:
    with WorkerRunner() as run:
        run.prestart()
        run.prestart()  # one worker, however often
        assert run.starts == 1 and run.process is not None
        assert run(scene, PLACE, WorldView(), seed=0) == run_event_program(scene, PLACE, WorldView(), seed=0)
        assert run.starts == 1


def test_a_prestarted_worker_that_died_before_its_first_program_is_restarted(scene: Scene) -> None:
    with WorkerRunner() as run:
        run.prestart()
        assert run.process is not None
        run.process.kill()
        run.process.wait()
        assert run(scene, PLACE, WorldView(), seed=0)[0].character == "Mia"
        assert run.starts == 2


class CountingRunner(WorkerRunner):
    """A ``WorkerRunner`` that counts the requests it sends its worker."""

    asked = 0

    def _ask(self, request: dict[str, Any], extra_seconds: float = 0.0) -> dict[str, Any]:
        self.asked += 1
        return super()._ask(request, extra_seconds)


@pytest.mark.parametrize("preload", [True, False])
def test_a_worker_prestarted_with_the_scene_has_it_loaded_for_the_first_program(scene: Scene, preload: bool) -> None:
    """``prestart(scene)``: the worker loads the scene before it says it is ready, so the first
    program is one request (without it, the worker asks for the scene and the program is sent
    again with it); the plans are the in-process ones either way."""
    with CountingRunner() as run:
        run.prestart(scene if preload else None)
        assert run(scene, PLACE, WorldView(), seed=0) == run_event_program(scene, PLACE, WorldView(), seed=0)
        assert (run.asked, run.starts) == (1 if preload else 2, 1)
        run(scene, PLACE, WorldView(), seed=1)
        assert run.asked == (2 if preload else 3)


def test_a_worker_prestarted_with_the_scene_that_died_is_restarted(scene: Scene) -> None:
    with WorkerRunner() as run:
        run.prestart(scene)
        assert run.process is not None
        run.process.kill()
        run.process.wait()
        assert run(scene, PLACE, WorldView(), seed=0)[0].character == "Mia"
        assert run.starts == 2


def test_closing_a_worker_prestarted_with_the_scene_stops_it(scene: Scene) -> None:
    run = WorkerRunner()
    run.prestart(scene)
    process = run.process
    assert process is not None
    run.close()
    assert run.process is None and process.poll() is not None


def test_closing_a_prestarted_worker_stops_it() -> None:
    run = WorkerRunner()
    run.prestart()
    process = run.process
    assert process is not None
    run.close()
    assert run.process is None and process.poll() is not None

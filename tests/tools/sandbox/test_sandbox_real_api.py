"""The whole hostile corpus, run against the real spatial API on a bundled scene.

``tests/tools/sandbox/test_sandbox_hostile.py`` runs the corpus of ``tests/support/hostile_programs.py``
against a stand-in world; here every one of them (plus the huge-range membership cases) goes
through ``run_event_program`` exactly as ``storyteller event-program home --states ...`` runs
it: a real ``SpatialAPI`` over the bundled home scene with two characters already placed.

A program that hangs in C (as ``0.5 in range(10**15)`` did) holds the interpreter lock, so no
thread can time it out: the cases run in a worker subprocess that reports one JSON line per
case, and the test kills the worker when a case gives no answer within ``HANG_TIMEOUT_S``
(a hang detector, far above the sandbox's 1 s budget; nothing here asserts how fast a case
was). Each case must end in a typed sandbox error (never the catch-all "the program
failed"), a budget case must be stopped by the budget (``BudgetExceededError``), and the
scene, its graph and the recorded plans of the world must be unchanged afterwards. The
sandbox's own accounting (``EventProgramError.steps``) of a budget stop stays within one
charge of the step budget.
"""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, cast

import pytest

from storyteller.tools.sandbox import Budget

if TYPE_CHECKING:  # the worker subprocess imports these when it runs, not at collection
    from storyteller.sim.scene.model import Scene
    from storyteller.tools.character_states import WorldView
    from storyteller.tools.scene_graph import SceneGraph

HERE = Path(__file__).resolve().parents[2]
HANG_TIMEOUT_S = 10.0
SCENE = "home"


# ---------------------------------------------------------------- the worker (a subprocess)


def _cases() -> list[tuple[str, object, str, object]]:
    """(name, source, expected error class name or "value", expected value)."""
    sys.path.insert(0, str(HERE.parent))  # the worker runs this file as a script
    from tests.support.hostile_programs import HOSTILE, RANGE_MEMBERSHIP, body

    out: list[tuple[str, object, str, object]] = [
        (name, source, expected.__name__, None) for name, source, expected in HOSTILE
    ]
    out += [(name, body(f"return {expr}"), "value", value) for name, expr, value in RANGE_MEMBERSHIP]
    return out


def _snapshot(scene: Scene, graph: SceneGraph, world: WorldView) -> str:
    return json.dumps(
        {
            "scene": scene.model_dump(mode="json"),
            "edges": graph.triples(),
            "world": world.model_dump(mode="json"),
        },
        sort_keys=True,
    )


def _world(scene: Scene, graph: SceneGraph) -> WorldView:
    """Mia standing near the fridge, Ava sitting on chair_2 (placed by a real program run)."""
    from storyteller.tools.character_states import CharacterState, WorldView
    from storyteller.tools.event_program import run_event_program

    setup = (
        "def parse_event():\n"
        "    get_character('Mia').set_position(get_area_adjacent_to('fridge_1'))\n"
        "    get_character('Ava').set_position(get_area_to_sit_on('chair_2'))\n"
    )
    plans = run_event_program(scene, setup, WorldView(), seed=0, graph=graph)
    states = tuple(
        CharacterState(
            name=p.character,
            position=p.position,
            facing=p.facing,
            action=p.action,
            seat=p.seat,
            area=p.area,
        )
        for p in plans
    )
    return WorldView(
        characters=states, objects_in_use={p.seat: p.character for p in plans if p.seat}
    )


def worker(start: int) -> None:
    """Run cases ``start...`` and print one JSON line per case."""
    from storyteller.sim.scene.bundled import load_bundled_scene
    from storyteller.tools.errors import EventProgramError
    from storyteller.tools.event_program import run_event_program
    from storyteller.tools.sandbox import execute
    from storyteller.tools.scene_graph import build_scene_graph
    from storyteller.tools.spatial_api import SpatialAPI

    scene = load_bundled_scene(SCENE)
    graph = build_scene_graph(scene)
    world = _world(scene, graph)
    before = _snapshot(scene, graph, world)
    print(json.dumps({"ready": True}), flush=True)
    for index, (name, source, _expected, _value) in enumerate(_cases()):
        if index < start:
            continue
        report: dict[str, object] = {"index": index, "name": name}
        try:
            if _expected == "value":
                assert isinstance(source, str)  # the value cases are range-membership programs
                api = SpatialAPI(scene, graph, world)
                report["value"] = execute(source, api.namespace())
                report["plans"] = len(api.resolve(0))
            else:
                plans = run_event_program(scene, cast(str, source), world, seed=0, graph=graph)  # may be bytes, on purpose
                report["plans"] = len(plans)
        except EventProgramError as err:
            report["error"] = type(err).__name__
            report["message"] = err.feedback
            report["steps"] = err.steps
        except BaseException as err:  # reported: the test fails on it
            report["escaped"] = f"{type(err).__name__}: {err}"
        report["unchanged"] = _snapshot(scene, graph, world) == before
        print(json.dumps(report, default=repr), flush=True)


# ---------------------------------------------------------------- the test (the parent)


def _read_line(proc: subprocess.Popen[str], timeout: float) -> str | None:
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    if not ready:
        return None
    return proc.stdout.readline()


def _start(start: int) -> subprocess.Popen[str]:
    env = dict(os.environ, PYTHONHASHSEED="0")
    return subprocess.Popen(
        [sys.executable, str(Path(__file__)), "--worker", str(start)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
        cwd=HERE.parent,
    )


def run_all() -> dict[int, dict[str, object]]:
    """Every case's report; a case that hangs gets ``{"hang": True}`` and the worker restarts."""
    total = len(_cases())
    reports: dict[int, dict[str, object]] = {}
    next_index = 0
    while next_index < total:
        proc = _start(next_index)
        try:
            line = _read_line(proc, 120.0)  # importing and building the scene
            assert line and json.loads(line) == {"ready": True}, "the worker did not start"
            while next_index < total:
                line = _read_line(proc, HANG_TIMEOUT_S)
                if not line:
                    reports[next_index] = {"hang": True, "name": _cases()[next_index][0]}
                    next_index += 1
                    break
                report = json.loads(line)
                reports[report["index"]] = report
                next_index = report["index"] + 1
        finally:
            _stop(proc)
    return reports


def _stop(proc: subprocess.Popen[str]) -> None:
    proc.kill()
    proc.wait()
    if proc.stdout is not None:
        proc.stdout.close()


@pytest.fixture(scope="module")
def reports() -> dict[int, dict[str, object]]:
    return run_all()


CASES = _cases()


@pytest.mark.parametrize("index", range(len(CASES)), ids=[c[0] for c in CASES])
def test_hostile_program_against_the_real_api(
    reports: dict[int, dict[str, object]], index: int
) -> None:
    name, _source, expected, value = CASES[index]
    report = reports[index]
    assert not report.get("hang"), f"{name} gave no answer within {HANG_TIMEOUT_S} s"
    assert "escaped" not in report, report["escaped"]
    assert report["unchanged"], f"{name} changed the scene, its graph or the world"
    if expected == "value":
        assert "error" not in report, report.get("message")
        assert report["value"] == value
        assert report["plans"] == 0
        return
    assert "error" in report, f"{name} finished with {report.get('plans')} plans"
    message = str(report["message"])
    assert not message.startswith("the program failed"), message  # the catch-all wrapper
    if expected == "BudgetExceededError":
        assert report["error"] == expected, message
        steps = report["steps"]
        if steps is not None:  # stopped while running: within one charge of the step budget
            budget = Budget()
            assert isinstance(steps, int)  # EventProgramError.steps, through JSON
            assert steps <= budget.steps + budget.container_len * 10 // 8 + 64, steps


def test_a_silent_worker_is_a_hang_not_a_wait() -> None:
    """The hang detector itself: a worker that never answers is a reported hang."""
    sleeper = subprocess.Popen(
        [sys.executable, "-c", "import time; time.sleep(60)"], stdout=subprocess.PIPE, text=True
    )
    try:
        assert _read_line(sleeper, 0.2) is None
    finally:
        _stop(sleeper)


if __name__ == "__main__" and len(sys.argv) == 3 and sys.argv[1] == "--worker":
    sys.path.insert(0, str(HERE.parent))
    worker(int(sys.argv[2]))

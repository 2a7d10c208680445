"""The planning graph's default program runner (the worker process) gives exactly the plans
of the in-process runner: on the 10 reference PI programs for several seeds, and through
``run_plan`` (which starts the worker for the run and stops it at the end)."""

from __future__ import annotations

import json

import pytest

import storyteller.orchestrator.sandbox_worker
from storyteller.benchmark.reference_cases import CaseWorld, case_tags, planning_inputs
from storyteller.orchestrator.sandbox_worker import WorkerRunner
from storyteller.orchestrator.session.plan_job import run_plan
from storyteller.tools.character_states import world_view_from_reference_case
from storyteller.tools.event_program import run_event_program
from tests.support.reference import requires_reference
from tests.support.reference_pipeline import (
    CASE_IDS,
    MODEL,
    PROGRAMS,
    SEED,
    answer,
    case_path,
    scene_and_graph,
    the_case,
)
from tests.support.scripted_llm import ScriptedLLM

pytestmark = requires_reference


def test_worker_and_in_process_plans_are_identical_on_the_pi_programs() -> None:
    with WorkerRunner() as runner:
        for case_id in CASE_IDS:
            data = json.loads(case_path(case_id).read_text())
            scene, graph = scene_and_graph(data["scene_name"])
            world = world_view_from_reference_case(data, scene)
            source = (PROGRAMS / f"testcase_{case_id}.py").read_text()
            for seed in range(3):
                expected = run_event_program(
                    scene, source, world, seed=seed, action_labels=data["action_labels"], graph=graph
                )
                got = runner(scene, source, world, seed=seed, action_labels=data["action_labels"], graph=graph)
                assert got == expected, f"case {case_id} seed {seed}"
                assert got  # a program that plans nothing would make the comparison empty
        assert runner.starts == 1  # one worker for every case and scene


async def test_run_plan_runs_programs_in_a_worker_it_closes(monkeypatch: pytest.MonkeyPatch) -> None:
    started: list[WorkerRunner] = []

    class Recorded(WorkerRunner):
        def __init__(self) -> None:
            super().__init__()
            started.append(self)

    monkeypatch.setattr(storyteller.orchestrator.sandbox_worker, "WorkerRunner", Recorded)
    case, scene = the_case()
    inputs = planning_inputs(case, scene)
    outcomes = []
    for in_process in (False, True):
        planned = await run_plan(
            scene=scene, port=ScriptedLLM(answer), instruction=case.user_instruction, events=1, seed=SEED,
            runs_db=":memory:", thread_id="plan", roster=inputs.roster, history=inputs.history,
            world=CaseWorld(inputs), action_labels=case.action_labels, tags=case_tags(case),
            describer_model=MODEL, max_retries=1, program_grammar=True, in_process_programs=in_process,
        )
        outcomes.append(planned.outcomes)
    (worker,) = started  # only the default run made a worker ...
    assert worker.starts == 1 and worker.process is None  # ... ran the program in it and stopped it
    assert outcomes[0] == outcomes[1] and outcomes[0][0][1] is not None

"""One pipeline: the planning benchmark's full-method run of a reference case sends the same
LLM requests, byte for byte, as ``storyteller plan``'s job (``run_plan``, called as the
command calls it) and as the compiled planning graph invoked by hand on that case.

Each way gets its own scripted port that answers by request content (the describer's reply is
rejected, so its repair path runs too; narrator and parser answer right) and keeps every
request; the three lists of serialized requests must be equal.
"""

from __future__ import annotations

from collections.abc import Sequence

from storyteller.agents.llm_port import LLMRequest
from storyteller.agents.messages import CharacterStatus
from storyteller.benchmark.planning_benchmark import Descriptions, run_cases
from storyteller.benchmark.reference_cases import CaseWorld, case_tags, planning_inputs
from storyteller.orchestrator.planning.checkpoints import StoryLog
from storyteller.orchestrator.planning.graph import compile_planning_graph, recursion_limit
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState
from storyteller.orchestrator.session.plan_job import run_plan
from storyteller.orchestrator.session.port_setup import describer_mode_for
from tests.support.reference import REFERENCE, requires_reference
from tests.support.reference_pipeline import MODEL, RETRIES, SEED, answer, the_case
from tests.support.scripted_llm import ScriptedLLM

pytestmark = requires_reference

def serialized(requests: Sequence[LLMRequest]) -> list[str]:
    return [r.model_dump_json() for r in requests]


async def test_benchmark_and_plan_send_byte_identical_requests() -> None:
    case, scene = the_case()
    inputs = planning_inputs(case, scene)

    bench = ScriptedLLM(answer)
    results = await run_cases([case], bench, Descriptions("describer", REFERENCE), REFERENCE,
                              max_retries=RETRIES, describer_model=MODEL, seed=SEED, program_grammar=True)
    assert results[0].score.passed, results[0].score.reason

    # storyteller plan's job, with the arguments plan_command passes, from the case's inputs
    plan = ScriptedLLM(answer)
    planned = await run_plan(
        scene=scene, port=plan, instruction=case.user_instruction, events=1, seed=SEED, runs_db=":memory:",
        thread_id="plan", roster=inputs.roster, history=inputs.history, world=CaseWorld(inputs),
        action_labels=case.action_labels, tags=case_tags(case), describer_model=MODEL, description_cache=None,
        busy_events=0, max_retries=RETRIES, program_grammar=True,
    )
    assert planned.outcomes[0][1] is not None

    # the compiled planning graph, invoked by hand
    raw = ScriptedLLM(answer)
    story = StoryLog(":memory:", "raw")
    deps = PlanningDeps(port=raw, scene=scene, world=CaseWorld(inputs), story=story, action_labels=case.action_labels,
                        tags=case_tags(case), seed=SEED, max_retries=RETRIES, describer_model=MODEL,
                        describer_mode=describer_mode_for(MODEL), program_grammar=True)
    roster: tuple[CharacterStatus, ...] = inputs.roster
    start = PlanningState(instruction=case.user_instruction, events_target=1, roster=roster, recent=inputs.history)
    await compile_planning_graph().ainvoke(start.model_dump(), context=deps,
                                           config={"recursion_limit": recursion_limit(1, RETRIES)})
    story.close()

    # the narrator, then the event parser: this case's words name no action the label ranker knows,
    # so its action is chosen first (a choice request), then the program is written
    assert [r.node for r in bench.requests] == ["describer", "describer", "narrator", "event_parser", "event_parser"]
    assert bench.requests[3].choices is not None and bench.requests[4].choices is None
    assert serialized(bench.requests) == serialized(plan.requests)
    assert serialized(bench.requests) == serialized(raw.requests)
    # the case, not a default roster, reached the model: its characters, busy ones included
    narrator = bench.requests[2].messages[-1].content
    assert all(c.name in narrator for c in inputs.roster) and "- Melissa: busy, use_laptop" in narrator


async def test_a_changed_request_is_seen() -> None:
    """The comparison is sensitive: another seed changes the requests (the check can fail)."""
    case, _ = the_case()
    one, other = ScriptedLLM(answer), ScriptedLLM(answer)
    for port, seed in ((one, SEED), (other, SEED + 1)):
        await run_cases([case], port, Descriptions("reference", REFERENCE), REFERENCE, seed=seed)
    assert [r.node for r in one.requests] == [r.node for r in other.requests]
    assert serialized(one.requests) != serialized(other.requests)

"""A hostile event program from the model is a typed rejection fed back to the event parser,
and the story goes on.

A story session (simulation and the event-driven planning graph, as ``storyteller run``
builds them) whose event parser (``ScriptedLLM``) first answers with an infinite loop, a
memory bomb, a huge integer and an attribute escape (``().__class__.__bases__``), then with a
good program. The programs run in the OS-limited worker process (``WorkerRunner``), as in a
run. Each bad program is rejected with its error type, that rejection is what the parser is
asked again with, the fifth answer becomes the story's event, and the simulation plays the
story to its last frame.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from langgraph.checkpoint.memory import InMemorySaver

from storyteller.agents.event_parser import scene_action_labels
from storyteller.agents.messages import ParsedEvent
from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.llm.traces import ParsedRecord, read_trace
from storyteller.orchestrator.planning.ablation_graph import Ablation, compile_graph
from storyteller.orchestrator.planning.checkpoints import StoryLog
from storyteller.orchestrator.planning.state import PlanningDeps
from storyteller.orchestrator.sandbox_worker import WorkerRunner
from storyteller.orchestrator.session.roster import RosterWorld, start_positions
from storyteller.orchestrator.session.runtime import Session
from storyteller.orchestrator.session.session_types import SessionSettings
from storyteller.orchestrator.session.step_planner import GraphStepPlanner
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.scene.bundled import resolve_scene
from storyteller.sim.world.step import World
from tests.support.scripted_llm import ScriptedLLM

NARRATION = json.dumps({"reasoning": "r", "event": {"characters": ["Ava"], "activity": "Ava makes coffee with coffee_maker_1"}})


def fenced(body: str) -> str:
    return f"```python\ndef parse_event():\n{body}\n```"


HOSTILE = {
    "infinite loop": fenced("    n = 0\n    while n >= 0:\n        n = n + 1"),
    "memory bomb": fenced("    x = [[0] * 100000 for _ in range(100000)]"),
    "huge integer": fenced("    x = 7 ** (10 ** 9)"),
    "attribute escape": fenced("    k = ().__class__.__bases__[0].__subclasses__()"),
}
REJECTED_AS = {
    "infinite loop": "BudgetExceededError", "memory bomb": "BudgetExceededError",
    "huge integer": "BudgetExceededError", "attribute escape": "ForbiddenConstructError",
}
SAYS = {
    "infinite loop": "loops ran more than", "memory bomb": "items (limit",
    "huge integer": "bits (limit", "attribute escape": "attributes starting with '_' are not allowed",
}
COFFEE = fenced(
    '    a = get_character("Ava")\n    a.set_position(get_area_to_interact_with("coffee_maker_1"))\n'
    '    a.set_orientation("coffee_maker_1")\n    a.set_target_action("use_coffee_maker")'
)



@pytest.mark.slow
async def test_hostile_programs_are_rejected_with_their_type_and_the_story_goes_on(
    motion: MotionMatcher, tmp_path: Path
) -> None:
    scene = resolve_scene("home")
    trace = TraceWriter(tmp_path / "trace.jsonl", fsync="never")
    port = ScriptedLLM({"narrator": lambda _request: NARRATION, "event_parser": [*HOSTILE.values(), COFFEE]},
                       trace=trace)
    story = StoryLog(tmp_path / "runs.sqlite", "t")
    runner = WorkerRunner()
    deps = PlanningDeps(port=port, scene=scene, world=RosterWorld(), story=story,
                        action_labels=scene_action_labels(scene), seed=0, max_retries=len(HOSTILE),
                        runner=runner)
    graph = compile_graph(Ablation(planner="event", description="object-list"), InMemorySaver())
    (start,) = start_positions(scene, 1, 0)
    world = World(scene, {"Ava": (start, 0.0)}, motion)
    settings = SessionSettings(frames=60, max_steps=1, instruction="Ava makes coffee.")
    try:
        result = await Session(world, GraphStepPlanner(graph, deps, "t"), settings, trace=trace).run()
    finally:
        runner.close()
        story.close()
        trace.close()

    # the story went on: the good program became the event, the simulation ran to its end
    assert result.planner_error is None and result.frames == 60
    ((_, outcome),) = result.outcomes
    assert isinstance(outcome, ParsedEvent) and outcome.plans[0].action == "use_coffee_maker"
    assert [e.state for e in result.events] == ["ongoing"]

    # each hostile program was rejected with its error type (the trace's parsed records) ...
    parsed = [r for r in read_trace(tmp_path / "trace.jsonl").records
              if isinstance(r, ParsedRecord) and r.node == "event_parser"]
    assert [r.error_type for r in parsed] == [*REJECTED_AS.values(), None]
    # ... and that rejection, one sentence saying what went wrong, is what the parser was asked again with
    asks = [r for r in port.requests if r.node == "event_parser"]
    assert len(asks) == len(HOSTILE) + 1
    for record, again, says in zip(parsed, asks[1:], SAYS.values(), strict=False):
        assert record.error_message is not None and record.error_message in again.messages[-1].content
        assert says in record.error_message, record.error_message

"""The paper's ablations as variants of the planning graph: the same wiring, other nodes.

``storyteller plan``, ``storyteller run`` and the planning benchmark pick a planner
(``--planner``) and a scene description (``--description``); :func:`compile_graph` returns the
compiled graph for the pair. Every variant takes :class:`PlanningState` and
:class:`PlanningDeps` unchanged, makes at most one LLM call per node (checkpointed per call,
so a resumed run never repeats a finished call) and records its outcome with the planning
graph's own ``record_outcome``:

- planner ``event`` (the full method) is :func:`storyteller.orchestrator.planning.graph.build_planning_graph`
  as it is: narrator, event parser and their feedback loops;
- planner ``direct`` ("Direct Inference") is the same graph with the event parser's two nodes
  swapped: ``parse_event`` asks for coordinates (:func:`storyteller.agents.ablations.direct.direct_request`)
  and ``check_program`` checks and runs them
  (:func:`storyteller.agents.ablations.direct.check_direct_reply`);
- planner ``unified`` ("w/o Event") replaces the narrator and the parser by one call
  (node ``planner``, :func:`storyteller.agents.ablations.unified.unified_request`) and its check, with
  the planning graph's describer nodes, routers and ``record_outcome`` around them::

      START -> describe_scene <-> check_description
                   |                   |
                   v                   v
                route_step --> plan_event -> check_plan --+
                   ^   |   (no free character: wait)      |
                   |   v                                   v
                   +- record_outcome <---------------------+

  It keeps its reply, turns and trace seq in the state's ``parser_*`` fields (the call that
  places the characters); a program that plans nobody sets a wait event;
- description ``describer`` asks the describer; ``object-list`` and ``scene-graph`` swap the
  ``describe_scene`` node for one that sets
  :func:`~storyteller.agents.ablations.descriptions.object_list_description` or
  :func:`~storyteller.agents.ablations.descriptions.scene_graph_description` (no LLM call). A state that
  already holds a description (e.g. the benchmark's reference text) skips it either way.

A model that is unavailable after the client's retries and fallbacks
(:class:`~storyteller.agents.llm_port.LLMError`) makes the step fail, as in the main graph; a replay
miss propagates.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from langgraph.graph import END, START, StateGraph
from langgraph.runtime import Runtime
from langgraph.types import Checkpointer
from pydantic import JsonValue

from storyteller.agents.ablations.descriptions import object_list_description, scene_graph_description
from storyteller.agents.ablations.direct import check_direct_reply, direct_request
from storyteller.agents.ablations.unified import check_unified_reply, unified_request
from storyteller.agents.messages import Event, ParsedEvent, SceneDescription
from storyteller.agents.program_grammar import open_program_grammar
from storyteller.agents.retry_feedback import REJECTIONS
from storyteller.orchestrator.planning import graph as planning_graph
from storyteller.orchestrator.planning.action_node import skip_action_choice
from storyteller.orchestrator.planning.describer_nodes import check_description, describe_scene
from storyteller.orchestrator.planning.graph import CompiledPlanningGraph, NodeFn, PlanningGraph
from storyteller.orchestrator.planning.kinds import DescriptionKind, PlannerKind
from storyteller.orchestrator.planning.narrator_nodes import narrator_input
from storyteller.orchestrator.planning.node_calls import ask, off_loop
from storyteller.orchestrator.planning.parser_nodes import parser_input
from storyteller.orchestrator.planning.record_node import record_outcome
from storyteller.orchestrator.planning.rejection import record_parsed, rejected_reply
from storyteller.orchestrator.planning.seat_node import skip_seat_choice
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState


@dataclass(frozen=True)
class Ablation:
    """Which planner and which scene description a run uses."""

    planner: PlannerKind = "event"
    description: DescriptionKind = "describer"

    @property
    def is_default(self) -> bool:
        return self.planner == "event" and self.description == "describer"

    @property
    def label(self) -> str:
        return f"{self.planner}+{self.description}"

    def thread_id(self, thread: str) -> str:
        """The checkpoint / story-log thread of ``thread`` under this ablation: a run resumed
        with other options starts its own thread instead of mixing two planners' states."""
        return thread if self.is_default else f"{thread}@{self.label}"


# ----- description nodes ------------------------------------------------------------------
def preset_description(kind: DescriptionKind, deps: PlanningDeps) -> SceneDescription:
    """The object list or the raw scene graph of the run's scene (no LLM call)."""
    if kind == "object-list":
        return object_list_description(deps.scene)
    if kind == "scene-graph":
        return scene_graph_description(deps.scene, deps.scene_graph)
    raise ValueError(f"description {kind!r} is not a preset")


def preset_node(kind: DescriptionKind) -> NodeFn:
    """``describe_scene`` for a preset description (object list or scene graph), once per run."""

    async def describe_scene(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
        if state.description is not None:
            return {}
        return {"description": preset_description(kind, runtime.context)}

    return describe_scene


def _plans_json(parsed: ParsedEvent | None) -> JsonValue:
    if parsed is None:
        return {"wait": True}
    return {"plans": [p.model_dump(mode="json") for p in parsed.plans], "program": parsed.program}


# ----- Direct Inference: the event parser's nodes, answering coordinates -------------------
async def parse_event_as_coordinates(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """One coordinates call for the narrator's event; checked by the next node."""
    deps = runtime.context
    assert state.description is not None
    turns = tuple(t.as_turn() for t in state.parser_turns)
    lists_objects = state.description.source == "object_list"
    request = await off_loop(lambda: direct_request(
        deps.prompts, parser_input(state, deps), deps.scene, lists_objects=lists_objects, turns=turns,
    ))
    return await ask(deps, state, request, "event_parser")


async def check_coordinates(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """Check the points and run them as an event program; a typed error becomes feedback."""
    deps = runtime.context
    if state.failure is not None:
        return {}
    assert state.event is not None
    reply = state.parser_reply or ""
    try:
        event = state.event
        result = await off_loop(lambda: check_direct_reply(
            reply, scene=deps.scene, event=event, world=deps.world.world_view(state.roster),
            seed=deps.seed + state.step, action_labels=deps.action_labels, graph=deps.scene_graph, runner=deps.runner,
        ))
    except REJECTIONS as exc:
        return rejected_reply(state, deps, "event_parser", reply, exc)
    parsed = ParsedEvent(
        index=state.step, event=state.event, plans=result.plans, program=result.program,
        narrator_attempts=state.narrator_attempts, parser_attempts=len(state.parser_turns) + 1, part=state.part,
    )
    record_parsed(deps, state.parser_seq, "event_parser", _plans_json(parsed))
    return {"parsed": parsed, "parser_reply": None, "parser_seq": None}


# ----- w/o Event: one call places the free characters --------------------------------------
async def plan_event(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """One planner call (no narrator); its reply is checked by the next node."""
    deps = runtime.context
    turns = tuple(t.as_turn() for t in state.parser_turns)
    seats_in_use = deps.world.seats_in_use(state.roster)
    grammar = None
    if deps.program_grammar and any(not c.busy for c in state.roster):
        grammar = open_program_grammar(deps.scene, state.roster, seats_in_use, deps.action_labels)
    request = unified_request(
        deps.prompts, narrator_input(state, deps), action_labels=deps.action_labels,
        seats_in_use=seats_in_use, turns=turns, grammar=grammar,
    )
    return await ask(deps, state, request, "planner")


async def check_plan(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """Run the planner's program; a program that plans nobody is a wait (a wait event)."""
    deps = runtime.context
    if state.failure is not None:
        return {}
    reply = state.parser_reply or ""
    try:
        parsed = await off_loop(lambda: check_unified_reply(
            reply, index=state.step, scene=deps.scene, characters=state.roster,
            world=deps.world.world_view(state.roster), seed=deps.seed + state.step,
            action_labels=deps.action_labels, graph=deps.scene_graph, runner=deps.runner,
        ))
    except REJECTIONS as exc:
        return rejected_reply(state, deps, "planner", reply, exc)
    record_parsed(deps, state.parser_seq, "planner", _plans_json(parsed))
    update: dict[str, Any] = {"parser_reply": None, "parser_seq": None}
    if parsed is None:
        return {**update, "event": Event()}
    attempts = len(state.parser_turns) + 1
    return {**update, "parsed": parsed.model_copy(update={"narrator_attempts": 0, "parser_attempts": attempts})}


def route_plan(state: PlanningState) -> Literal["plan_event", "record_outcome"]:
    if state.parsed is not None or state.failure is not None or (state.event is not None and state.event.is_wait):
        return "record_outcome"
    return "plan_event"  # rejected: retry with the feedback


# ----- graphs -----------------------------------------------------------------------------
def build_unified_graph(describe: NodeFn = describe_scene) -> PlanningGraph:
    """The uncompiled "w/o Event" graph (see the module docstring)."""
    step_map: dict[Any, str] = {"narrate_event": "plan_event", "record_outcome": "record_outcome", END: END}
    graph: PlanningGraph = StateGraph(PlanningState, context_schema=PlanningDeps)
    graph.add_node("describe_scene", describe)
    graph.add_node("check_description", check_description)
    graph.add_node("plan_event", plan_event)
    graph.add_node("check_plan", check_plan)
    graph.add_node("record_outcome", record_outcome)
    graph.add_edge(START, "describe_scene")
    graph.add_conditional_edges(
        "describe_scene", planning_graph.route_description, {**step_map, "check_description": "check_description"}
    )
    graph.add_conditional_edges(
        "check_description", planning_graph.route_checked_description, {**step_map, "describe_scene": "describe_scene"}
    )
    graph.add_edge("plan_event", "check_plan")
    graph.add_conditional_edges("check_plan", route_plan)
    graph.add_conditional_edges("record_outcome", planning_graph.route_step, step_map)
    return graph


def build_graph(ablation: Ablation) -> PlanningGraph:
    """The uncompiled graph of ``ablation`` (the planning graph itself for the default)."""
    describe = describe_scene if ablation.description == "describer" else preset_node(ablation.description)
    if ablation.planner == "unified":
        return build_unified_graph(describe)
    if ablation.planner == "direct":
        return planning_graph.build_planning_graph(
            describe, parse_event_as_coordinates, check_coordinates, choose=skip_seat_choice, act=skip_action_choice,
        )
    return planning_graph.build_planning_graph(describe)


def compile_graph(ablation: Ablation, checkpointer: Checkpointer = None) -> CompiledPlanningGraph:
    """The compiled graph of ``ablation``."""
    return build_graph(ablation).compile(checkpointer=checkpointer)

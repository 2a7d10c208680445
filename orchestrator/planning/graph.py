"""The planning graph: describer -> narrator -> (feedback) -> event parser -> (feedback) -> record.

Nodes are verbs; every node makes at most one LLM call, so with ``durability="sync"`` each
call's reply is checkpointed before anything else happens, and a resumed run never repeats a
finished call. That holds for the describer's retries too: each describer call
(``describe_scene``) and its check (``check_description``) are nodes of their own, and the
finished description is also cached on disk per scene, model and prompts.

::

    START -> describe_scene <-> check_description        (one call per describer attempt)
                 |                   |
                 v                   v
              route_step --> narrate_event -> check_narration --+
                 ^   |  (no free character: wait)               |
                 |   v                                          v
                 |   |                            choose_action -> choose_seat
                 |   v                                          v
                 +- record_outcome <-- check_program <-- parse_event <+
                          (retries loop back through the routers)

``choose_seat`` (:mod:`storyteller.orchestrator.planning.seat_node`) decides the seat of a one-character
sitting event among the seats the scene allows, checked against the relations the words state,
with at most one call (scored continuations); other events pass through it without a call.
Before it, ``choose_action`` (:mod:`storyteller.orchestrator.planning.action_node`) lets the model rank the
action labels of an event whose words name no action the label ranker knows (one call, scored
continuations); its choice is the parser's suggestion and the first label its grammar offers.

Off the event loop: running an event program (scene-graph queries, position sampling, or the
wait on the program's worker process), building the parser's input (its grammar), the
describer's clusters, and logging a step's outcome (the trace's fsync, then the story log's
SQLite commit) happen in a worker thread (:func:`~storyteller.orchestrator.planning.node_calls.off_loop`),
so a session's simulation task keeps its frame rate while a step is checked.

The nodes live by role: :mod:`.describer_nodes`, :mod:`.narrator_nodes`, :mod:`.parser_nodes`,
:mod:`.action_node`, :mod:`.seat_node`, :mod:`.record_node` (what their calls share:
:mod:`.node_calls`); this module holds the routers and the wiring. Routers return
``Literal[...]`` node names. Dependencies (LLM port, scene, world view provider, story log,
trace sink) come from ``Runtime[PlanningDeps]``.

Progress: with ``deps.progress`` set (a story session does, per step),
:func:`~storyteller.orchestrator.planning.node_calls.complete` reports every call's latency and
``check_narration`` reports the accepted event's characters before
the event parser is asked, so the session may plan the next event beside this one.

Traces: every request carries ``state.sim_frame`` (the frame of the world snapshot the step
plans from; None without a simulation) as metadata outside the request hash. The check
nodes record, for the attempt they judged, the parsed output (narrator event, event-parser
plans per character, describer areas) or the typed error that rejected it (one update for
every check node and ablation: :func:`storyteller.orchestrator.planning.rejection.rejected_reply`). The
seqs of a step's narrator and event-parser attempts are stored with its outcome in the story log
(:meth:`~storyteller.orchestrator.planning.checkpoints.StoryLog.trace_seqs`) for the ``applied`` record.
"""

from __future__ import annotations

from collections.abc import Awaitable
from typing import Any, Literal, Protocol

from langgraph.graph import START, StateGraph
from langgraph.graph.state import CompiledStateGraph
from langgraph.runtime import Runtime
from langgraph.types import Checkpointer

from storyteller.agents.narrator import waits_without_a_call
from storyteller.orchestrator.planning.action_node import choose_action
from storyteller.orchestrator.planning.describer_nodes import check_description, describe_scene
from storyteller.orchestrator.planning.narrator_nodes import check_narration, narrate_event
from storyteller.orchestrator.planning.parser_nodes import check_program, parse_event
from storyteller.orchestrator.planning.record_node import record_outcome
from storyteller.orchestrator.planning.seat_node import choose_seat
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState

NODES = (
    "describe_scene", "check_description", "narrate_event", "check_narration", "choose_action", "choose_seat",
    "parse_event", "check_program", "record_outcome",
)


# ----- routers ----------------------------------------------------------------------------
def route_description(state: PlanningState) -> Literal["check_description", "narrate_event", "record_outcome", "__end__"]:
    """After a describer call: check it; with a description (cached or earlier): plan."""
    if state.description is None:
        return "check_description"
    return route_step(state)


def route_checked_description(state: PlanningState) -> Literal["describe_scene", "narrate_event", "record_outcome", "__end__"]:
    """After a check: another describer call with the feedback, or plan."""
    if state.description is None:
        return "describe_scene"
    return route_step(state)


def route_step(state: PlanningState) -> Literal["narrate_event", "record_outcome", "__end__"]:
    """Next step: done after K steps; with no free character, or nothing of the instruction
    for the free ones now (``storyteller.agents.instruction_parts``), the step is a wait, without a call."""
    if state.step >= state.events_target:
        return "__end__"  # langgraph's END, spelled as the literal the router's type names
    if waits_without_a_call(state.roster, state.instruction, state.recent, state.instruction_since):
        return "record_outcome"
    return "narrate_event"


def route_narration(state: PlanningState) -> Literal["narrate_event", "choose_action", "record_outcome"]:
    if state.failure is not None:
        return "record_outcome"
    if state.event is None:
        return "narrate_event"  # rejected: retry with the feedback
    if state.event.is_wait:
        return "record_outcome"
    return "choose_action"


def route_program(state: PlanningState) -> Literal["parse_event", "record_outcome"]:
    if state.parsed is not None or state.failure is not None:
        return "record_outcome"
    return "parse_event"


class NodeFn(Protocol):
    """A node of the planning graph: state in, state update out, dependencies from the runtime."""

    def __call__(self, state: PlanningState, *, runtime: Runtime[PlanningDeps]) -> Awaitable[dict[str, Any]]: ...


PlanningGraph = StateGraph[PlanningState, PlanningDeps, PlanningState, PlanningState]
CompiledPlanningGraph = CompiledStateGraph[PlanningState, PlanningDeps, Any, Any]
"""The compiled planning graph. Its input and output are typed ``Any``: langgraph types them as
the state model, but our callers pass a dict of state fields (``PlanningState.model_dump()``,
or some of its fields to resume a thread) and the graph returns the state's values as a dict."""


def build_planning_graph(
    describe: NodeFn = describe_scene, parse: NodeFn = parse_event, check: NodeFn = check_program,
    choose: NodeFn = choose_seat, act: NodeFn = choose_action,
) -> PlanningGraph:
    """The uncompiled graph; compile with a checkpointer (see :func:`compile_planning_graph`).

    The ablations swap nodes, never the wiring: ``describe`` (a preset description),
    ``parse`` / ``check`` (the event parser's call and its check, e.g. coordinates), ``choose``
    (the seat choice; a pass-through for a parser that writes no program), ``act`` (the action
    choice of an event whose words name none; a pass-through likewise)."""
    graph = StateGraph(PlanningState, context_schema=PlanningDeps)
    graph.add_node("describe_scene", describe)
    graph.add_node("check_description", check_description)
    graph.add_node("narrate_event", narrate_event)
    graph.add_node("check_narration", check_narration)
    graph.add_node("choose_action", act)
    graph.add_node("choose_seat", choose)
    graph.add_node("parse_event", parse)
    graph.add_node("check_program", check)
    graph.add_node("record_outcome", record_outcome)
    graph.add_edge(START, "describe_scene")
    graph.add_conditional_edges("describe_scene", route_description)
    graph.add_conditional_edges("check_description", route_checked_description)
    graph.add_edge("narrate_event", "check_narration")
    graph.add_conditional_edges("check_narration", route_narration)
    graph.add_edge("choose_action", "choose_seat")
    graph.add_edge("choose_seat", "parse_event")
    graph.add_edge("parse_event", "check_program")
    graph.add_conditional_edges("check_program", route_program)
    graph.add_conditional_edges("record_outcome", route_step)
    return graph


def compile_planning_graph(checkpointer: Checkpointer = None) -> CompiledPlanningGraph:
    return build_planning_graph().compile(checkpointer=checkpointer)


def recursion_limit(events: int, max_retries: int) -> int:
    """Enough super-steps for K events with every retry used: per step 2 nodes per attempt
    of each LLM role plus the action and seat choices and the record node, plus 2 nodes per
    describer attempt."""
    return 2 * (max_retries + 1) + 4 + events * (4 * (max_retries + 1) + 4)

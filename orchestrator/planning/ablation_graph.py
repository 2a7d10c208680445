"""The paper's ablations on langgraph, with the planning graph's state, context and story log.

``storyteller plan`` / ``storyteller run`` pick a planner (``--planner``) and a scene description
(``--description``):

- planner ``event`` (the full method) is the planning graph itself
  (:func:`orchestrator.planning.graph.compile_planning_graph`: narrator, event parser and
  their feedback loops, one LLM call per node, checkpointed per call). With a description
  ablation it is wrapped by :class:`PresetDescriptionGraph`, which hands a fresh thread the
  object list or scene graph as its description, so the describer node has nothing to do;
- planner ``unified`` ("w/o Event", :class:`agents.ablation_planners.UnifiedPlanner`, node
  ``planner``) and ``direct`` ("Direct Inference",
  :class:`agents.ablation_planners.DirectInferencePlanner`, nodes ``narrator`` and
  ``event_parser``) run on a small graph of their own (:func:`build_ablation_graph`): the
  main graph's describer nodes (one per describer call and check, cached on disk) or one
  node setting a preset description, one ``plan_step`` node per planning step, and the main
  graph's ``record_outcome``. A resumed run repeats the calls of an interrupted step, never those of a
  finished one;
- description ``describer`` asks the describer; ``object-list`` and ``scene-graph`` use
  :func:`~agents.ablation_planners.object_list_description` and
  :func:`~agents.ablation_planners.scene_graph_description` (no LLM call).

All of them take :class:`PlanningState` and :class:`PlanningDeps` unchanged, so
:class:`~orchestrator.session.step_planner.GraphStepPlanner` drives them in a simulation exactly
like the main graph. In ``plan_step``, a model that is unavailable after the client's retries
and fallbacks (:class:`~agents.llm_port.LLMError`) makes the step fail, as in the main graph;
a replay miss propagates.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, Literal, get_args

from langgraph.graph import END, START, StateGraph
from langgraph.runtime import Runtime

from agents.ablation_planners import (
    DirectInferencePlanner,
    JudgeHook,
    Planner,
    PlanningStep,
    UnifiedPlanner,
    object_list_description,
    scene_graph_description,
)
from agents.llm_port import LLMError, LLMRequest, LLMResponse, NodeName, ReplayMissError
from agents.messages import ParsedEvent, PlanningFailure, SceneDescription
from orchestrator.planning import graph as planning_graph
from orchestrator.planning.state import PlanningDeps, PlanningState

PlannerKind = Literal["event", "unified", "direct"]
DescriptionKind = Literal["describer", "object-list", "scene-graph"]
PLANNER_KINDS: tuple[str, ...] = get_args(PlannerKind)
DESCRIPTION_KINDS: tuple[str, ...] = get_args(DescriptionKind)


class AblationChoiceError(ValueError):
    """An unknown ``--planner`` or ``--description`` value."""


@dataclass(frozen=True)
class Ablation:
    """Which planner and which scene description a run uses."""

    planner: PlannerKind = "event"
    description: DescriptionKind = "describer"

    @classmethod
    def parse(cls, planner: str, description: str) -> Ablation:
        """Validate command-line values; raises :class:`AblationChoiceError` naming the option."""
        if planner not in PLANNER_KINDS:
            raise AblationChoiceError(f"--planner must be one of {', '.join(PLANNER_KINDS)}; got {planner!r}")
        if description not in DESCRIPTION_KINDS:
            raise AblationChoiceError(
                f"--description must be one of {', '.join(DESCRIPTION_KINDS)}; got {description!r}"
            )
        return cls(planner=planner, description=description)  # type: ignore[arg-type]

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


# ----- nodes ------------------------------------------------------------------------------
NodeFn = Callable[[PlanningState, Runtime[PlanningDeps]], Awaitable[dict[str, Any]]]


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


class CountingPort:
    """Passes requests through with the step's simulation frame attached (trace metadata, not
    hashed), counting calls per node and keeping the trace seqs of the answers."""

    def __init__(self, port: Any, sim_frame: int | None = None) -> None:
        self.port = port
        self.sim_frame = sim_frame
        self.calls: dict[NodeName, int] = {}
        self.last_node: NodeName | None = None
        self.trace_seqs: list[int] = []
        self.last_seq: int | None = None

    async def complete(self, request: LLMRequest) -> LLMResponse:
        self.last_node = request.node
        self.calls[request.node] = self.calls.get(request.node, 0) + 1
        if self.sim_frame is not None:
            request = request.model_copy(update={"sim_frame": self.sim_frame})
        response = await self.port.complete(request)
        self.last_seq = response.trace_seq
        if response.trace_seq is not None:
            self.trace_seqs.append(response.trace_seq)
        return response


def parsed_recorder(deps: PlanningDeps, counting: CountingPort) -> JudgeHook | None:
    """A hook that traces what each attempt parsed to (or the typed error that rejected it),
    against the attempt record of the reply just judged."""
    sink = deps.trace_sink()
    if sink is None:
        return None

    def record(node: str, parsed: Any, error: BaseException | None, feedback: str | None) -> None:
        if counting.last_seq is None:
            return
        if error is None:
            sink.record_parsed(counting.last_seq, parsed, node=node)
        else:
            sink.record_parsed(counting.last_seq, None, node=node, error_type=type(error).__name__, error_message=feedback)

    return record


def make_planner(kind: PlannerKind, port: Any, deps: PlanningDeps, judged: JudgeHook | None = None) -> Planner:
    if kind == "unified":
        return UnifiedPlanner(port, deps.prompts, max_retries=deps.max_retries, judged=judged)
    if kind == "direct":
        return DirectInferencePlanner(port, deps.prompts, max_retries=deps.max_retries, judged=judged)
    raise ValueError(f"planner {kind!r} runs on the planning graph's own nodes")


def plan_node(kind: PlannerKind) -> NodeFn:
    """One whole planning step of an ablation planner (all its LLM calls and retries)."""

    async def plan_step(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
        deps = runtime.context
        assert state.description is not None
        counting = CountingPort(deps.port, sim_frame=state.sim_frame)
        step = PlanningStep(
            index=state.step,
            scene=deps.scene,
            description=state.description,
            characters=state.roster,
            instruction=state.instruction,
            world=deps.world.world_view(state.roster),
            action_labels=deps.action_labels,
            history=state.recent,
            seats_in_use=deps.world.seats_in_use(state.roster),
            tags=deps.tags,
            seed=deps.seed,
            graph=deps.scene_graph,
            runner=deps.runner,
        )
        try:
            outcome = await make_planner(kind, counting, deps, parsed_recorder(deps, counting)).plan(step)
        except ReplayMissError:
            raise
        except LLMError as exc:  # the model is out after the client's retries: the step fails
            node = counting.last_node if counting.last_node in ("narrator", "event_parser", "planner") else "planner"
            outcome = PlanningFailure(
                index=state.step,
                node=node,  # type: ignore[arg-type]
                attempts=counting.calls.get(node, 1),  # type: ignore[call-overload]
                feedback=f"{type(exc).__name__}: {exc}",
            )
        update: dict[str, Any] = {"llm_calls": state.llm_calls + sum(counting.calls.values())}
        update["step_trace_seqs"] = (*state.step_trace_seqs, *counting.trace_seqs)  # kept with the outcome
        if isinstance(outcome, ParsedEvent):
            update["parsed"] = outcome
        elif isinstance(outcome, PlanningFailure):
            update["failure"] = outcome
        return update

    return plan_step


# ----- graphs -----------------------------------------------------------------------------
def build_ablation_graph(ablation: Ablation) -> StateGraph:
    """The uncompiled graph of an ablation planner (``unified`` or ``direct``)."""
    if ablation.planner == "event":
        raise ValueError("the event planner runs on the planning graph itself (see compile_graph)")
    step_map: dict[Any, str] = {"narrate_event": "plan_step", "record_outcome": "record_outcome", END: END}
    graph = StateGraph(PlanningState, context_schema=PlanningDeps)
    graph.add_node("plan_step", plan_node(ablation.planner))
    graph.add_node("record_outcome", planning_graph.record_outcome)
    graph.add_edge(START, "describe_scene")
    if ablation.description == "describer":  # the planning graph's describer nodes and routers
        graph.add_node("describe_scene", planning_graph.describe_scene)
        graph.add_node("check_description", planning_graph.check_description)
        graph.add_conditional_edges(
            "describe_scene", planning_graph.route_description, {**step_map, "check_description": "check_description"}
        )
        graph.add_conditional_edges(
            "check_description", planning_graph.route_checked_description, {**step_map, "describe_scene": "describe_scene"}
        )
    else:
        graph.add_node("describe_scene", preset_node(ablation.description))
        graph.add_conditional_edges("describe_scene", planning_graph.route_step, step_map)
    graph.add_edge("plan_step", "record_outcome")
    graph.add_conditional_edges("record_outcome", planning_graph.route_step, step_map)
    return graph


class PresetDescriptionGraph:
    """The compiled planning graph, but a fresh thread starts with a preset description
    (object list or scene graph), so its describer node passes straight on to planning.
    Everything else is the wrapped graph's."""

    def __init__(self, graph: Any, kind: DescriptionKind) -> None:
        self.graph = graph
        self.kind = kind

    def astream(self, start: Any, *args: Any, **kwargs: Any) -> Any:
        deps = kwargs.get("context")
        if isinstance(start, dict) and "description" in start and start["description"] is None:
            if not isinstance(deps, PlanningDeps):
                raise TypeError("PresetDescriptionGraph.astream needs context=PlanningDeps")
            start = {**start, "description": preset_description(self.kind, deps).model_dump()}
        return self.graph.astream(start, *args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.graph, name)


def compile_graph(ablation: Ablation, checkpointer: Any = None, **kwargs: Any) -> Any:
    """The compiled graph of ``ablation``: the planning graph itself for the default."""
    if ablation.planner == "event":
        graph = planning_graph.compile_planning_graph(checkpointer, **kwargs)
        return graph if ablation.description == "describer" else PresetDescriptionGraph(graph, ablation.description)
    return build_ablation_graph(ablation).compile(checkpointer=checkpointer, **kwargs)

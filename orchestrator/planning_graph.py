"""The planning graph: describer -> narrator -> (feedback) -> event parser -> (feedback) -> record.

Nodes are verbs; every node makes at most one LLM call, so with ``durability="sync"`` each
call's reply is checkpointed before anything else happens, and a resumed run never repeats a
finished call (the describer's retries are the exception: it is cached on disk instead).

::

    START -> describe_scene -> route_step --> narrate_event -> check_narration --+
                 ^                  |  (no free character: wait)               |
                 |                  v                                          v
                 |            record_outcome <-- check_program <-- parse_event <+
                 +------------------+      (retries loop back through the routers)

Routers return ``Literal[...]`` node names. Dependencies (LLM port, scene, world view
provider, story log) come from ``Runtime[PlanningDeps]``.
"""

from __future__ import annotations

from typing import Any, Literal

from langgraph.graph import END, START, StateGraph
from langgraph.runtime import Runtime

from agents.describer import describe_scene_cached
from agents.event_parser import PARSER_RETRY_INSTRUCTION, ParserInput, parser_request, run_reply
from agents.llm_port import LLMError, ReplayMissError
from agents.messages import CharacterStatus, HistoryEntry, ParsedEvent, PlanningFailure
from agents.narrator import NarratorInput, narrator_request, parse_narration
from agents.retry_feedback import REJECTIONS, feedback_from_error
from orchestrator.planning_state import RECENT_WINDOW, PlanningDeps, PlanningState, RetryTurn

NODES = ("describe_scene", "narrate_event", "check_narration", "parse_event", "check_program", "record_outcome")


# ----- nodes ------------------------------------------------------------------------------
async def describe_scene(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """Describe the scene once per run (cached on disk per scene, model and prompts)."""
    if state.description is not None:
        return {}
    deps = runtime.context
    description = await describe_scene_cached(
        deps.port,
        deps.prompts,
        deps.scene,
        model=deps.describer_model,
        cache_dir=deps.description_cache,
        mode=deps.describer_mode,
        max_retries=deps.max_retries,
    )
    return {"description": description}


def _narrator_input(state: PlanningState, deps: PlanningDeps) -> NarratorInput:
    assert state.description is not None
    return NarratorInput(
        scene_description=state.description.text,
        characters=state.roster,
        instruction=state.instruction,
        history=state.recent,
        tags=deps.tags,
        seed=deps.seed,
    )


async def narrate_event(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """One narrator call; its reply is checked by the next node."""
    deps = runtime.context
    turns = tuple(t.as_turn() for t in state.narrator_turns)
    try:
        response = await deps.port.complete(narrator_request(deps.prompts, _narrator_input(state, deps), turns))
    except LLMError as exc:
        return _unavailable(state, "narrator", exc)
    return {"narrator_reply": response.text, "llm_calls": state.llm_calls + 1}


def _unavailable(state: PlanningState, node: Literal["narrator", "event_parser"], exc: LLMError) -> dict[str, Any]:
    """The model gave no answer after the client's own retries and fallbacks: this step fails
    (the story goes on and asks again later). A replay miss is a bug in the run, not an outage,
    so it propagates."""
    if isinstance(exc, ReplayMissError):
        raise exc
    turns = state.narrator_turns if node == "narrator" else state.parser_turns
    return {
        "failure": PlanningFailure(
            index=state.step, node=node, attempts=len(turns) + 1, feedback=f"{type(exc).__name__}: {exc}"
        ),
        "llm_calls": state.llm_calls + 1,
    }


async def check_narration(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """Accept the narrator's reply, or turn what is wrong with it into feedback."""
    deps = runtime.context
    if state.failure is not None:
        return {}
    reply = state.narrator_reply or ""
    attempts = len(state.narrator_turns) + 1
    try:
        out = parse_narration(reply, state.roster)
    except REJECTIONS as exc:
        feedback = feedback_from_error(exc)
        update: dict[str, Any] = {
            "narrator_turns": (*state.narrator_turns, RetryTurn(reply=reply, feedback=feedback)),
            "narrator_reply": None,
        }
        if attempts > deps.max_retries:
            update["failure"] = PlanningFailure(index=state.step, node="narrator", attempts=attempts, feedback=feedback)
        return update
    return {"event": out.event, "narrator_attempts": attempts, "narrator_reply": None}


def _parser_input(state: PlanningState, deps: PlanningDeps) -> ParserInput:
    assert state.description is not None and state.event is not None
    return ParserInput(
        scene_description=state.description.text,
        event=state.event,
        characters=state.roster,
        action_labels=deps.action_labels,
        tags=deps.tags,
        seats_in_use=deps.world.seats_in_use(state.roster),
        seed=deps.seed,
    )


async def parse_event(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """One event-parser call; the program in its reply is run by the next node."""
    deps = runtime.context
    turns = tuple(t.as_turn() for t in state.parser_turns)
    try:
        response = await deps.port.complete(parser_request(deps.prompts, _parser_input(state, deps), turns))
    except LLMError as exc:
        return _unavailable(state, "event_parser", exc)
    return {"parser_reply": response.text, "llm_calls": state.llm_calls + 1}


async def check_program(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """Run the reply's parse_event() in the sandbox; a typed error becomes feedback."""
    deps = runtime.context
    if state.failure is not None:
        return {}
    assert state.event is not None
    reply = state.parser_reply or ""
    attempts = len(state.parser_turns) + 1
    try:
        result = run_reply(
            reply,
            scene=deps.scene,
            event=state.event,
            world=deps.world.world_view(state.roster),
            seed=deps.seed + state.step,
            action_labels=deps.action_labels,
            graph=deps.scene_graph,
            runner=deps.runner,
        )
    except REJECTIONS as exc:
        feedback = feedback_from_error(exc, instruction=PARSER_RETRY_INSTRUCTION)
        update: dict[str, Any] = {
            "parser_turns": (*state.parser_turns, RetryTurn(reply=reply, feedback=feedback)),
            "parser_reply": None,
        }
        if attempts > deps.max_retries:
            update["failure"] = PlanningFailure(
                index=state.step, node="event_parser", attempts=attempts, feedback=feedback
            )
        return update
    parsed = ParsedEvent(
        index=state.step,
        event=state.event,
        plans=result.plans,
        program=result.program,
        narrator_attempts=state.narrator_attempts,
        parser_attempts=attempts,
    )
    return {"parsed": parsed, "parser_reply": None}


async def record_outcome(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """Log the step's outcome, move and occupy its characters, release finished ones."""
    deps = runtime.context
    step = state.step
    outcome: ParsedEvent | PlanningFailure | None = state.parsed or state.failure
    deps.story.record(step, outcome)
    roster = {c.name: c for c in state.roster}
    busy_until = dict(state.busy_until)
    recent = list(state.recent)
    if state.parsed is not None:
        ongoing = deps.busy_for_events > 0
        for plan in state.parsed.plans:
            roster[plan.character] = CharacterStatus(
                name=plan.character,
                busy=ongoing,
                action=plan.action,
                position=plan.position,
                facing=plan.facing,
                event_index=step if ongoing else None,
                seat=plan.seat,
            )
            busy_until[plan.character] = step + deps.busy_for_events
        recent.append(
            HistoryEntry(
                index=step,
                characters=state.parsed.event.characters,
                activity=state.parsed.event.activity,
                state="ongoing" if ongoing else "completed",
            )
        )
    next_step = step + 1
    for name, until in list(busy_until.items()):
        if next_step > until:
            del busy_until[name]
            if roster[name].busy:
                roster[name] = roster[name].model_copy(update={"busy": False, "event_index": None})
    still_busy = {n for n in busy_until}
    recent = [
        h if h.state != "ongoing" or any(c in still_busy for c in h.characters) else h.model_copy(update={"state": "completed"})
        for h in recent
    ][-RECENT_WINDOW:]
    return {
        "step": next_step,
        "roster": tuple(roster[c.name] for c in state.roster),
        "busy_until": busy_until,
        "recent": tuple(recent),
        "narrator_reply": None,
        "narrator_turns": (),
        "event": None,
        "narrator_attempts": 0,
        "parser_reply": None,
        "parser_turns": (),
        "parsed": None,
        "failure": None,
    }


# ----- routers ----------------------------------------------------------------------------
def route_step(state: PlanningState) -> Literal["narrate_event", "record_outcome", "__end__"]:
    """Next step: done after K steps; with no free character the step is a wait."""
    if state.step >= state.events_target:
        return END
    if not state.free:
        return "record_outcome"
    return "narrate_event"


def route_narration(state: PlanningState) -> Literal["narrate_event", "parse_event", "record_outcome"]:
    if state.failure is not None:
        return "record_outcome"
    if state.event is None:
        return "narrate_event"  # rejected: retry with the feedback
    if state.event.is_wait:
        return "record_outcome"
    return "parse_event"


def route_program(state: PlanningState) -> Literal["parse_event", "record_outcome"]:
    if state.parsed is not None or state.failure is not None:
        return "record_outcome"
    return "parse_event"


def build_planning_graph() -> StateGraph:
    """The uncompiled graph; compile with a checkpointer (see :func:`compile_planning_graph`)."""
    graph = StateGraph(PlanningState, context_schema=PlanningDeps)
    graph.add_node("describe_scene", describe_scene)
    graph.add_node("narrate_event", narrate_event)
    graph.add_node("check_narration", check_narration)
    graph.add_node("parse_event", parse_event)
    graph.add_node("check_program", check_program)
    graph.add_node("record_outcome", record_outcome)
    graph.add_edge(START, "describe_scene")
    graph.add_conditional_edges("describe_scene", route_step)
    graph.add_edge("narrate_event", "check_narration")
    graph.add_conditional_edges("check_narration", route_narration)
    graph.add_edge("parse_event", "check_program")
    graph.add_conditional_edges("check_program", route_program)
    graph.add_conditional_edges("record_outcome", route_step)
    return graph


def compile_planning_graph(checkpointer: Any = None, **kwargs: Any) -> Any:
    return build_planning_graph().compile(checkpointer=checkpointer, **kwargs)


def recursion_limit(events: int, max_retries: int) -> int:
    """Enough super-steps for K events with every retry used: per step 2 nodes per attempt
    of each LLM role plus the record node, plus the describer."""
    return 4 + events * (4 * (max_retries + 1) + 2)

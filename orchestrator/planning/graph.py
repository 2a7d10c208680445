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

``choose_seat`` (:mod:`orchestrator.planning.seat_node`) decides the seat of a one-character
sitting event among the seats the scene allows, checked against the relations the words state,
with at most one call (scored continuations); other events pass through it without a call.
Before it, ``choose_action`` (:mod:`orchestrator.planning.action_node`) lets the model rank the
action labels of an event whose words name no action the label ranker knows (one call, scored
continuations); its choice is the parser's suggestion and the first label its grammar offers.

Off the event loop: running an event program (scene-graph queries, position sampling, or the
wait on the program's worker process), building the parser's input (its grammar), the
describer's clusters, and logging a step's outcome (the trace's fsync, then the story log's
SQLite commit) happen in a worker thread (:func:`off_loop`), so a session's simulation task
keeps its frame rate while a step is checked.

Routers return ``Literal[...]`` node names. Dependencies (LLM port, scene, world view
provider, story log, trace sink) come from ``Runtime[PlanningDeps]``.

Progress: with ``deps.progress`` set (a story session does, per step), :func:`complete` reports
every call's latency and ``check_narration`` reports the accepted event's characters before
the event parser is asked, so the session may plan the next event beside this one.

Traces: every request carries ``state.sim_frame`` (the frame of the world snapshot the step
plans from; None without a simulation) as metadata outside the request hash. The check
nodes record, for the attempt they judged, the parsed output (narrator event, event-parser
plans per character, describer areas) or the typed error that rejected it (one update for
every check node and ablation: :func:`orchestrator.planning.rejection.rejected_reply`). The
seqs of a step's narrator and event-parser attempts are stored with its outcome in the story log
(:meth:`~orchestrator.planning.checkpoints.StoryLog.trace_seqs`) for the ``applied`` record.
"""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, Literal, Protocol, TypeVar

import anyio.to_thread
from langgraph.graph import START, StateGraph
from langgraph.graph.state import CompiledStateGraph
from langgraph.runtime import Runtime
from langgraph.types import Checkpointer

from agents.bystanders import scene_now
from agents.describer import (
    best_effort,
    describer_request,
    description_cache_file,
    finish,
    judge_reply,
    read_cached,
    write_cached,
)
from agents.device_in_use import waiting_for_busy_device
from agents.event_parser import (
    PARSER_RETRY_INSTRUCTION,
    ParserInput,
    event_text,
    parser_request,
    run_reply,
)
from agents.history import keep_window
from agents.instruction_parts import InstructionProgress
from agents.llm_port import LLMError, LLMRequest, LLMResponse, ReplayMissError
from agents.messages import (
    CharacterStatus,
    Event,
    HistoryEntry,
    ParsedEvent,
    PlanningFailure,
)
from agents.narrator import NarratorInput, narrator_request, parse_narration, waits_without_a_call
from agents.program_grammar import event_program_grammar
from agents.retry_feedback import REJECTIONS
from orchestrator.planning.action_node import choose_action
from orchestrator.planning.rejection import record_parsed, rejected_reply
from orchestrator.planning.seat_node import choose_seat
from orchestrator.planning.state import PlanningDeps, PlanningState
from tools.errors import ObjectInUseError

NODES = (
    "describe_scene", "check_description", "narrate_event", "check_narration", "choose_action", "choose_seat",
    "parse_event", "check_program", "record_outcome",
)


_T = TypeVar("_T")


async def off_loop(fn: Callable[[], _T]) -> _T:
    """``fn()`` in a worker thread (CPU work and blocking waits never run on the event loop);
    its exception is raised here. A cancelled caller waits for ``fn`` to return."""
    return await anyio.to_thread.run_sync(fn)


async def complete(deps: PlanningDeps, request: LLMRequest, state: PlanningState) -> LLMResponse:
    """One LLM call with the step's simulation frame attached (metadata, not hashed); its
    latency goes to ``deps.progress`` (the response's, which a replay takes from the trace;
    the wall time of a call that failed)."""
    started = time.monotonic()
    try:
        response = await deps.port.complete(request.model_copy(update={"sim_frame": state.sim_frame}))
    except LLMError:
        if deps.progress is not None:
            deps.progress.llm_call(request.node, time.monotonic() - started)
        raise
    if deps.progress is not None:
        deps.progress.llm_call(request.node, response.latency_s)
    return response


# ----- nodes ------------------------------------------------------------------------------
def _description_cache(deps: PlanningDeps) -> Path | None:
    if deps.description_cache is None:
        return None
    return description_cache_file(deps.description_cache, deps.scene, deps.describer_model, deps.describer_mode, deps.prompts)


async def describe_scene(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """One describer call (the scene is described once per run; cached on disk per scene,
    model and prompts). A describer that cannot answer stops the run (LLMError)."""
    if state.description is not None:
        return {}
    deps = runtime.context
    path = _description_cache(deps)
    if not state.describer_turns and path is not None and (hit := read_cached(path)) is not None:
        return {"description": hit}
    turns = tuple(t.as_turn() for t in state.describer_turns)
    inp = await off_loop(deps.describer_input)
    response = await complete(deps, describer_request(deps.prompts, inp, turns), state)
    return {"describer_reply": response.text, "describer_seq": response.trace_seq, "llm_calls": state.llm_calls + 1}


async def check_description(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """Accept the describer's reply, or keep its feedback for another call; after the last
    rejected call, repair the best answer from the clusters."""
    deps = runtime.context
    inp = await off_loop(deps.describer_input)
    reply = state.describer_reply or ""
    judged = await off_loop(lambda: judge_reply(reply, inp))
    attempts = len(state.describer_turns) + 1
    update: dict[str, Any] = {"describer_reply": None, "describer_seq": None}
    if judged.areas is not None:
        record_parsed(deps, state.describer_seq, "describer", judged.areas.model_dump(mode="json"))
        description = finish(inp, judged.areas, repaired=False, attempts=attempts)
    else:
        assert judged.turn is not None and judged.error is not None
        update = rejected_reply(state, deps, "describer", judged.turn.reply, judged.error, feedback=judged.turn.feedback)
        turns = update["describer_turns"]
        if attempts <= deps.max_retries:
            return update
        description = await off_loop(lambda: best_effort(inp, [t.as_turn() for t in turns]))
    path = _description_cache(deps)
    if path is not None:
        write_cached(path, description)
    return {**update, "description": description, "describer_turns": ()}


def narrator_input(state: PlanningState, deps: PlanningDeps) -> NarratorInput:
    """The narrator's input for the state's step (the one builder: ablation nodes use it too),
    with the scene now (everyday activities for bystanders, who uses what): CPU work, so nodes
    build it off the event loop."""
    assert state.description is not None
    choices, areas = deps.everyday()
    return NarratorInput(
        scene_description=state.description.text,
        characters=state.roster,
        instruction=state.instruction,
        instruction_since=state.instruction_since,
        history=state.recent,
        earlier=state.earlier,
        tags=deps.tags,
        seed=deps.seed,
        sim_frame=state.sim_frame,
        now=scene_now(deps.scene, deps.action_labels, choices, areas, deps.world.world_view(state.roster), state.roster),
    )


def _with_seq(state: PlanningState, seq: int | None) -> tuple[int, ...]:
    return state.step_trace_seqs if seq is None else (*state.step_trace_seqs, seq)


def reply_update(state: PlanningState, role: Literal["narrator", "parser"], response: Any) -> dict[str, Any]:
    """State update for one answered call: the reply, its trace seq, the step's seqs, the count."""
    return {
        f"{role}_reply": response.text,
        f"{role}_seq": response.trace_seq,
        "step_trace_seqs": _with_seq(state, response.trace_seq),
        "llm_calls": state.llm_calls + 1,
    }


async def narrate_event(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """One narrator call; its reply is checked by the next node."""
    deps = runtime.context
    turns = tuple(t.as_turn() for t in state.narrator_turns)
    try:
        inp = await off_loop(lambda: narrator_input(state, deps))
        response = await complete(deps, narrator_request(deps.prompts, inp, turns), state)
    except LLMError as exc:
        return unavailable(state, "narrator", exc)
    return reply_update(state, "narrator", response)


def unavailable(
    state: PlanningState, node: Literal["narrator", "event_parser", "planner"], exc: LLMError
) -> dict[str, Any]:
    """The model gave no answer after the client's own retries and fallbacks: this step fails
    (the story goes on and asks again later). A replay miss is a bug in the run, not an outage,
    so it propagates."""
    if isinstance(exc, ReplayMissError):
        raise exc
    turns = state.narrator_turns if node == "narrator" else state.parser_turns
    return {
        "failure": PlanningFailure(
            index=state.step, node=node, attempts=len(turns) + 1, feedback=f"{type(exc).__name__}: {exc}",
            event=state.event if node == "event_parser" else None, part=state.part if node == "event_parser" else "",
        ),
        "step_trace_seqs": (*state.step_trace_seqs, *exc.trace_seqs),
        "llm_calls": state.llm_calls + 1,
    }


async def check_narration(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """Accept the narrator's reply, or turn what is wrong with it into feedback."""
    deps = runtime.context
    if state.failure is not None:
        return {}
    reply = state.narrator_reply or ""
    attempts = len(state.narrator_turns) + 1
    inp = await off_loop(lambda: narrator_input(state, deps))
    try:
        out = parse_narration(reply, state.roster, deps.prompts, inp.bystanders)
    except REJECTIONS as exc:
        return rejected_reply(state, deps, "narrator", reply, exc)
    record_parsed(deps, state.narrator_seq, "narrator", out.model_dump(mode="json"))
    progress = inp.progress
    event = with_all_part_actors(out.event, progress)
    part = instruction_part(progress, event)
    if deps.progress is not None and not event.is_wait:
        deps.progress.claim(event.characters, event.activity, part)
    return {"event": event, "part": part, "narrator_attempts": attempts, "narrator_reply": None, "narrator_seq": None}


def with_all_part_actors(event: Event, progress: InstructionProgress) -> Event:
    """``event``, with every actor of the part the narrator was asked to take next when it
    named only some of them ("Ava and Ben hug" narrated for Ben alone): the part is theirs
    together, and they are all free (a part is only offered when they are)."""
    actors = progress.next_actors
    if progress.next_part is None or not event.characters or not set(event.characters) < set(actors):
        return event
    return event.model_copy(update={"characters": tuple(actors)})


def instruction_part(progress: InstructionProgress, event: Event) -> str:
    """The instruction part ``event`` carries out: the part the narrator was asked to take
    next, when the event's characters are among its actors ("" otherwise)."""
    if progress.next_part is None or not event.characters:
        return ""
    if progress.next_actors and not set(event.characters) <= set(progress.next_actors):
        return ""
    return progress.next_part


def parser_input(state: PlanningState, deps: PlanningDeps) -> ParserInput:
    """The event parser's input for the state's event (the one builder: ablation nodes use it too)."""
    assert state.description is not None and state.event is not None
    part = state.part
    widen = any(t.error == "UnsatisfiableAreaError" for t in state.parser_turns)
    seat = None if widen else state.seat  # the chosen seat had no room: every free seat again
    labels = deps.labels_now(state.recent)
    return ParserInput(
        scene_description=state.description.text,
        event=state.event,
        characters=state.roster,
        action_labels=labels,
        tags=deps.tags,
        seats_in_use=deps.world.seats_in_use(state.roster),
        seed=deps.seed,
        sim_frame=state.sim_frame,
        instruction_part=part,
        seat=seat,
        action=state.action,
        grammar=event_program_grammar(
            deps.scene, state.event.characters, state.roster, deps.world.seats_in_use(state.roster), labels,
            activity=event_text(state.event.activity, part),
            widen=widen,
            context=state.event.activity if part else "",
            seat=seat,
            action=state.action,
        ) if deps.program_grammar else None,
    )


async def parse_event(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """One event-parser call; the program in its reply is run by the next node."""
    deps = runtime.context
    turns = tuple(t.as_turn() for t in state.parser_turns)
    request = await off_loop(lambda: parser_request(deps.prompts, parser_input(state, deps), turns))
    try:
        response = await complete(deps, request, state)
    except LLMError as exc:
        return unavailable(state, "event_parser", exc)
    return reply_update(state, "parser", response)


async def check_program(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """Run the reply's parse_event() in the sandbox; a typed error becomes feedback. A program
    that gives a character an object another one uses alone is refused once with that feedback
    (ObjectInUseError) while a retry is left; after it, or on the last attempt, such a character
    waits by the object instead (idle). Words
    about a device every one of which is in use, with a program that avoids it, make the
    event's characters wait for it (:mod:`agents.device_in_use`)."""
    deps = runtime.context
    if state.failure is not None:
        return {}
    assert state.event is not None
    reply = state.parser_reply or ""
    attempts = len(state.parser_turns) + 1
    event = state.event
    world = deps.world.world_view(state.roster)
    told = any(t.error == ObjectInUseError.__name__ for t in state.parser_turns)
    if told or attempts > deps.max_retries:
        world = world.model_copy(update={"busy_objects": "wait"})  # told once, or no retry left: whoever is refused waits
    try:
        result = await off_loop(lambda: run_reply(
            reply,
            scene=deps.scene,
            event=event,
            world=world,
            seed=deps.seed + state.step,
            action_labels=deps.action_labels,
            graph=deps.scene_graph,
            runner=deps.runner,
        ))
    except REJECTIONS as exc:
        return rejected_reply(state, deps, "event_parser", reply, exc, instruction=PARSER_RETRY_INSTRUCTION)
    # words about a device nobody leaves free: its characters wait for it
    plans = waiting_for_busy_device(event_text(event.activity, state.part), result.plans, world, deps.scene,
                                    event.characters)
    parsed = ParsedEvent(
        index=state.step,
        event=state.event,
        plans=plans,
        program=result.program,
        narrator_attempts=state.narrator_attempts,
        parser_attempts=attempts,
        part=state.part,
    )
    record_parsed(deps, state.parser_seq, "event_parser", {
        "plans": [p.model_dump(mode="json") for p in plans], "program": result.program,
    })
    return {"parsed": parsed, "parser_reply": None, "parser_seq": None}


async def record_outcome(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """Log the step's outcome, move and occupy its characters, release finished ones."""
    deps = runtime.context
    step = state.step
    outcome: ParsedEvent | PlanningFailure | None = state.parsed or state.failure
    sink = deps.trace_sink()

    def log() -> None:  # the step's trace records on disk first: the log (and the session) count on them
        if sink is not None:
            sink.sync()
        deps.story.record(step, outcome, trace_seqs=state.step_trace_seqs)

    await off_loop(log)
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
                part=state.parsed.part,
            )
        )
    elif state.failure is not None and state.failure.event is not None:  # the part stays open
        recent.append(HistoryEntry(
            index=step, characters=state.failure.event.characters, activity=state.failure.event.activity,
            state="failed", part=state.failure.part,
        ))
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
    ]
    window, earlier = keep_window(recent, state.earlier)
    return {
        "step": next_step,
        "roster": tuple(roster[c.name] for c in state.roster),
        "busy_until": busy_until,
        "recent": window,
        "earlier": earlier,
        "step_trace_seqs": (),
        "narrator_reply": None,
        "narrator_seq": None,
        "narrator_turns": (),
        "event": None,
        "part": "",
        "narrator_attempts": 0,
        "parser_reply": None,
        "parser_seq": None,
        "parser_turns": (),
        "seat": None,
        "action": None,
        "parsed": None,
        "failure": None,
    }


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
    for the free ones now (``agents.instruction_parts``), the step is a wait, without a call."""
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

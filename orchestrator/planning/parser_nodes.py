"""The event parser's nodes: ``parse_event`` (one event-parser call) and ``check_program`` (run
the reply's program in the sandbox; a typed error becomes feedback), and :func:`parser_input`,
the one builder of the parser's input (the ablation nodes use it too).
"""

from __future__ import annotations

from typing import Any

from langgraph.runtime import Runtime

from storyteller.agents.area_words import described_areas
from storyteller.agents.device_in_use import waiting_for_busy_device
from storyteller.agents.event_parser import (
    PARSER_RETRY_INSTRUCTION,
    ParserInput,
    event_text,
    parser_request,
    run_reply,
)
from storyteller.agents.instruction_parts import served_characters
from storyteller.agents.messages import ParsedEvent
from storyteller.agents.program_grammar import event_program_grammar, free_seats
from storyteller.agents.retry_feedback import REJECTIONS
from storyteller.orchestrator.planning.node_calls import ask, off_loop
from storyteller.orchestrator.planning.rejection import record_parsed, rejected_reply
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState
from storyteller.tools.character_states import WorldView
from storyteller.tools.errors import ObjectInUseError


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
            areas=described_areas(state.description.text, deps.scene.object_names),
            served=served_characters(state.instruction, part, [c.name for c in state.roster]),
            heading=heading_of(deps.world.world_view(state.roster)),
        ) if deps.program_grammar else None,
    )


def heading_of(view: WorldView) -> dict[str, tuple[float, float]]:
    """Where each busy character's event takes them (their plan's target), by name."""
    return {c.name: (float(c.target_position[0]), float(c.target_position[1]))
            for c in view.characters if c.target_position is not None}


async def parse_event(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """One event-parser call; the program in its reply is run by the next node."""
    deps = runtime.context
    turns = tuple(t.as_turn() for t in state.parser_turns)
    request = await off_loop(lambda: parser_request(deps.prompts, parser_input(state, deps), turns))
    return await ask(deps, state, request, "event_parser")


async def check_program(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """Run the reply's parse_event() in the sandbox; a typed error becomes feedback. A program
    that gives a character an object another one uses alone is refused once with that feedback
    (ObjectInUseError) while a retry is left; after it, or on the last attempt, such a character
    waits by the object instead (idle). Words
    about a device every one of which is in use, with a program that avoids it, make the
    event's characters wait for it (:mod:`storyteller.agents.device_in_use`)."""
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
    # words about a device nobody leaves free, or about sitting at a place with no free seat: they wait for it
    free = free_seats(deps.scene, event.characters, state.roster, deps.world.seats_in_use(state.roster))
    plans = waiting_for_busy_device(event_text(event.activity, state.part), result.plans, world, deps.scene,
                                    event.characters, free)
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

"""The planning graph's ``choose_seat`` node: the seat of a sitting event, decided before its program.

Between the narrator's accepted event and the event parser's first call. For an event of one
character whose grammar would offer seats only (``storyteller.agents.program_grammar.EventOptions.must_sit``),
the candidates, their relations and the stated-relation check come from
:mod:`storyteller.agents.place_choice`; when more than one candidate meets the stated relations the model
ranks them in one call (scored continuations through the port, :mod:`storyteller.agents.scored_choice`),
and the best-ranked one that meets them is the step's ``seat``. Every other event passes
through without a call. The event parser then offers only that seat (and names it in its
request); a retry after "no room" (``UnsatisfiableAreaError``) offers every free seat again.

A model that gives no answer (``LLMError``) or an answer that is no candidate leaves the choice
to the scene (the first candidate meeting the relations); a replay miss propagates, as
everywhere in the graph. The call is recorded like the others: its ``parsed`` record holds the
chosen seat, the model's ranking and the candidates the check allowed.
"""

from __future__ import annotations

from typing import Any

import anyio.to_thread
from langgraph.runtime import Runtime

from storyteller.agents.area_words import described_areas
from storyteller.agents.event_parser import event_text
from storyteller.agents.out_of_use import out_of_use, seats_taken_by
from storyteller.agents.part_span import words_before, words_so_far
from storyteller.agents.place_choice import (
    SeatCandidates,
    checked_choice,
    needs_model,
    seat_candidates,
    seat_choice_request,
)
from storyteller.agents.program_grammar import event_options
from storyteller.agents.relation_words import points_back
from storyteller.orchestrator.planning.choice_call import ask_choice, choice_update
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState


def event_seats(state: PlanningState, deps: PlanningDeps) -> SeatCandidates | None:
    """The seat candidates of the state's event, or None when it gets no seat choice: not one
    sitting character, or the event's grammar already offers exactly the one seat the scene's
    check leaves (the request stays as it was without the choice)."""
    event = state.event
    if event is None or event.is_wait or len(event.characters) != 1 or not deps.program_grammar:
        return None
    text = event_text(event.activity, state.part)
    seats_in_use = deps.world.seats_in_use(state.roster)
    areas = described_areas(state.description.text, deps.scene.object_names) if state.description else ()
    options = event_options(
        deps.scene, event.characters, state.roster, seats_in_use, deps.labels_now(state.recent), activity=text,
        context=event.activity if state.part else "", action=state.action, areas=areas,
    )
    if not options.must_sit or not options.free_seats:
        return None
    seats = seat_candidates(
        deps.scene, text, options.free_seats, options.others, options.labels, deps.prompts,
        before=words_before(state.instruction, state.part),
        areas=areas,
        unusable=out_of_use(f"{state.instruction}\n{text}", deps.scene) - seats_taken_by(text, deps.scene),
    )
    if not seats.candidates or options.seats == seats.allowed == seats.allowed[:1]:
        return None
    return seats


async def choose_seat(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """Decide the step's seat (see the module docstring); at most one LLM call."""
    deps = runtime.context
    if state.failure is not None or state.seat is not None:
        return {}
    seats = await anyio.to_thread.run_sync(lambda: event_seats(state, deps))  # CPU work: off the event loop
    if seats is None:
        return {}
    if not needs_model(seats):
        return {"seat": checked_choice(seats, None)}
    assert state.event is not None
    request = seat_choice_request(
        deps.prompts, seats, state.event.characters[0], state.event.activity,
        words_so_far(state.instruction, state.part) if points_back(state.part, deps.scene.labels) else state.part,
        seed=deps.seed, sim_frame=state.sim_frame,
    )
    ranked = await ask_choice(deps, request)
    seat = checked_choice(seats, ranked)
    parsed = {} if ranked is None else {"seat": seat, "ranked": list(ranked.ranked), "allowed": list(seats.allowed)}
    return {**choice_update(state, deps, ranked, parsed), "seat": seat}


async def skip_seat_choice(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """The node for planners whose event parser does not write a program (coordinates)."""
    del state, runtime
    return {}

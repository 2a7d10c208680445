"""The planning graph's ``choose_action`` node: the action of an event whose words name none.

Between the narrator's accepted event and the seat choice. When the event's words (its
instruction part, else the narrator's activity, with the activity as context) give the label
ranker no evidence (:func:`storyteller.agents.action_choice.action_candidates`), the model ranks the offered
labels in one call (scored continuations through the port, :mod:`storyteller.agents.scored_choice`) and its
best is the step's ``action``: the event parser's suggested label and the first its grammar
offers (so a seated activity gives the event its posture, and then its seat choice). Words that
say only a direction ("Then Ava closes it.") take the thing an earlier part of the same
characters worked instead, without a call (:func:`storyteller.agents.action_choice.earlier_thing_action`).
Every other event passes through without a call.

A model that gives no answer (``LLMError``) or an answer that is no candidate leaves the step
without an action (the parser's suggestion is the ranker's, as before); a replay miss
propagates, as everywhere in the graph. The call is recorded like the others: its ``parsed``
record holds the chosen label and the model's five best.
"""

from __future__ import annotations

from typing import Any

from langgraph.runtime import Runtime

from storyteller.agents.action_choice import action_candidates, action_choice_request, earlier_thing_action
from storyteller.agents.event_parser import event_text
from storyteller.agents.instruction_parts import earlier_parts
from storyteller.orchestrator.planning.choice_call import ask_choice, choice_update
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState


async def choose_action(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """Decide the step's action when the event's words name none (see the module docstring);
    at most one LLM call."""
    deps = runtime.context
    event = state.event
    if state.failure is not None or state.action is not None or event is None or event.is_wait:
        return {}
    if not deps.program_grammar:
        return {}
    candidates = action_candidates(
        event_text(event.activity, state.part), deps.labels_now(state.recent), deps.scene.labels,
        context=event.activity if state.part else "",
    )
    if not candidates:
        return {}
    names = [c.name for c in state.roster]
    carried = earlier_thing_action(event_text(event.activity, state.part), candidates, deps.scene.labels,
                                   earlier_parts(state.instruction, state.part, names) if state.part else [])
    if carried is not None:  # "closes it" after "opens the cupboard": no call
        return {"action": carried}
    request = action_choice_request(
        candidates, event.characters, event.activity, state.part, deps.prompts, seed=deps.seed,
        sim_frame=state.sim_frame,
    )
    ranked = await ask_choice(deps, request)
    if ranked is None:
        return choice_update(state, deps, None, {})
    update = choice_update(state, deps, ranked, {"action": ranked.choice, "ranked": list(ranked.ranked[:5])})
    return {**update, "action": ranked.choice}


async def skip_action_choice(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """The node for planners whose event parser does not write a program (coordinates)."""
    del state, runtime
    return {}

"""The planning graph's ``choose_action`` node: the action of an event whose words name none.

Between the narrator's accepted event and the seat choice. When the event's words (its
instruction part, else the narrator's activity, with the activity as context) give the label
ranker no evidence (:func:`agents.action_choice.action_candidates`), the model ranks the offered
labels in one call (scored continuations through the port, :mod:`agents.scored_choice`) and its
best is the step's ``action``: the event parser's suggested label and the first its grammar
offers (so a seated activity gives the event its posture, and then its seat choice). Every other
event passes through without a call.

A model that gives no answer (``LLMError``) or an answer that is no candidate leaves the step
without an action (the parser's suggestion is the ranker's, as before); a replay miss
propagates, as everywhere in the graph. The call is recorded like the others: its ``parsed``
record holds the chosen label and the model's five best.
"""

from __future__ import annotations

import time
from typing import Any

from langgraph.runtime import Runtime

from agents.action_choice import action_candidates, action_choice_request
from agents.event_parser import event_text
from agents.llm_port import LLMError, ReplayMissError
from agents.scored_choice import ChoiceError, ScoredChoice, choose
from orchestrator.planning.state import PlanningDeps, PlanningState


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
        event_text(event.activity, state.part), deps.action_labels, deps.scene.labels,
        context=event.activity if state.part else "",
    )
    if not candidates:
        return {}
    request = action_choice_request(
        candidates, event.characters, event.activity, state.part, deps.prompts, seed=deps.seed,
        sim_frame=state.sim_frame,
    )
    started = time.monotonic()
    ranked: ScoredChoice | None = None
    try:
        ranked = await choose(deps.port, request)
    except ReplayMissError:
        raise
    except (LLMError, ChoiceError):
        ranked = None
    if deps.progress is not None:
        deps.progress.llm_call("event_parser", time.monotonic() - started)
    update: dict[str, Any] = {"llm_calls": state.llm_calls + 1}
    if ranked is None:
        return update
    sink = deps.trace_sink()
    if ranked.trace_seq is not None:
        if sink is not None:
            sink.record_parsed(ranked.trace_seq, {"action": ranked.choice, "ranked": list(ranked.ranked[:5])},
                               node="event_parser")
        update["step_trace_seqs"] = (*state.step_trace_seqs, ranked.trace_seq)
    return {**update, "action": ranked.choice}


async def skip_action_choice(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """The node for planners whose event parser does not write a program (coordinates)."""
    del state, runtime
    return {}

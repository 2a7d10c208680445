"""One choice call of a planning node (the action or the seat decided before the program).

:func:`ask_choice` sends a :func:`storyteller.agents.scored_choice.choice_request` through the port and
reports its latency; a model that gives no answer (``LLMError``) or names no candidate
(``ChoiceError``) gives None, so the node decides without it, while a replay miss propagates as
everywhere in the graph. :func:`choice_update` is the node's state update for the call: one more
LLM call, and the call's ``parsed`` record (what the node decided) with its seq kept for the
step's ``applied`` record.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from storyteller.agents.llm_port import LLMError, LLMRequest, ReplayMissError
from storyteller.agents.scored_choice import ChoiceError, ScoredChoice, choose
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState


async def ask_choice(deps: PlanningDeps, request: LLMRequest) -> ScoredChoice | None:
    """The model's ranking for ``request`` (see the module docstring)."""
    started = time.monotonic()
    ranked: ScoredChoice | None
    try:
        ranked = await choose(deps.port, request)
    except ReplayMissError:
        raise
    except (LLMError, ChoiceError):
        ranked = None
    if deps.progress is not None:
        deps.progress.llm_call("event_parser", time.monotonic() - started)
    return ranked


def choice_update(
    state: PlanningState, deps: PlanningDeps, ranked: ScoredChoice | None, parsed: Mapping[str, Any],
) -> dict[str, Any]:
    """The state update of one choice call; ``parsed``: what the node decided, recorded for the call."""
    update: dict[str, Any] = {"llm_calls": state.llm_calls + 1}
    if ranked is not None and ranked.trace_seq is not None:
        sink = deps.trace_sink()
        if sink is not None:
            sink.record_parsed(ranked.trace_seq, dict(parsed), node="event_parser")
        update["step_trace_seqs"] = (*state.step_trace_seqs, ranked.trace_seq)
    return update

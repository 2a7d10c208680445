"""The describer's nodes: ``describe_scene`` (one describer call) and ``check_description``
(accept its areas, or keep the feedback for another call; after the last rejected call, repair
the best answer from the clusters). The finished description is cached on disk per scene,
model and prompts.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from langgraph.runtime import Runtime

from storyteller.agents.describer import (
    best_effort,
    describer_request,
    description_cache_file,
    finish,
    judge_reply,
    read_cached,
    write_cached,
)
from storyteller.orchestrator.planning.node_calls import complete, off_loop
from storyteller.orchestrator.planning.rejection import record_parsed, rejected_reply
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState


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

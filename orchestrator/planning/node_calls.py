"""What every node of the planning graphs shares about its LLM call: :func:`off_loop` (CPU work
and blocking waits in a worker thread), :func:`complete` (one call with the step's simulation
frame attached, its latency reported), and the state updates for an answered call
(:func:`reply_update`) and for a model that gave no answer (:func:`unavailable`), and
:func:`ask`, the call node's body built from them (every node that asks the model once uses it).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, Literal, TypeVar

import anyio.to_thread

from storyteller.agents.llm_port import LLMError, LLMRequest, LLMResponse, ReplayMissError
from storyteller.agents.messages import PlanningFailure
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState

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


def _with_seq(state: PlanningState, seq: int | None) -> tuple[int, ...]:
    return state.step_trace_seqs if seq is None else (*state.step_trace_seqs, seq)


def reply_update(state: PlanningState, role: Literal["narrator", "parser"], response: LLMResponse) -> dict[str, Any]:
    """State update for one answered call: the reply, its trace seq, the step's seqs, the count."""
    return {
        f"{role}_reply": response.text,
        f"{role}_seq": response.trace_seq,
        "step_trace_seqs": _with_seq(state, response.trace_seq),
        "llm_calls": state.llm_calls + 1,
    }


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


async def ask(
    deps: PlanningDeps, state: PlanningState, request: LLMRequest, node: Literal["narrator", "event_parser", "planner"]
) -> dict[str, Any]:
    """One ``node`` call: the update for its reply (:func:`reply_update`; the narrator's reply, or
    the parser's for the event parser and the planner), or the step's failure when the model gave
    no answer (:func:`unavailable`)."""
    try:
        response = await complete(deps, request, state)
    except LLMError as exc:
        return unavailable(state, node, exc)
    return reply_update(state, "narrator" if node == "narrator" else "parser", response)

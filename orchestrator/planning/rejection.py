"""What a check node does with a rejected reply: the one state update every node and ablation uses.

A check node (``check_description``, ``check_narration``, ``check_program`` and the ablations'
``check_coordinates`` / ``check_plan``) that refuses a reply calls :func:`rejected_reply`. It
records the rejection in the trace (the error's type and the feedback, at the reply's seq),
appends the reply, its feedback and the error's type as a :class:`RetryTurn` to the role's
turns, clears the role's pending reply and, for the narrator and the placing call, turns the
last allowed attempt into the step's :class:`PlanningFailure`. The describer has no failure:
after its last attempt ``check_description`` repairs the best answer instead.

The feedback text itself is built by :func:`storyteller.agents.retry_feedback.feedback_from_error`, so
every retry prompt reads alike. The error type kept on the turn is state only: requests are
built from :meth:`RetryTurn.as_turn` (reply and feedback), never from it.

Imports: ``agents`` and ``storyteller.orchestrator.planning.state`` only (the graph modules import this one).
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import JsonValue

from storyteller.agents.messages import PlanningFailure
from storyteller.agents.retry_feedback import ANSWER_AGAIN, feedback_from_error
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState, RetryTurn

TraceNode = Literal["describer", "narrator", "event_parser", "planner"]
"""The trace node of a call: the describer, the narrator, the event parser (or Direct
Inference's coordinates call) and the unified planner of the "w/o Event" ablation."""

_ROLE: dict[TraceNode, Literal["describer", "narrator", "parser"]] = {
    "describer": "describer",
    "narrator": "narrator",
    "event_parser": "parser",
    "planner": "parser",  # the call that places the characters keeps the parser's fields
}


def record_parsed(
    deps: PlanningDeps, seq: int | None, node: TraceNode,
    parsed: JsonValue = None, error: BaseException | None = None, feedback: str | None = None,
) -> None:
    """Record at trace seq ``seq`` what its reply parsed to, or the error that rejected it
    (its type and ``feedback``, else the error's text). No trace or no seq: nothing."""
    sink = deps.trace_sink()
    if sink is None or seq is None:
        return
    if error is None:
        sink.record_parsed(seq, parsed, node=node)
    else:
        sink.record_parsed(seq, None, node=node, error_type=type(error).__name__, error_message=feedback or str(error))


def rejected_reply(
    state: PlanningState,
    deps: PlanningDeps,
    node: TraceNode,
    reply: str,
    error: BaseException,
    *,
    feedback: str | None = None,
    instruction: str = ANSWER_AGAIN,
) -> dict[str, Any]:
    """The state update for ``reply`` of ``node`` rejected with ``error``.

    ``feedback``: the text already built for it (the describer's judge builds its own); else
    :func:`feedback_from_error` of ``error`` followed by the ``instruction`` prompt file (the
    event parser's is ``PARSER_RETRY_INSTRUCTION``). The update holds the role's turns with
    this one appended (error type included), its reply and seq cleared, and, for a role other
    than the describer whose ``deps.max_retries`` retries are used up, the step's failure
    (with the event and its instruction part for the placing call)."""
    text = feedback if feedback is not None else feedback_from_error(error, instruction=instruction)
    role = _ROLE[node]
    seq = {"describer": state.describer_seq, "narrator": state.narrator_seq, "parser": state.parser_seq}[role]
    turns = {"describer": state.describer_turns, "narrator": state.narrator_turns, "parser": state.parser_turns}[role]
    record_parsed(deps, seq, node, error=error, feedback=text)
    update: dict[str, Any] = {
        f"{role}_turns": (*turns, RetryTurn(reply=reply, feedback=text, error=type(error).__name__)),
        f"{role}_reply": None,
        f"{role}_seq": None,
    }
    attempts = len(turns) + 1
    if node != "describer" and attempts > deps.max_retries:
        placing = role == "parser"
        update["failure"] = PlanningFailure(
            index=state.step, node=node, attempts=attempts, feedback=text,
            event=state.event if placing else None, part=state.part if placing else "",
        )
    return update

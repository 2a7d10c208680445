"""The node that closes a planning step, ``record_outcome``: the step's trace records made durable,
then its outcome logged in the story log (in a worker thread), then the roster, the busy
counts and the story history moved on to the next step, and the step's per-call fields reset.
"""

from __future__ import annotations

from typing import Any

from langgraph.runtime import Runtime

from storyteller.agents.history import keep_window
from storyteller.agents.messages import CharacterStatus, HistoryEntry, ParsedEvent, PlanningFailure
from storyteller.orchestrator.planning.node_calls import off_loop
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState


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

"""The narrator's nodes: ``narrate_event`` (one narrator call) and ``check_narration`` (accept
the event it narrates, or turn what is wrong with it into feedback), and :func:`narrator_input`,
the one builder of the narrator's input (the ablation nodes use it too).
"""

from __future__ import annotations

from typing import Any

from langgraph.runtime import Runtime

from storyteller.agents.bystanders import scene_now
from storyteller.agents.instruction_parts import InstructionProgress
from storyteller.agents.messages import Event
from storyteller.agents.narrator import NarratorInput, narrator_request, parse_narration
from storyteller.agents.retry_feedback import REJECTIONS
from storyteller.orchestrator.planning.node_calls import ask, off_loop
from storyteller.orchestrator.planning.rejection import record_parsed, rejected_reply
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState


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


async def narrate_event(state: PlanningState, runtime: Runtime[PlanningDeps]) -> dict[str, Any]:
    """One narrator call; its reply is checked by the next node."""
    deps = runtime.context
    turns = tuple(t.as_turn() for t in state.narrator_turns)
    inp = await off_loop(lambda: narrator_input(state, deps))
    return await ask(deps, state, narrator_request(deps.prompts, inp, turns), "narrator")


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

"""Ablation "w/o Event": one call (node ``planner``) plans the free characters directly.

The model sees what the narrator sees (a :class:`~storyteller.agents.narrator.NarratorInput`: scene
description, characters, story so far, instruction) plus the action labels and the seats in
use, and answers a ``parse_event()``; there is no explicit event, so the event is read back
from the program's plans. A program that plans nobody (``pass``, or no character touched)
is a wait; naming a busy character is rejected with feedback.
"""

from __future__ import annotations

from collections.abc import Sequence

from storyteller.agents.event_parser import ProgramRunner, check_plans, default_runner, extract_program
from storyteller.agents.llm_port import ChatMessage, LLMRequest
from storyteller.agents.messages import MAX_ACTIVITY_CHARS, CharacterStatus, Event, ParsedEvent
from storyteller.agents.narrator import NarratorInput, characters_text, history_text
from storyteller.agents.prompt_templates import PromptLibrary, package_prompts
from storyteller.agents.retry_feedback import AnswerRejectedError, Turn, retry_temperature, with_turns
from storyteller.sim.scene.model import Scene
from storyteller.tools.character_states import WorldView
from storyteller.tools.scene_graph import SceneGraph


def unified_max_tokens(free: int) -> int:
    """80 + 110 per free character, at most 400 (as the event parser's budget; a small model
    that is given more tends to repeat lines until the cap)."""
    return min(400, 80 + 110 * max(1, free))


def unified_request(
    prompts: PromptLibrary,
    inp: NarratorInput,
    *,
    action_labels: Sequence[str],
    seats_in_use: Sequence[str],
    turns: tuple[Turn, ...] = (),
    max_tokens: int | None = None,
    grammar: str | None = None,
) -> LLMRequest:
    """The planner's request (``max_tokens`` None: :func:`unified_max_tokens`; ``grammar``:
    :func:`storyteller.agents.program_grammar.open_program_grammar`, or None for free text)."""
    free = inp.free
    system = prompts.render(
        "planner/system.md",
        scene_description=inp.scene_description.strip(),
        action_labels=", ".join(action_labels),
    )
    user = prompts.render(
        "planner/request.md",
        characters=characters_text(inp.characters, prompts),
        free=", ".join(free) if free else prompts.render_text("story/nobody_free.md"),
        seats_in_use=", ".join(seats_in_use) if seats_in_use else prompts.render_text("story/no_seats_in_use.md"),
        history=history_text(inp.history, prompts, inp.earlier),
        instruction=inp.instruction.strip() or prompts.render_text("story/no_instruction.md"),
    )
    base = (ChatMessage(role="system", content=system), ChatMessage(role="user", content=user))
    return LLMRequest(
        node="planner",
        messages=with_turns(base, turns),
        max_tokens=max_tokens or unified_max_tokens(len(free)),
        seed=inp.seed,
        temperature=retry_temperature(turns),
        grammar=grammar,
    )


def check_unified_reply(
    reply: str,
    *,
    index: int,
    scene: Scene,
    characters: Sequence[CharacterStatus],
    world: WorldView,
    seed: int,
    action_labels: Sequence[str],
    graph: SceneGraph | None = None,
    runner: ProgramRunner | None = None,
    prompts: PromptLibrary | None = None,
) -> ParsedEvent | None:
    """Run the reply; a program that plans nobody is a wait (None). Raises the typed errors
    that become feedback (a busy character planned, a bad program); the event's activity
    sums the plans up (``prompts/planner/plan_summary.md``)."""
    lib = prompts or package_prompts()
    program = extract_program(reply)
    body = [ln.strip() for ln in program.splitlines()[1:] if ln.strip() and not ln.strip().startswith("#")]
    if body == ["pass"]:
        return None
    busy = {c.name for c in characters if c.busy}
    free = [c.name for c in characters if not c.busy]
    run = runner or default_runner()
    plans = run(scene, program, world, seed=seed, action_labels=list(action_labels), graph=graph)
    if not plans:  # a program that touches nobody plans nothing: a wait
        return None
    names = tuple(dict.fromkeys(str(p.character) for p in plans))
    bad = [n for n in names if n in busy]
    if bad:
        raise AnswerRejectedError(
            [lib.render_text("feedback/planner/busy.md", name=n) for n in bad]
            + [lib.render_text("feedback/free_characters.md", free=", ".join(free))]
        )
    summaries = (lib.render_text("planner/plan_summary.md", character=p.character, action=p.action, area=p.area) for p in plans)
    activity = "; ".join(summaries)
    if len(activity) > MAX_ACTIVITY_CHARS:  # several characters' plans: cut at a word, marked
        activity = activity[: MAX_ACTIVITY_CHARS - 3].rsplit(" ", 1)[0] + "..."
    event = Event(characters=names, activity=activity)
    return ParsedEvent(index=index, event=event, plans=check_plans(event, plans, lib), program=program)

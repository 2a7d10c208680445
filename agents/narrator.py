"""The narrator: picks the next event (which free characters do what) from the story so far.

One call = one :class:`~storyteller.agents.llm_port.LLMRequest` built by :func:`narrator_request`; the
reply is checked by :func:`parse_narration` (JSON, schema, then the rules: only free
characters, no duplicates, an activity when someone takes part). A rejected reply becomes
feedback naming the offending characters (:mod:`storyteller.agents.retry_feedback`).

Prompt layout (stable first, for prefix caching): system = role, rules, examples, scene
description; user = characters and their states, event history, instruction.

Bystanders (free characters no open part of the instruction names, asked for an event of their
own): with the scene at hand (``NarratorInput.now``) the prompt lists everyday activities for
them and the schema admits only those (``storyteller.agents.bystanders``); a reply naming a bystander is
also checked by code (not the instruction's own activity, not what it did last, not an object
another character uses alone), and what is wrong goes back as feedback.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

from storyteller.agents.bystanders import BystanderRules, SceneNow, bystander_rules, never_named
from storyteller.agents.history import LISTED_FINISHED
from storyteller.agents.instruction_parts import InstructionProgress, instruction_progress
from storyteller.agents.llm_port import ChatMessage, LLMPort, LLMRequest
from storyteller.agents.llm_schemas import Refine, reply_schema
from storyteller.agents.messages import (
    CharacterStatus,
    EarlierEvents,
    Event,
    HistoryEntry,
    NarratorOutput,
)
from storyteller.agents.prompt_templates import BENCHMARK_TAGS, PromptLibrary, package_prompts
from storyteller.agents.retry_feedback import (
    Accepted,
    AnswerRejectedError,
    Turn,
    ask_until_valid,
    retry_temperature,
    with_turns,
)

NARRATOR_FILES = ("narrator/system.md", "narrator/request.md")
DEFAULT_MAX_TOKENS = 160


@dataclass(frozen=True)
class NarratorInput:
    """Everything one narrator call depends on."""

    scene_description: str
    characters: Sequence[CharacterStatus]
    instruction: str
    history: Sequence[HistoryEntry] = ()
    earlier: EarlierEvents | None = None  # the events before ``history`` (a long story), summarised
    instruction_since: int = 0  # events before this index were planned under an earlier instruction
    tags: tuple[str, ...] = BENCHMARK_TAGS
    seed: int | None = None
    sim_frame: int | None = None
    max_tokens: int = DEFAULT_MAX_TOKENS
    extra: dict[str, Any] = field(default_factory=dict)
    now: SceneNow | None = None  # the scene and who uses what (None: bystanders get no list)

    @property
    def free(self) -> list[str]:
        return [c.name for c in self.characters if not c.busy]

    @property
    def busy(self) -> list[str]:
        return [c.name for c in self.characters if c.busy]

    @property
    def candidates(self) -> list[str]:
        """Who the reply may name: the next part's actors when it has some, else every free one."""
        actors = set(self.progress.next_actors)
        return [n for n in self.free if n in actors] if actors else self.free

    @property
    def progress(self) -> InstructionProgress:
        """The instruction's parts and how far the story has got with them."""
        return instruction_progress(
            self.instruction, [c.name for c in self.characters], self.history, self.free, since=self.instruction_since,
            idle=[c.name for c in self.characters if not c.busy and c.action in IDLE_ACTIONS],
        )

    @cached_property
    def bystanders(self) -> BystanderRules:
        """The rules for this turn's bystanders: the ones asked for an event of their own (with
        the everyday activities listed for them), or, when every part has happened, the free
        characters the instruction never names (their events are checked, nothing is listed)."""
        progress = self.progress
        if progress.bystanders:
            names: tuple[str, ...] = progress.bystanders
        elif progress.next_part is None and not progress.nothing_for_the_free:
            unnamed = set(never_named(self.instruction, [c.name for c in self.characters]))
            names = tuple(n for n in self.free if n in unnamed)
        else:
            names = ()
        return bystander_rules(
            self.now, self.characters, self.instruction, self.history, names, offer=bool(progress.bystanders)
        )


IDLE_ACTIONS = frozenset({"idle", "sit_idle"})
"""Actions of a character who is only there (standing or sitting), doing nothing in particular."""


def waits_without_a_call(
    characters: Sequence[CharacterStatus], instruction: str, history: Sequence[HistoryEntry], since: int = 0
) -> bool:
    """The narrator's step is a wait the model need not be asked about: nobody is free, or
    what is left of the instruction is for busy characters only (``storyteller.agents.instruction_parts``)."""
    free = [c.name for c in characters if not c.busy]
    names = [c.name for c in characters]
    idle = [c.name for c in characters if not c.busy and c.action in IDLE_ACTIONS]
    return not free or instruction_progress(instruction, names, history, free, since=since, idle=idle).nothing_for_the_free


def narrator_schema(
    free: Sequence[str], at_least_one: bool = False, activities: Sequence[str] = ()
) -> dict[str, Any]:
    """JSON schema of the reply; ``characters`` may only name free characters (enum), and must
    name one when ``at_least_one`` (bystanders asked for an event of their own); with
    ``activities``, the activity must be one of them (the everyday activities listed for
    bystanders) and the event is one character's (a 0.5B model otherwise names every bystander
    for one coffee maker and repeats it through every retry)."""
    names = list(dict.fromkeys(free))
    most = min(1, len(names)) if activities else len(names)  # a listed activity is one character's
    refine = {"event.characters": Refine(enum=names, max_items=most, min_items=1 if at_least_one and names else None)}
    if activities:
        refine["event.activity"] = Refine(enum=list(dict.fromkeys(activities)))
    return reply_schema(NarratorOutput, refine)


def history_text(
    history: Sequence[HistoryEntry], prompts: PromptLibrary | None = None, earlier: EarlierEvents | None = None
) -> str:
    """One line per event, oldest first: ``3. [ongoing] Ann, Bob: chat by sofa_1``
    (``prompts/story/history_*.md``). Completed and failed events before the last
    ``LISTED_FINISHED`` of them (``storyteller.agents.history``) are left out and counted; with ``earlier`` (the events before
    ``history``, which a long story leaves out) every event left out is summarised in one line
    instead: how many, and per character how many and the latest one's activity."""
    lib = prompts or package_prompts()
    if not history and earlier is None:
        return lib.render_text("story/history_empty.md")
    shown = [h for h in history if h.state not in ("completed", "failed")]
    completed = [h for h in history if h.state in ("completed", "failed")][-LISTED_FINISHED:]
    entries = sorted({h.index: h for h in (*shown, *completed)}.values(), key=lambda h: h.index)
    lines = []
    if earlier is not None:
        kept = {h.index for h in entries}
        hidden = sorted((h for h in history if h.index not in kept), key=lambda h: h.index)
        left_out = EarlierEvents.fold(earlier, ((h.characters, h.activity) for h in hidden))
        assert left_out is not None
        who = [
            lib.render_text("story/history_earlier_character.md", name=c.name, events=c.events, activity=c.last_activity)
            for c in left_out.characters
        ]
        lines.append(lib.render_text("story/history_earlier.md", count=left_out.count, characters="; ".join(who)))
    elif len(entries) < len(history):
        lines.append(lib.render_text("story/history_hidden.md", count=len(history) - len(entries)))
    for h in entries:
        lines.append(
            lib.render_text(
                "story/history_line.md",
                number=h.index + 1,
                state=h.state,
                characters=", ".join(h.characters),
                activity=h.activity,
            )
        )
    return "\n".join(lines)


def characters_text(characters: Sequence[CharacterStatus], prompts: PromptLibrary | None = None) -> str:
    """One line per character, busy ones with their event (``prompts/story/character_*.md``)."""
    lib = prompts or package_prompts()
    lines = []
    for c in characters:
        if c.busy and c.event_index is not None:
            lines.append(
                lib.render_text("story/character_busy_in_event.md", name=c.name, action=c.action, event=c.event_index + 1)
            )
        else:
            lines.append(lib.render_text("story/character_busy.md" if c.busy else "story/character_free.md", name=c.name, action=c.action))
    return "\n".join(lines)


def _next_part_line(
    prompts: PromptLibrary, instruction: str, progress: InstructionProgress, choices: Sequence[str] = ()
) -> str:
    if progress.next_part is not None:
        return progress.next_part
    if progress.bystanders:
        line = prompts.render_text("narrator/bystanders.md", names=", ".join(progress.bystanders))
        if not choices:
            return line
        listed = "\n".join(prompts.render_text("narrator/choice_line.md", activity=c) for c in choices)
        return line + "; " + prompts.render_text("narrator/bystander_choices.md", choices=listed)
    if progress.nothing_for_the_free:
        return prompts.render_text("narrator/next_part_wait.md")
    return prompts.render_text("narrator/next_part_all_done.md" if instruction.strip() else "story/no_instruction.md")


def narrator_messages(prompts: PromptLibrary, inp: NarratorInput) -> tuple[ChatMessage, ...]:
    system = prompts.render(
        "narrator/system.md",
        examples=prompts.examples("narrator", inp.tags),
        scene_description=inp.scene_description.strip(),
    )
    free = inp.free
    progress = inp.progress
    user = prompts.render(
        "narrator/request.md",
        characters=characters_text(inp.characters, prompts),
        free=", ".join(free) if free else prompts.render_text("story/nobody_free.md"),
        history=history_text(inp.history, prompts, inp.earlier),
        instruction=progress.text,
        next_part=_next_part_line(prompts, inp.instruction, progress, inp.bystanders.texts),
    )
    return (ChatMessage(role="system", content=system), ChatMessage(role="user", content=user))


def narrator_request(prompts: PromptLibrary, inp: NarratorInput, turns: tuple[Turn, ...] = ()) -> LLMRequest:
    return LLMRequest(
        node="narrator",
        messages=with_turns(narrator_messages(prompts, inp), turns),
        json_schema=narrator_schema(
            inp.candidates, at_least_one=bool(inp.progress.bystanders), activities=inp.bystanders.texts
        ),
        max_tokens=inp.max_tokens,
        seed=inp.seed,
        temperature=retry_temperature(turns),
        sim_frame=inp.sim_frame,
    )


def parse_narration(
    text: str, characters: Sequence[CharacterStatus], prompts: PromptLibrary | None = None,
    bystanders: BystanderRules | None = None,
) -> NarratorOutput:
    """Check a reply. Raises JSONDecodeError, ValidationError or AnswerRejectedError, whose
    problems are ``prompts/feedback/narrator/*.md``; with ``bystanders`` (the turn's
    :attr:`NarratorInput.bystanders`) what it gives them is checked too."""
    lib = prompts or package_prompts()
    data = json.loads(_json_slice(text))
    out = NarratorOutput.model_validate(data)
    known = {c.name: c for c in characters}
    problems: list[str] = []
    seen: set[str] = set()
    for name in out.event.characters:
        if name in seen:
            problems.append(lib.render_text("feedback/narrator/listed_twice.md", name=name))
            continue
        seen.add(name)
        status = known.get(name)
        if status is None:
            problems.append(lib.render_text("feedback/narrator/not_a_character.md", name=name))
        elif status.busy and status.event_index is not None:
            problems.append(lib.render_text("feedback/narrator/busy_in_event.md", name=name, event=status.event_index + 1))
        elif status.busy:
            problems.append(lib.render_text("feedback/narrator/busy.md", name=name))
    if out.event.characters and not out.event.activity.strip():
        problems.append(lib.render_text("feedback/narrator/empty_activity.md"))
    if problems:
        free = [c.name for c in characters if not c.busy]
        problems.append(
            lib.render_text("feedback/free_characters.md", free=", ".join(free) if free else lib.render_text("feedback/none.md"))
        )
        raise AnswerRejectedError(problems)
    if bystanders is not None and (wrong := bystanders.problems(out.event, lib)):
        raise AnswerRejectedError(wrong)
    return out


def _json_slice(text: str) -> str:
    """The outermost ``{...}`` of a reply (tolerates fences or prose around the JSON)."""
    start, end = text.find("{"), text.rfind("}")
    if start == -1 or end < start:
        return text
    return text[start : end + 1]


WAIT = NarratorOutput(reasoning="no character is free", event=Event())
WAIT_FOR_BUSY = NarratorOutput(reasoning="the instruction has nothing for the free characters now", event=Event())


async def narrate(
    port: LLMPort, prompts: PromptLibrary, inp: NarratorInput, *, max_retries: int = 3
) -> Accepted[NarratorOutput]:
    """Ask for the next event: a first try plus at most ``max_retries`` retries.

    With no free character, or an instruction with nothing for the free characters now (see
    ``storyteller.agents.instruction_parts``), the answer is a wait, without an LLM call (attempts = 0).
    Raises :class:`~storyteller.agents.retry_feedback.RetriesExhaustedError` when every reply is rejected.
    """
    if waits_without_a_call(inp.characters, inp.instruction, inp.history, inp.instruction_since):
        return Accepted(value=WAIT if not inp.free else WAIT_FOR_BUSY, attempts=0, reply="")
    return await ask_until_valid(
        port,
        lambda turns: narrator_request(prompts, inp, turns),
        lambda text: parse_narration(text, inp.characters, prompts, inp.bystanders),
        max_attempts=max_retries + 1,
        node="narrator",
        prompts=prompts,
    )

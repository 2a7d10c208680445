"""The action of an event whose words give the label ranker no evidence, as the model's choice.

The event parser's prompt names a suggested label (:func:`storyteller.agents.action_shortlist.suggested_action`),
ranked from the event's words; a small model mostly follows it. When the words name no action
the ranker knows ("sits down to have an apple and some crackers", "takes a free seat at that
table"), the suggestion was ``idle`` and the program sat the character down doing nothing. Here
such an event's action is a choice among the labels offered, ranked by the model's own
likelihood of each label as its reply (one prompt, scored continuations for the embedded model:
:mod:`storyteller.agents.scored_choice`; an enum-constrained reply elsewhere). An event whose words do rank a
label keeps the ranker's answer and gets no call.

The chosen label is the parser's suggestion and the first label its grammar offers (so a seated
activity such as ``eat`` also gives the event its posture and seat choice); the program still
writes the action, among the same labels.
"""

from __future__ import annotations

from collections.abc import Sequence

from storyteller.agents.action_shortlist import posture, rank_action_labels, suggested_action, switch_directions
from storyteller.agents.llm_port import ChatMessage, LLMRequest
from storyteller.agents.prompt_templates import PromptLibrary, package_prompts
from storyteller.agents.relation_words import names_a_relation
from storyteller.agents.scored_choice import choice_request

MOTION_LABELS = frozenset({"walk", "sit_down", "sit_idle", "stand_up"})
"""Labels the simulation plays by itself, never the action of an event."""


def action_candidates(
    text: str, labels: Sequence[str], object_labels: Sequence[str] = (), context: str = "",
) -> tuple[str, ...]:
    """The labels the model chooses among for an event with words ``text`` (and ``context``: the
    narrator's own words), or ``()`` when the words rank a label (the ranker decides), when they
    only say where someone stands (a relation word and no sitting: the suggestion is ``idle``),
    or fewer than two labels are offered."""
    if rank_action_labels(text, labels, object_labels, context):
        return ()
    if posture(text) != "sit" and names_a_relation(text):
        return ()  # only where someone is ("hangs about beside the till"): they stand there, idle
    offered = tuple(dict.fromkeys(a for a in labels if a not in MOTION_LABELS))
    return offered if len(offered) > 1 else ()


def earlier_thing_action(
    text: str, labels: Sequence[str], object_labels: Sequence[str], earlier: Sequence[str],
) -> str | None:
    """The label for words that say a direction and no thing of their own ("Then Ava closes
    it.", "turns the set off again"): the direction applied to the thing the nearest of the
    ``earlier`` parts of the same characters (latest first) worked ("Ava opens the cupboard":
    ``close_cabinet``; "Ben watches TV": ``turn_off_tv``), when the scene offers that label;
    None otherwise (the model chooses)."""
    directions = switch_directions(text)
    if not directions or rank_action_labels(text, labels, object_labels):
        return None
    for words in earlier:
        words_of = suggested_action(words, labels, object_labels).split("_")
        for k in range(1, len(words_of)):  # the thing: the label's last words (watch_tv: tv)
            found = [d + "_".join(words_of[k:]) for d in directions if d + "_".join(words_of[k:]) in labels]
            if len(found) == 1:
                return found[0]
    return None


def action_choice_request(
    candidates: Sequence[str], characters: Sequence[str], activity: str, instruction_part: str,
    prompts: PromptLibrary | None = None, *, seed: int | None = None, sim_frame: int | None = None,
) -> LLMRequest:
    """The one prompt whose reply scores each candidate label (``prompts/event_parser/choose_action*.md``)."""
    lib = prompts or package_prompts()
    system = lib.render("event_parser/choose_action_system.md")
    user = lib.render(
        "event_parser/choose_action.md", characters=" and ".join(characters), activity=activity.strip(),
        instruction=(instruction_part or activity).strip(), labels=", ".join(candidates),
        verb="does" if len(characters) == 1 else "do",
    )
    return choice_request(
        "event_parser", (ChatMessage(role="system", content=system), ChatMessage(role="user", content=user)),
        candidates, seed=seed, sim_frame=sim_frame,
    )

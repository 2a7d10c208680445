"""The narrator's own words, shown to a person only where code has checked that they say the plan.

The text a person reads is built from the applied plan (``storyteller.agents.story_text``); the narrator's
activity stays data (``story.json``'s ``activity``) and is shown beside it (``narration``) only
when :func:`says_the_plan` holds:

- :func:`agrees`: for every character it names the planned object (the seat, else the first
  object of the area; its id, its label or its human name) and an action word of the planned
  label (``storyteller.agents.story_text.VerbPhrase.words``);
- its words rank every planned label close to their best (``storyteller.agents.action_shortlist``, the
  planner's own reading of words), and say no other such label by an action word of its own
  ("switch TV on, ... and turn off TV, then watch a movie" for a plan that only watches TV;
  "bring coffee to Ben, who waits on the bench ... looking at his phone" for Ava on her phone);
- every object id in it is one the plans are about (a seat, an object of a planned place): a
  narrator that lists half the room ("work at desks_1, desk_2, ... office_chair_6, potted_")
  is not shown.

Shown words have their object ids replaced by human names (:func:`with_names`). Pure: no
clock, no model; the same words and plans give the same verdict (a replayed run shows the same).
Nothing here reaches a prompt: the narrator's history reads the activity, not these texts.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from storyteller.agents.action_shortlist import action_shortlist
from storyteller.agents.event_parser import scene_action_labels
from storyteller.agents.messages import ParsedEvent, PlannedCharacter
from storyteller.agents.story_text import ObjectNames, label_of, noun, parse_place, phrase_of, planned_object
from storyteller.sim.motion.action_labels import ACTION_LABELS
from storyteller.sim.scene.model import Scene

_ID_IN_TEXT = re.compile(r"\b[a-z][a-z0-9]*(?:_[a-z0-9]+)*_\d+\b")


def _mentions_object(text: str, name: str, scene: Scene | None) -> bool:
    label = label_of(name, scene)
    patterns = [re.escape(name), re.escape(label).replace("_", "[ _]") + "s?", re.escape(noun(label)) + "s?"]
    return any(re.search(rf"(?<![a-z0-9_]){p}(?![a-z0-9_])", text, re.IGNORECASE) for p in patterns)


def _words(text: str) -> str:
    """``text`` lower-cased, its object ids blanked, underscores read as spaces."""
    return _ID_IN_TEXT.sub(" ", text.lower()).replace("_", " ")


def _says_word(words: str, word: str) -> bool:
    return re.search(rf"(?<![a-z]){re.escape(word)}", words) is not None


def _mentions_action(text: str, label: str) -> bool:
    words = _words(text)
    return any(_says_word(words, w) for w in phrase_of(label).words)


def agrees(text: str, plans: Sequence[PlannedCharacter], scene: Scene | None) -> bool:
    """Whether ``text`` says what the plans do: for every plan it names the planned object (id,
    label or human name; not checked for a plan without one) and an action word of its label."""
    if not plans:
        return False
    for p in plans:
        obj = planned_object(p, scene)
        if obj is not None and not _mentions_object(text, obj, scene):
            return False
        if not _mentions_action(text, p.action):
            return False
    return True


def actions_off_plan(text: str, plans: Sequence[PlannedCharacter], scene: Scene | None) -> list[str]:
    """The labels on which ``text`` and the plans part: a planned label the words do not rank
    close to their best (``storyteller.agents.action_shortlist``, over the scene's labels), and a label no
    plan carries that the words rank so and say by an action word of its own (a word no planned
    label has). Empty when the words say the planned actions and no other."""
    planned = dict.fromkeys(p.action for p in plans)
    own = {w for label in planned for w in phrase_of(label).words}
    labels = scene_action_labels(scene) if scene is not None else ACTION_LABELS
    object_labels = sorted(set(scene.labels)) if scene is not None else []
    ranked = action_shortlist(text, labels, object_labels)
    words = _words(text)
    others = [label for label in ranked if label not in planned
              and any(_says_word(words, w) for w in phrase_of(label).words if w not in own)]  # fmt: skip
    return [label for label in planned if label not in ranked] + others


def unplanned_ids(text: str, plans: Sequence[PlannedCharacter], scene: Scene | None) -> list[str]:
    """Object ids in ``text`` that no plan is about (its seat, the objects of its place)."""
    about = {o for p in plans for o in ((p.seat,) if p.seat else ()) + parse_place(p.area, p.position, scene).objects}
    return [i for i in dict.fromkeys(m.lower() for m in re.findall(_ID_IN_TEXT.pattern, text, re.IGNORECASE))
            if i not in about]  # fmt: skip


def says_the_plan(text: str, plans: Sequence[PlannedCharacter], scene: Scene | None) -> bool:
    """Whether the narrator's ``text`` may be shown beside the plan sentence (module docstring)."""
    return agrees(text, plans, scene) and not actions_off_plan(text, plans, scene) and not unplanned_ids(text, plans, scene)


def with_names(text: str, scene: Scene | None) -> str:
    """``text`` with every object id of the scene (any ``<label>_<idx>`` without a scene)
    replaced by its human name, a "the" before it absorbed."""
    names = ObjectNames(scene)

    def swap(m: re.Match[str]) -> str:
        name = m.group("id")
        if scene is not None and name not in scene.by_name:
            return m.group(0)
        return names(name)

    return re.sub(r"(?:\bthe\s+)?(?P<id>" + _ID_IN_TEXT.pattern + ")", swap, text, flags=re.IGNORECASE)


def narration(event: ParsedEvent, scene: Scene | None) -> str | None:
    """The narrator's activity in human names when :func:`says_the_plan`; None otherwise (a
    reader then sees the plan sentence alone)."""
    activity = " ".join(event.event.activity.split())
    if not activity or not says_the_plan(activity, event.plans, scene):
        return None
    return with_names(activity, scene)

"""Bystanders: everyday activities for the characters the instruction does not need now, offered
as a short list the narrator chooses from, and the checks a reply naming them must pass.

A 0.5B narrator told "give Ben something of his own to do" copies the instruction ("Ben makes
coffee") or what Ben did last, at an object somebody else is using. So code works out what the
scene allows and the model only chooses (the pattern issue 24 asks for: candidates the scene
allows, a choice, a check):

- :func:`scene_choices`: every (action label, object) pair of the scene that :data:`EVERYDAY`
  allows (standing at an object of some labels, on a seat, or on a seat near an object of some
  labels), for the action labels the scene offers, each said as one activity ("make toast at
  toaster_1", "read a book sitting on armchair_1", ``prompts/story/choice_*.md`` with the verb
  phrases of ``storyteller.agents.story_text``). A text is kept only when it ranks its own label first
  (``storyteller.agents.action_shortlist``), so the event parser reads the same action back.
- :func:`bystander_rules` picks the choices for one narrator turn: not an object another
  character uses alone now (``storyteller.tools.object_use``), not a seat without a free place, not the
  instruction's own activities (the labels its parts rank first), not an object the instruction
  names, not what a bystander did last. When that leaves nothing, the named objects come back,
  then a repeat (the scene offers nothing else); with still nothing, no list is offered and the
  model writes an activity of its own. The choices are spread over the scene's areas (the
  describer's clusters): one per area in turn, areas with nobody in them first and the
  bystanders' own area last, a new label in each area first; at most :data:`MAX_CHOICES`.
- :meth:`BystanderRules.problems`: what is wrong with a reply for a bystander: an activity that
  is not one listed (when a list was offered), one the instruction asks of its own characters,
  the one the character did last (unless repeats are all the scene has), an object another
  character uses alone (the world's users, and those of ongoing events whose words name it:
  an event planned beside this one is not in the world yet), or such an object given to several
  characters at once; each one sentence of ``prompts/feedback/narrator/bystander_*.md`` that
  the narrator reads on its retry.

Pure: no LLM, no clock, no I/O; the same inputs give the same list in the same order.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from storyteller.agents.action_shortlist import action_shortlist, posture, rank_action_labels
from storyteller.agents.instruction_parts import named_in, split_instruction
from storyteller.agents.messages import CharacterStatus, Event, HistoryEntry
from storyteller.agents.prompt_templates import PromptLibrary, package_prompts
from storyteller.agents.shortlist import CLOSE_M, VIEWED_M, mentioned_labels
from storyteller.agents.story_text import phrase_of, plural
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.areas import seat_slots
from storyteller.tools.character_states import CharacterState, WorldView
from storyteller.tools.object_use import SINGLE_USER_ACTIONS, used_labels, users_of_objects
from storyteller.tools.scene_graph import footprint_distance, point_footprint_distance

MAX_CHOICES = 6
"""Activities listed for one turn (a short list keeps a small model's prompt short)."""


@dataclass(frozen=True)
class Where:
    """Where one action label is done as an everyday activity: standing at an object of a label
    in ``at``, or sitting on a seat (``seat``), within ``near_m`` metres of an object of a label
    in ``near`` when that is given. A label matches an object label equal to it or ending in
    ``_<label>`` (``table`` matches ``dining_table``)."""

    at: tuple[str, ...] = ()
    seat: bool = False
    near: tuple[str, ...] = ()
    near_m: float = CLOSE_M


UNDOING = ("close_", "turn_off_")
"""Label prefixes that undo an act (closing, switching off): they follow one, never start one."""
EVERYDAY: dict[str, Where] = {
    **{label: Where(at=objects) for label, objects in SINGLE_USER_ACTIONS.items()
       if not label.startswith(UNDOING) and label != "pay_bill"},  # paying follows a meal
    "read_book": Where(seat=True),
    "use_smartphone": Where(seat=True),
    "drink": Where(seat=True),
    "eat": Where(seat=True, near=("table", "bar_counter")),
    "watch_tv": Where(seat=True, near=("tv",), near_m=VIEWED_M),
    "listen_to_music": Where(seat=True, near=("record_player", "loudspeaker", "speaker", "radio"), near_m=VIEWED_M),
    "clean_table": Where(at=("table",)),
}
"""Everyday activities one person does alone, by action label (general English, no case's
wording). Labels done with others (chat, dance...), for others (serve, take an order) or that
need an earlier act are left out."""

RESTING = frozenset({"idle", "sit_idle", "walk", "sit_down", "stand_up"})
"""Actions that are no activity of their own (standing, sitting, walking there)."""


def _fits(label: str, wanted: Iterable[str]) -> bool:
    return any(label == w or label.endswith("_" + w) for w in wanted)


@dataclass(frozen=True)
class Choice:
    """One everyday activity: ``label`` at or on ``obj`` (in area ``area``), said as ``text``."""

    label: str
    obj: str
    area: int
    text: str
    seated: bool


def _text(label: str, obj: SceneObject, seated: bool, lib: PromptLibrary) -> str:
    phrase = phrase_of(label)
    if seated:
        return lib.render_text("story/choice_seated.md", action=plural(phrase.does), seat=obj.name)
    if phrase.on and _fits(obj.label, phrase.objects):
        return plural(phrase.on.format(obj=obj.name))
    return lib.render_text("story/choice_at.md", action=plural(phrase.does), obj=obj.name)


def object_areas(scene: Scene, clusters: Sequence[Sequence[str]]) -> dict[str, int]:
    """Object name -> its area: the index of its cluster; an object in none is an area of its own."""
    areas: dict[str, int] = {}
    for i, group in enumerate(clusters):
        for name in group:
            areas.setdefault(name, i)
    k = len(clusters)
    for o in scene.objects:
        if o.name not in areas:
            areas[o.name] = k
            k += 1
    return areas


def scene_choices(
    scene: Scene, action_labels: Sequence[str], areas: Mapping[str, int], prompts: PromptLibrary | None = None
) -> tuple[Choice, ...]:
    """Every everyday activity the scene allows (see the module docstring), in the order of
    ``action_labels`` then of the scene's objects."""
    lib = prompts or package_prompts()
    object_labels = sorted(set(scene.labels))
    out: list[Choice] = []
    for label in action_labels:
        where = EVERYDAY.get(label)
        if where is None:
            continue
        for obj in scene.objects:
            if where.at and _fits(obj.label, where.at):
                seated = False
            elif where.seat and obj.is_seat and (not where.near or _near(scene, obj, where)):
                seated = True
            else:
                continue
            text = _text(label, obj, seated, lib)
            if action_shortlist(text, action_labels, object_labels)[:1] == (label,):
                out.append(Choice(label, obj.name, areas.get(obj.name, -1), text, seated))
    return tuple(out)


def _near(scene: Scene, seat: SceneObject, where: Where) -> bool:
    return any(
        o.name != seat.name and _fits(o.label, where.near) and footprint_distance(seat, o) <= where.near_m
        for o in scene.objects
    )


@dataclass(frozen=True)
class SceneNow:
    """What the narrator's input lacks to offer everyday activities: the scene's choices and
    areas, and who uses which object alone or sits where now."""

    scene: Scene
    action_labels: tuple[str, ...]
    choices: tuple[Choice, ...]
    areas: Mapping[str, int]
    users: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    """Object -> the characters using it alone (``storyteller.tools.object_use.users_of_objects``)."""
    seated: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    """Seat -> the characters sitting on it or heading there."""


def scene_now(
    scene: Scene, action_labels: Sequence[str], choices: Sequence[Choice], areas: Mapping[str, int],
    view: object, roster: Sequence[CharacterStatus] = (),
) -> SceneNow:
    """The scene now, from the spatial API's view of the characters (a ``WorldView``; any other
    view, e.g. a test's stand-in, is replaced by ``roster`` without targets). ``choices`` and
    ``areas``: :func:`scene_choices` and :func:`object_areas`, built once per scene."""
    if not isinstance(view, WorldView):
        view = WorldView(characters=tuple(
            CharacterState(name=c.name, position=c.position, facing=c.facing, action=c.action, busy=c.busy, seat=c.seat)
            for c in roster
        ))
    users = {o: tuple(u) for o, u in users_of_objects(view.characters, scene).items()}
    seated: dict[str, list[str]] = {}
    for c in view.characters:
        if c.seat:
            seated.setdefault(c.seat, []).append(c.name)
    for seat, name in view.objects_in_use.items():
        if name not in seated.get(seat, []) and seat in scene.by_name and scene.by_name[seat].is_seat:
            seated.setdefault(seat, []).append(name)
    return SceneNow(scene, tuple(action_labels), tuple(choices), dict(areas), users,
                    {s: tuple(n) for s, n in seated.items()})  # fmt: skip


# ----- the instruction and the story so far -----------------------------------------------------
def never_named(instruction: str, names: Sequence[str]) -> tuple[str, ...]:
    """The characters no part of ``instruction`` names (none without an instruction)."""
    parts = split_instruction(instruction, names)
    if not parts:
        return ()
    named = named_in(parts, names)
    return tuple(n for n in names if n not in named)


def instruction_activities(
    instruction: str, names: Sequence[str], labels: Sequence[str], object_labels: Sequence[str] = ()
) -> dict[str, tuple[str, ...]]:
    """Action label -> the actors of the instruction's parts that ask for it (the labels each
    part's words rank close to the best, ``storyteller.agents.action_shortlist``)."""
    out: dict[str, list[str]] = {}
    for part in split_instruction(instruction, names):
        for label in action_shortlist(part.text, labels, object_labels):
            actors = out.setdefault(label, [])
            actors += [a for a in part.actors if a not in actors]
    return {label: tuple(actors) for label, actors in out.items()}


def activity_label(text: str, labels: Sequence[str], object_labels: Sequence[str] = ()) -> str | None:
    """The action label an activity's words rank first, or None when they name none."""
    ranked = rank_action_labels(text, labels, object_labels)
    return ranked[0].label if ranked else None


def last_activity(
    name: str, characters: Sequence[CharacterStatus], history: Sequence[HistoryEntry],
    labels: Sequence[str], object_labels: Sequence[str] = (),
) -> tuple[str, str] | None:
    """(label, words) of what ``name`` did last: its current action when that is an activity
    (a looping one it is still at), else its latest event that did not fail, read from its words."""
    status = next((c for c in characters if c.name == name), None)
    latest = max((h for h in history if name in h.characters and h.state != "failed"), key=lambda h: h.index, default=None)
    if status is not None and status.action not in RESTING:
        words = latest.activity if latest is not None and activity_label(latest.activity, labels, object_labels) == status.action else status.action
        return status.action, words
    if latest is None:
        return None
    label = activity_label(latest.activity, labels, object_labels)
    return (label, latest.activity) if label is not None else None


# ----- one turn ---------------------------------------------------------------------------------
_ID = re.compile(r"\b[a-z][a-z0-9]*(?:_[a-z0-9]+)*_\d+\b")


@dataclass(frozen=True)
class BystanderRules:
    """What a narrator reply may give the bystanders ``names`` this turn (see the module docstring)."""

    names: tuple[str, ...]
    choices: tuple[Choice, ...] = ()
    """What the scene offers them now (named in feedback)."""
    listed: bool = False
    """The choices are listed in the prompt, and a bystander's activity must be one of them."""
    asked: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    """The instruction's own activities: action label -> the characters it asks them of."""
    previous: Mapping[str, tuple[str, str]] = field(default_factory=dict)
    """Bystander -> (label, words) of what it did last."""
    repeats_allowed: bool = False
    """The scene offers nothing but a repeat."""
    users: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    labels: tuple[str, ...] = ()
    object_labels: tuple[str, ...] = ()

    @property
    def texts(self) -> tuple[str, ...]:
        """The activities listed in the prompt (the schema's enum), empty when none are."""
        return tuple(c.text for c in self.choices) if self.listed else ()

    def problems(self, event: Event, prompts: PromptLibrary | None = None) -> list[str]:
        """Sentences saying what is wrong with ``event`` for the bystanders it names (empty: nothing)."""
        lib = prompts or package_prompts()
        named = [n for n in event.characters if n in self.names]
        if not named:
            return []
        said = event.activity.strip()
        choice = next((c for c in self.choices if c.text == said), None)
        out: list[str] = []
        label = choice.label if choice is not None else activity_label(said, self.labels, self.object_labels)
        for name in named:
            prev = self.previous.get(name)
            if label is not None and label in self.asked:
                owners = [a for a in self.asked[label] if a != name]
                out.append(lib.render_text(
                    "feedback/narrator/bystander_instruction.md", name=name, activity=said,
                    owners=" and ".join(owners) if owners else lib.render_text("feedback/narrator/its_characters.md"),
                ))
            elif label is not None and prev is not None and prev[0] == label and not self.repeats_allowed:
                out.append(lib.render_text("feedback/narrator/bystander_repeat.md", name=name, previous=prev[1]))
        for obj in [choice.obj] if choice is not None else _ID.findall(said):
            if label is None or obj.rsplit("_", 1)[0] not in used_labels(label):
                continue
            others = [u for u in self.users.get(obj, ()) if u not in named]
            if others:
                out.append(lib.render_text("feedback/narrator/bystander_in_use.md", obj=obj, users=" and ".join(others)))
            elif len(event.characters) > 1:
                out.append(lib.render_text("feedback/narrator/bystander_one_user.md", obj=obj,
                                           names=" or ".join(event.characters)))  # fmt: skip
        if not out and self.listed and self.choices and choice is None:
            out.append(lib.render_text("feedback/narrator/bystander_unlisted.md", names=" and ".join(named)))
        if out and self.choices:
            out.append(lib.render_text("feedback/narrator/bystander_choices.md", choices="; ".join(c.text for c in self.choices)))
        return out


def bystander_rules(
    now: SceneNow | None, characters: Sequence[CharacterStatus], instruction: str, history: Sequence[HistoryEntry],
    names: Sequence[str], *, offer: bool,
) -> BystanderRules:
    """The rules for ``names`` this turn; with ``offer`` (the reply may name only them) the
    choices are listed in the prompt. Without ``now`` (no scene at hand) there are no rules;
    when the scene offers nothing at all (every choice is the instruction's own activity or in
    use), only objects in use are checked: anything else would fail every retry."""
    if now is None or not names:
        return BystanderRules(tuple(names))
    everyone = [c.name for c in characters]
    labels = now.action_labels
    object_labels = tuple(sorted(set(now.scene.labels)))
    asked = instruction_activities(instruction, everyone, labels, object_labels)
    previous = {n: p for n in names if (p := last_activity(n, characters, history, labels, object_labels)) is not None}
    users, seated = pending_uses(now, history, labels, object_labels)
    now = replace(now, users=users, seated=seated)
    rules = BystanderRules(tuple(names), (), False, asked, previous, False, users, labels, object_labels)
    choices, repeats = _choose(now, characters, instruction, history, rules)
    if not choices:
        return BystanderRules(tuple(names), users=rules.users, labels=labels, object_labels=object_labels)
    return BystanderRules(tuple(names), choices, offer, asked, previous, repeats, rules.users, labels, object_labels)


def pending_uses(
    now: SceneNow, history: Sequence[HistoryEntry], labels: Sequence[str], object_labels: Sequence[str] = ()
) -> tuple[dict[str, tuple[str, ...]], dict[str, tuple[str, ...]]]:
    """``now.users`` and ``now.seated`` plus the characters of ongoing events whose words name
    an object their action uses alone ("take a book from bookshelf_1") or a seat they sit on
    ("eat sitting on chair_3"): an event planned beside this one (or not yet reached) takes its
    object before the world shows it."""
    users = {o: list(u) for o, u in now.users.items()}
    seated = {o: list(u) for o, u in now.seated.items()}
    for h in history:
        if h.state != "ongoing":
            continue
        label = activity_label(h.activity, labels, object_labels)
        wanted = used_labels(label) if label is not None else ()
        sits = posture(h.activity) == "sit"
        for obj in _ID.findall(h.activity):
            known = now.scene.by_name.get(obj)
            into = users if known is not None and known.label in wanted else seated if known is not None and known.is_seat and sits else None
            if into is not None:
                into.setdefault(obj, [])
                into[obj] += [c for c in h.characters if c not in into[obj]]
    return {o: tuple(u) for o, u in users.items()}, {o: tuple(u) for o, u in seated.items()}


def _choose(
    now: SceneNow, characters: Sequence[CharacterStatus], instruction: str, history: Sequence[HistoryEntry],
    rules: BystanderRules,
) -> tuple[tuple[Choice, ...], bool]:
    scene = now.scene
    mine = set(rules.names)
    named_labels = set(mentioned_labels(instruction.replace("_", " ").lower(), sorted(set(scene.labels))))
    named_ids = set(_ID.findall(instruction))

    def open_(c: Choice) -> bool:
        if c.label in rules.asked:
            return False
        if any(u not in mine for u in now.users.get(c.obj, ())):
            return False
        if c.seated:
            taken = [n for n in now.seated.get(c.obj, ()) if n not in mine]
            return len(taken) < len(seat_slots(scene.by_name[c.obj]))
        return True

    def unnamed(c: Choice) -> bool:
        return c.obj not in named_ids and scene.by_name[c.obj].label not in named_labels

    previous = {p[0] for p in rules.previous.values()}
    possible = [c for c in now.choices if open_(c)]
    def new(c: Choice) -> bool:
        return c.label not in previous

    def anything(c: Choice) -> bool:
        return True

    tiers: list[tuple[Callable[[Choice], bool], bool]] = [
        (lambda c: unnamed(c) and new(c), False), (new, False), (anything, True),
    ]
    for keep, repeats in tiers:
        kept = [c for c in possible if keep(c)]
        if kept:
            return _spread(kept, now, characters, history, rules.names), repeats
    return (), False


def _area_of(now: SceneNow, xy: tuple[float, float] | None, seat: str | None) -> int | None:
    if seat is not None and seat in now.areas:
        return now.areas[seat]
    if xy is None or not now.scene.objects:
        return None
    point = np.array([xy], dtype=float)
    _, name = min((float(point_footprint_distance(o, point)[0]), o.name) for o in now.scene.objects)
    return now.areas.get(name)


def _spread(
    choices: list[Choice], now: SceneNow, characters: Sequence[CharacterStatus], history: Sequence[HistoryEntry],
    names: Sequence[str],
) -> tuple[Choice, ...]:
    """At most MAX_CHOICES of ``choices``, one per area in turn (see the module docstring)."""
    mine = [c for c in characters if c.name in names]
    own = {a for c in mine if (a := _area_of(now, c.position, c.seat)) is not None}
    others = Counter(a for c in characters if c.name not in names and (a := _area_of(now, c.position, c.seat)) is not None)
    done = Counter(lab for h in history if set(h.characters) & set(names)
                   if (lab := activity_label(h.activity, now.action_labels, sorted(set(now.scene.labels)))) is not None)  # fmt: skip
    here = next((c.position for c in mine if c.position is not None), None)

    def distance(c: Choice) -> float:
        if here is None:
            return 0.0
        return float(point_footprint_distance(now.scene.by_name[c.obj], np.array([here], dtype=float))[0])

    by_area: dict[int, list[Choice]] = {}
    for c in sorted(choices, key=lambda c: (done[c.label], distance(c), c.text)):
        by_area.setdefault(c.area, []).append(c)
    order = sorted(by_area, key=lambda a: (a in own, others[a], distance(by_area[a][0]), a))
    picked: list[Choice] = []
    labels: set[str] = set()
    for new_label in (True, False):
        progress = True
        while progress and len(picked) < MAX_CHOICES:
            progress = False
            for area in order:
                pick = next((c for c in by_area[area] if c not in picked and (c.label not in labels or not new_label)), None)
                if pick is None or len(picked) >= MAX_CHOICES:
                    continue
                picked.append(pick)
                labels.add(pick.label)
                progress = True
    return tuple(picked)

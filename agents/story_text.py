"""The story a person reads, built from what the simulation was told to do (the applied plan).

:func:`event_text` turns a parsed event into plain English: per character the action label
(one verb phrase per label in :data:`PHRASES`), the seat or the area (its relation and its
landmark), and the partner of a social action, with the objects' human names ("coffee_maker_1"
-> "the coffee maker"). Characters doing the same thing at the same place are named together
("Ben and Cy sit on the couch and watch TV."); partners of one social action are grouped even
when they stand at different places. An object is named by its id too only where another
object of the scene has the same label, after a landmark that tells it apart when there is
one: "the chair by the desk (chair_3)" (:class:`ObjectNames`).

The narrator's own words are shown beside this text only where ``storyteller.agents.narrator_words`` has
checked that they say the plan; otherwise they stay data (``story.json``'s ``activity``).

:func:`step_text` says what a planning step that started no event means (a wait, a failure).

Guarantee: the text depends only on the plans, the event's characters and the scene (no
clock, no model, no randomness), so a replayed run tells the same story; every action label
of ``storyteller.sim.motion.action_labels`` has a phrase whose words include one of its action words
(a test enumerates them). The scene may be None (an old ``story.json`` read without its
scene): names then come from the ids alone, without disambiguation.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from storyteller.agents.messages import ParsedEvent, PlannedCharacter, PlanningFailure
from storyteller.sim.motion.action_labels import ACTION_SPECS
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.scene_graph import footprint_distance, point_footprint_distance

LANDMARK_REACH = 2.5
"""Metres (footprint to footprint) within which a uniquely named object can tell an object
apart from others of its label ("the chair by the desk")."""

_NOUNS = {"white_board": "whiteboard"}
_CAPITALS = {"tv": "TV", "dvd": "DVD", "cd": "CD", "pc": "PC"}
_ID = re.compile(r"^(?P<label>[a-z][a-z0-9]*(?:_[a-z0-9]+)*?)_(?P<idx>\d+)$")


# ----- objects ----------------------------------------------------------------------------------
def label_of(name: str, scene: Scene | None = None) -> str:
    """The label of object ``name`` (from the scene, else from the ``<label>_<idx>`` id)."""
    if scene is not None and name in scene.by_name:
        return scene.by_name[name].label
    m = _ID.match(name)
    return m.group("label") if m else name


def noun(label: str) -> str:
    """The human name of a label, e.g. ``coffee_maker`` -> ``coffee maker``, ``tv`` -> ``TV``."""
    return _NOUNS.get(label) or " ".join(_CAPITALS.get(w, w) for w in label.split("_"))


class ObjectNames:
    """How a text names the objects of one scene: "the couch"; where another object shares the
    label, with a landmark that tells it apart and its id: "the chair by the desk (chair_3)",
    "the desk with the laptop (desk_2)", else "the chair (chair_3)"."""

    def __init__(self, scene: Scene | None) -> None:
        self.scene = scene
        self._counts: dict[str, int] = {}
        if scene is not None:
            for o in scene.objects:
                self._counts[o.label] = self._counts.get(o.label, 0) + 1
        self._named: dict[str, str] = {}

    def unique(self, name: str) -> bool:
        """Whether no other object of the scene has ``name``'s label (True without a scene)."""
        return self._counts.get(label_of(name, self.scene), 1) <= 1

    def __call__(self, name: str) -> str:
        if name not in self._named:
            self._named[name] = self._name(name)
        return self._named[name]

    def _name(self, name: str) -> str:
        base = f"the {noun(label_of(name, self.scene))}"
        if self.scene is None or name not in self.scene.by_name or self.unique(name):
            return base
        landmark = self._landmark(self.scene.by_name[name])
        return f"{base} {landmark} ({name})" if landmark else f"{base} ({name})"

    def _landmark(self, obj: SceneObject) -> str:
        """"by the desk": the nearest uniquely named object within :data:`LANDMARK_REACH` to
        which ``obj`` is nearer than any other object of its label ("" when there is none)."""
        assert self.scene is not None
        siblings = [o for o in self.scene.objects if o.label == obj.label and o.name != obj.name]
        candidates = sorted(
            ((footprint_distance(obj, o), o.name, o) for o in self.scene.objects
             if self._counts[o.label] == 1 and o.label != obj.label),
            key=lambda t: (t[0], t[1]),
        )  # fmt: skip
        for d, _, mark in candidates:
            if d > LANDMARK_REACH:
                break
            if all(footprint_distance(s, mark) > d for s in siblings):
                return f"{_relation_to(obj, mark)} the {noun(mark.label)}"
        return ""


def _relation_to(obj: SceneObject, mark: SceneObject) -> str:
    """How ``obj`` stands to its landmark: "with" (the landmark rests on it), "on" (it rests on
    the landmark) or "by"."""
    if obj.contains_xy(mark.center_xy[None, :])[0] and mark.z_min >= obj.z_max - 0.15:
        return "with"
    if mark.contains_xy(obj.center_xy[None, :])[0] and obj.z_min >= mark.z_max - 0.15:
        return "on"
    return "by"


# ----- actions ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class VerbPhrase:
    """How a text says one action label (third person singular; the plural is derived)."""

    does: str
    """The action alone, e.g. "makes coffee"; a place follows it ("at the coffee maker")."""
    words: tuple[str, ...]
    """Action words (stems, matched at a word start): a text that says this action uses one."""
    on: str = ""
    """The action on an object that the phrase itself names, e.g. "opens {obj}": used instead of
    ``does`` + place when the character is at an object of a label in ``objects``."""
    objects: tuple[str, ...] = ()
    partner: str = ""
    """With the other characters of a social action, e.g. "chats with {partner}"."""


PHRASES: dict[str, VerbPhrase] = {
    "walk": VerbPhrase("walks over", ("walk", "stroll", "head")),
    "idle": VerbPhrase("stands", ("stand", "wait", "rest", "stay", "idle", "sit")),
    "sit_down": VerbPhrase("sits down", ("sit", "seat")),
    "sit_idle": VerbPhrase("sits", ("sit", "seat", "rest")),
    "stand_up": VerbPhrase("stands up", ("stand", "rise", "get up", "gets up")),
    "chat": VerbPhrase("chats", ("chat", "talk", "convers", "gossip"), partner="chats with {partner}"),
    "discuss": VerbPhrase("discusses things", ("discuss", "debat", "talk"), partner="discusses things with {partner}"),
    "attend_meeting": VerbPhrase("attends a meeting", ("meet",), partner="attends a meeting with {partner}"),
    "handshake": VerbPhrase("shakes hands", ("shak", "handshake", "greet"), partner="shakes hands with {partner}"),
    "hug": VerbPhrase("hugs", ("hug", "embrac"), partner="hugs {partner}"),
    "dance": VerbPhrase("dances", ("danc",), partner="dances with {partner}"),
    "drink": VerbPhrase("drinks", ("drink", "sip")),
    "eat": VerbPhrase("eats", ("eat", "ate", "breakfast", "lunch", "dinner", "snack", "meal")),
    "use_smartphone": VerbPhrase("checks a phone", ("phone", "smartphone", "text", "scroll")),
    "read_book": VerbPhrase("reads a book", ("read", "book")),
    "use_laptop": VerbPhrase("works on a laptop", ("laptop",), on="works on {obj}", objects=("laptop",)),
    "work_on_computer": VerbPhrase("works at a computer", ("work", "computer", "typ")),
    "watch_tv": VerbPhrase("watches TV", ("watch", "tv", "television"), on="watches {obj}", objects=("tv",)),
    "listen_to_music": VerbPhrase("listens to music", ("listen", "music")),
    "wave": VerbPhrase("waves", ("wave", "waving")),
    "turn_on_tv": VerbPhrase("turns on the TV", ("turn", "switch"), on="turns on {obj}", objects=("tv",)),
    "turn_off_tv": VerbPhrase("turns off the TV", ("turn", "switch"), on="turns off {obj}", objects=("tv",)),
    "turn_on_record_player": VerbPhrase(
        "turns on the record player", ("turn", "switch", "play"), on="turns on {obj}", objects=("record_player",)
    ),
    "turn_off_record_player": VerbPhrase(
        "turns off the record player", ("turn", "switch", "stop"), on="turns off {obj}", objects=("record_player",)
    ),
    "open_fridge": VerbPhrase("opens the fridge", ("open",), on="opens {obj}", objects=("fridge",)),
    "close_fridge": VerbPhrase("closes the fridge", ("clos", "shut"), on="closes {obj}", objects=("fridge",)),
    "open_cabinet": VerbPhrase("opens a cabinet", ("open",), on="opens {obj}", objects=("cabinet",)),
    "close_cabinet": VerbPhrase("closes a cabinet", ("clos", "shut"), on="closes {obj}", objects=("cabinet",)),
    "use_coffee_maker": VerbPhrase("makes coffee", ("coffee", "brew", "espresso")),
    "use_toaster": VerbPhrase("makes toast", ("toast",)),
    "use_microwave": VerbPhrase(
        "heats up food in a microwave", ("microwav", "heat", "warm"), on="heats up food in {obj}", objects=("microwave",)
    ),
    "use_dishwasher": VerbPhrase(
        "loads the dishwasher", ("dishwasher", "dishes", "load"), on="loads {obj}", objects=("dishwasher",)
    ),
    "use_water_dispenser": VerbPhrase("fills a cup with water", ("water", "fill")),
    "take_out_drink": VerbPhrase(
        "takes out a drink", ("drink", "take", "grab"), on="takes a drink from {obj}",
        objects=("fridge", "cabinet", "wine_rack", "bar_counter"),
    ),
    "take_out_document": VerbPhrase(
        "takes out a document", ("document", "file", "paper"), on="takes a document from {obj}",
        objects=("cabinet", "bookshelf", "desk"),
    ),
    "take_out_book": VerbPhrase(
        "takes out a book", ("book",), on="takes a book from {obj}", objects=("bookshelf", "cabinet")
    ),
    "clean_white_board": VerbPhrase(
        "cleans the whiteboard", ("clean", "wipe", "eras"), on="cleans {obj}", objects=("white_board",)
    ),
    "write_on_white_board": VerbPhrase(
        "writes on the whiteboard", ("writ", "draw"), on="writes on {obj}", objects=("white_board",)
    ),
    "clean_table": VerbPhrase(
        "wipes a table", ("clean", "wipe"), on="wipes {obj}", objects=("table", "desk", "bar_counter")
    ),
    "deliver_menu": VerbPhrase("brings a menu", ("menu",), on="brings a menu to {obj}", objects=("table", "bar_counter")),
    "serve_food": VerbPhrase(
        "serves food", ("serv", "food", "dish"), on="serves food at {obj}", objects=("table", "bar_counter")
    ),
    "serve_drink": VerbPhrase(
        "serves a drink", ("serv", "drink"), on="serves a drink at {obj}", objects=("table", "bar_counter")
    ),
    "take_order": VerbPhrase("takes an order", ("order",), on="takes an order at {obj}", objects=("table", "bar_counter")),
    "order_food": VerbPhrase("orders food", ("order", "food")),
    "order_drink": VerbPhrase("orders a drink", ("order", "drink")),
    "pay_bill": VerbPhrase("pays the bill", ("pay", "bill", "check")),
}

_SEATED_ONLY = {"idle": "sits on {seat}", "sit_idle": "sits on {seat}", "sit_down": "sits down on {seat}",
                "stand_up": "stands up from {seat}"}  # fmt: skip


def phrase_of(label: str) -> VerbPhrase:
    """The phrase of ``label``; an unknown label (an old or hand-made story) is said as it is."""
    known = PHRASES.get(label)
    if known is not None:
        return known
    words = label.replace("_", " ").strip() or "something"
    return VerbPhrase(f"does {words}", tuple(w for w in words.split() if len(w) > 2) or (words,))


def plural(singular: str) -> str:
    """The plural of a phrase in the third person singular (its first word): "watches TV" ->
    "watch TV", "sits on" -> "sit on"."""
    first, _, rest = singular.partition(" ")
    if first in ("has", "does", "goes"):
        base = {"has": "have", "does": "do", "goes": "go"}[first]
    elif first.endswith(("ches", "shes", "sses", "xes", "zes")):
        base = first[:-2]
    elif first.endswith("ies"):
        base = first[:-3] + "y"
    elif first.endswith("s"):
        base = first[:-1]
    else:
        base = first
    return f"{base} {rest}".rstrip()


# ----- places -----------------------------------------------------------------------------------
_RELATIONS = {
    "interact with": "at", "sit on": "on", "lie on": "on", "adjacent to": "next to", "close to": "by",
    "in front of": "in front of", "behind": "behind", "to the left of": "to the left of",
    "to the right of": "to the right of", "inside": "in",
}  # fmt: skip
_ONE = re.compile(r"^(?P<rel>" + "|".join(re.escape(r) for r in _RELATIONS) + r") (?P<a>\S+)$")
_TWO = re.compile(r"^(?P<rel>between|aligned with) (?P<a>\S+) and (?P<b>\S+)$")
_POINT = re.compile(r"^\[\s*(-?[\d.]+)\s*,\s*(-?[\d.]+)\s*\]$")


@dataclass(frozen=True)
class Place:
    """Where a character's area puts it: the relations (phrase, anchor objects) that hold there."""

    parts: tuple[tuple[str, tuple[str, ...]], ...] = ()

    @property
    def objects(self) -> tuple[str, ...]:
        return tuple(o for _, objs in self.parts for o in objs)

    def text(self, names: ObjectNames) -> str:
        out = []
        for rel, objs in self.parts:
            if rel in ("between", "aligned with"):
                joined = " and ".join(names(o) for o in objs)
                out.append(f"{'between' if rel == 'between' else 'in line with'} {joined}")
            else:
                out.append(f"{_RELATIONS.get(rel, rel)} {names(objs[0])}")
        return " and ".join(out)


def _split_top(text: str, operator: str) -> list[str]:
    """``text`` split at ``operator`` outside parentheses."""
    parts, depth, start, i = [], 0, 0, 0
    while i < len(text):
        ch = text[i]
        if ch == "(":
            depth += 1
        elif ch == ")":
            depth -= 1
        elif depth == 0 and text.startswith(operator, i):
            parts.append(text[start:i])
            i += len(operator)
            start = i
            continue
        i += 1
    parts.append(text[start:])
    return [p.strip() for p in parts]


def _unwrap(text: str) -> str:
    text = text.strip()
    while text.startswith("(") and text.endswith(")") and _balanced(text[1:-1]):
        text = text[1:-1].strip()
    return text


def _balanced(text: str) -> bool:
    depth = 0
    for ch in text:
        depth += {"(": 1, ")": -1}.get(ch, 0)
        if depth < 0:
            return False
    return depth == 0


def parse_place(area: str, position: tuple[float, float], scene: Scene | None) -> Place:
    """The :class:`Place` of an area text (``storyteller.tools.areas`` descriptions: "interact with X",
    "close to X", "A && B", "A || B", "[x, y]"); of an "or", the alternative whose objects are
    nearest the sampled ``position``. An explicit point is "by" its nearest object; text that
    is none of these ("current position", "") gives no place."""
    text = _unwrap(area)
    alternatives = _split_top(text, " || ")
    if len(alternatives) > 1:
        places = [parse_place(a, position, scene) for a in alternatives]
        return min(places, key=lambda p: _distance(p, position, scene))
    conjuncts = _split_top(text, " && ")
    if len(conjuncts) > 1:
        return Place(tuple(part for c in conjuncts for part in parse_place(c, position, scene).parts))
    if m := _ONE.match(text):
        return Place(((m.group("rel"), (m.group("a"),)),))
    if m := _TWO.match(text):
        return Place(((m.group("rel"), (m.group("a"), m.group("b"))),))
    if _POINT.match(text) and scene is not None and scene.objects:
        xy = np.array([position])
        nearest = min(scene.objects, key=lambda o: (float(point_footprint_distance(o, xy)[0]), o.name))
        return Place((("close to", (nearest.name,)),))
    return Place()


def _distance(place: Place, position: tuple[float, float], scene: Scene | None) -> float:
    if scene is None or not place.objects:
        return float("inf") if not place.objects else 0.0
    xy = np.array([position])
    known = [scene.by_name[o] for o in place.objects if o in scene.by_name]
    return sum(float(point_footprint_distance(o, xy)[0]) for o in known) / max(1, len(known))


def place_text(plan: PlannedCharacter, scene: Scene | None) -> str:
    """Where a plan puts its character, in words: "on the couch", "at the coffee maker"; the
    area text as it is when it reads as no place (an unknown form, "current position")."""
    names = ObjectNames(scene)
    if plan.seat:
        return f"on {names(plan.seat)}"
    return parse_place(plan.area, plan.position, scene).text(names) or plan.area


def planned_object(plan: PlannedCharacter, scene: Scene | None) -> str | None:
    """The object a character's plan is about: its seat, else the first object of its place."""
    if plan.seat:
        return plan.seat
    objects = parse_place(plan.area, plan.position, scene).objects
    return objects[0] if objects else None


# ----- sentences --------------------------------------------------------------------------------
def join_names(names: Sequence[str]) -> str:
    """"Ava", "Ava and Ben", "Ava, Ben and Cy"."""
    names = list(names)
    if len(names) <= 1:
        return "".join(names)
    return f"{', '.join(names[:-1])} and {names[-1]}"


@dataclass(frozen=True)
class _Clause:
    character: str
    label: str
    does: str
    """The whole predicate in the singular, e.g. "sits on the couch and drinks"."""
    do: str
    """The same in the plural: "sit on the couch and drink"."""
    where: str
    """Where the character is, for a group of partners at different places ("on the couch")."""


def _clause(plan: PlannedCharacter, names: ObjectNames) -> _Clause:
    phrase = phrase_of(plan.action)
    if plan.seat:
        seat = names(plan.seat)
        seated = _SEATED_ONLY.get(plan.action)
        if seated:
            does = seated.format(seat=seat)
            return _Clause(plan.character, plan.action, does, plural(does), f"on {seat}")
        return _Clause(plan.character, plan.action, f"sits on {seat} and {phrase.does}",
                       f"sit on {seat} and {plural(phrase.does)}", f"on {seat}")  # fmt: skip
    place = parse_place(plan.area, plan.position, names.scene)
    where = place.text(names)
    anchor = place.objects[0] if len(place.parts) == 1 and len(place.objects) == 1 else None
    if phrase.on and anchor is not None and label_of(anchor, names.scene) in phrase.objects:
        does = phrase.on.format(obj=names(anchor))
    elif plan.action == "walk" and where.startswith("at "):
        does = f"{phrase.does} to {where[3:]}"
    else:
        does = f"{phrase.does} {where}".rstrip()
    return _Clause(plan.character, plan.action, does, plural(does), where)


def _is_social(label: str) -> bool:
    spec = ACTION_SPECS.get(label)
    return spec is not None and spec.family == "partner"


def _sentence(who: list[str], does: str, do: str | None = None) -> str:
    return f"{join_names(who)} {does if len(who) == 1 else (do if do is not None else plural(does))}."


def plan_text(characters: Sequence[str], plans: Sequence[PlannedCharacter], scene: Scene | None) -> str:
    """The plain-English sentences of one event's plans (see the module docstring): one per
    action label, in the order the plans give them; characters with the same clause share it
    ("Ben and Cy sit on the couch and watch TV."), and those doing one action at different
    places are told together with each one's place ("Ben and Cy chat, Ben on the armchair and
    Cy by the TV.")."""
    if not plans:
        return _sentence(list(characters), "carries on") if characters else "Nobody does anything new."
    names = ObjectNames(scene)
    clauses = [_clause(p, names) for p in plans]
    by_label: dict[str, dict[str, list[_Clause]]] = {}
    for c in clauses:
        by_label.setdefault(c.label, {}).setdefault(c.does, []).append(c)
    return " ".join(_label_sentences(list(same.values()), clauses) for same in by_label.values())


def _label_sentences(groups: list[list[_Clause]], everyone: list[_Clause]) -> str:
    """The sentences of one action label: ``groups`` of characters with the same clause."""
    first = groups[0][0]
    phrase = phrase_of(first.label)
    who = [c.character for g in groups for c in g]
    if len(groups) > 1 and all(c.where for g in groups for c in g):
        spots = join_names([f"{join_names([c.character for c in g])} {g[0].where}" for g in groups])
        return f"{join_names(who)} {plural(phrase.does)}, {spots}."
    out = []
    for g in groups:
        members = [c.character for c in g]
        if len(g) == 1 and _is_social(first.label):
            others = [c.character for c in everyone if _is_social(c.label) and c.character not in members]
            out.append(_sentence(members, _with_partners(g[0], phrase, others)))
        else:
            out.append(_sentence(members, g[0].does, g[0].do))
    return " ".join(out)


def _with_partners(clause: _Clause, phrase: VerbPhrase, partners: list[str]) -> str:
    """A lone character's social clause naming the others of the action: "sits on the couch
    and chats with Cy", "chats with Cy by the TV"."""
    if not partners or not phrase.partner:
        return clause.does
    with_them = phrase.partner.format(partner=join_names(partners))
    if clause.does.endswith(phrase.does):
        return clause.does[: len(clause.does) - len(phrase.does)] + with_them
    if clause.does.startswith(phrase.does):
        return with_them + clause.does[len(phrase.does):]
    return clause.does


def event_text(event: ParsedEvent, scene: Scene | None) -> str:
    """The text a person reads for an applied event (built from its plans, never the narrator's
    words)."""
    return plan_text(event.event.characters, event.plans, scene)


# ----- steps without an event -------------------------------------------------------------------
_NODES = {"describer": "the describer", "narrator": "the narrator", "event_parser": "the event parser",
          "planner": "the planner"}  # fmt: skip


def step_text(outcome: PlanningFailure | None) -> str:
    """What a planning step that started no event means to a reader: a wait (None) or a failure."""
    if outcome is None:
        return "Nothing new starts; everyone carries on with what they are doing."
    who = outcome.event.characters if outcome.event is not None else ()
    whom = f" for {join_names(list(who))}" if who else ""
    tries = "attempt" if outcome.attempts == 1 else "attempts"
    return (f"No new event could be planned{whom}: {_NODES.get(outcome.node, outcome.node)} gave up after "
            f"{outcome.attempts} {tries}.")  # fmt: skip

"""Shortlists of the objects and seats an event is about, from its words and the scene.

A 0.5B model asked to pick one of 40 objects or 10 seats picks the first one listed about as
often as the right one. Most events name what they are about: an object (``couch_1``), an
object label (``the couch``, ``the coffee maker``), an action whose label names an object
label (``makes coffee`` -> ``use_coffee_maker`` -> ``coffee_maker``), or a place relative to
another object (``the chair by the window``). :func:`event_shortlist` turns those words into
candidates, and :mod:`storyteller.agents.program_grammar` offers only those to the model:

- objects: every object named, or of a label named (a label's last word, ``table``, matches
  every label ending in it unless a longer label matches in full, ``coffee table``), or of a
  label the best-matching action labels name; with two named groups and a proximity word
  (``by``, ``near``, ``next to``, ``nearest``, ``farthest``...) the first group keeps only its
  members close to (within ``CLOSE_M`` of) the second, or the nearest / farthest one;
- seats: the free seats among those objects (those close to a named non-seat object when there
  are such: "a chair at the table"), else the free seats within ``CLOSE_M`` of the named
  objects (sitting at a table, at the desk with the laptop; within ``VIEWED_M`` of a thing watched
  from afar, a TV).

An empty shortlist means "no evidence": the caller offers everything. Pure: no LLM, no I/O.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from storyteller.agents.object_names import read_as_labels
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.areas import seat_slots
from storyteller.tools.scene_graph import footprint_distance

CLOSE_M = 1.0
"""Horizontal gap (m) under which an object counts as close to another (the scene graph's
``close to``)."""
SYNONYMS = {"sofa": "couch", "television": "tv", "refrigerator": "fridge", "telly": "tv", "turntable": "record player"}
"""One-word names the action reader (:mod:`storyteller.agents.action_shortlist`) reads as object words;
object names in general are :mod:`storyteller.agents.object_names`' (read before any matching here)."""
DINING = re.compile(r"\b(?:dining|dinner|kitchen|breakfast|conference|meeting|boardroom) tables?\b")
"""A table people eat or meet at: of the tables named, those with the most chairs around them."""
CHARACTER_NEAR_M = 1.5
"""Free seats within this distance (m) of a character the event names ("joins Gus at his
table") are the seats for it."""
VIEWED_M = 4.0
"""Seats within this gap of a thing watched from afar (``VIEWED``) count as seats for it."""
VIEWED = frozenset({"tv", "screen", "whiteboard", "projector", "window", "fireplace", "stage"})
NEAR_WORDS = ("near", "nearest", "closest", "next to", "beside", "by the", "close to", "at the end", "facing", "with the")
FAR_WORDS = ("farthest", "furthest", "away from", "most distant", "far from", "avoiding", "clear of")

_WORD = re.compile(r"[a-z0-9]+")


RELATIONS = (
    ("get_area_behind", re.compile(r"\bbehind\b")),
    ("get_area_left_of", re.compile(r"\bleft(?:[- ]hand)?(?: side)? of\b|\bto the left\b")),
    ("get_area_right_of", re.compile(r"\bright(?:[- ]hand)?(?: side)? of\b|\bto the right\b")),
    ("get_area_in_front_of", re.compile(r"\bin front of\b")),
    ("get_area_between", re.compile(r"\bbetween\b")),
)
"""Where-words that name one area function of the spatial API ("on the right-hand side of the
armchair" is ``get_area_right_of``); a place of that kind is a place to stand."""
NEXT_TO = re.compile(r"\bnext to\b|\bbeside\b|\badjacent to\b|\balongside\b")


def relation_areas(text: str) -> tuple[str, ...]:
    """The area functions the text's where-words name: the directional ones (behind, left /
    right of, in front of, between), else adjacent / close for "next to" and "beside"; () when
    it names none (every area function stays on offer)."""
    lowered = " ".join(_WORD.findall(text.lower().replace("-", " ")))
    found = tuple(fn for fn, pattern in RELATIONS if pattern.search(lowered))
    if found:
        return found
    if NEXT_TO.search(lowered):
        return ("get_area_adjacent_to", "get_area_close_to")
    return ()


@dataclass(frozen=True)
class Shortlist:
    """Candidates for one event (empty: no evidence, offer everything)."""

    objects: tuple[str, ...]
    seats: tuple[str, ...]


def _rewrite(text: str) -> str:
    return text.lower().replace("_", " ")


def _words(text: str) -> list[str]:
    out = []
    for w in _WORD.findall(_rewrite(text)):
        out.extend(SYNONYMS.get(w, w).split())
        if len(w) > 3 and w.endswith("s"):  # plurals: "plates" also reads as "plate"
            out.extend(SYNONYMS.get(w[:-1], w[:-1]).split())
    return out


def _contains(words: Sequence[str], phrase: Sequence[str]) -> int:
    """Index of the first occurrence of ``phrase`` in ``words`` (-1: absent)."""
    n = len(phrase)
    for i in range(len(words) - n + 1):
        if list(words[i : i + n]) == list(phrase):
            return i
    return -1


def mentioned_labels(text: str, labels: Sequence[str], everyday: bool = True) -> list[str]:
    """Object labels the text names, in order of first mention (see the module docstring); the
    everyday names of :mod:`storyteller.agents.object_names` are read as the labels they name (unless
    ``everyday`` is False: the words as written)."""
    words = _words(read_as_labels(text.lower(), labels) if everyday else text)
    found: dict[str, int] = {}
    by_head: dict[str, list[str]] = {}
    for label in dict.fromkeys(labels):
        parts = label.split("_")
        by_head.setdefault(parts[-1], []).append(label)
        if (at := _contains(words, parts)) >= 0:
            found[label] = at
    for head, group in by_head.items():
        if any(label in found for label in group):
            continue
        if (at := _contains(words, [head])) >= 0:
            for label in group:
                found[label] = at
    return sorted(found, key=lambda label: found[label])


def _most_chairs(tables: list[SceneObject], scene: Scene) -> list[SceneObject]:
    """The tables with the most chairs within ``CLOSE_M`` (a dining table, not a coffee table)."""
    chairs = [o for o in scene.objects if o.is_seat and o.label.split("_")[-1] == "chair"]
    count = {t.name: sum(footprint_distance(t, c) <= CLOSE_M for c in chairs) for t in tables}
    best = max(count.values(), default=0)
    return [t for t in tables if count[t.name] == best] if best else tables


_NUMBERS = {"one": 1, "two": 2, "three": 3, "four": 4, "five": 5, "six": 6, "seven": 7, "eight": 8, "ten": 10, "twelve": 12}
_COUNT = r"(\d+|" + "|".join(_NUMBERS) + r")"
CAPACITY = re.compile(
    r"\btables?\s+(?:(?:for|seating|that seats|which seats)\s+" + _COUNT
    + r"|with\s+" + _COUNT + r"\s+(?:chairs|seats|stools|places))\b"
)
"""A table named by how many it seats: "a table for four", "the table that seats six", "the
table with two chairs"."""
SMALL = frozenset({"small", "smaller", "smallest", "little", "tiny"})
LARGE = frozenset({"big", "bigger", "biggest", "large", "larger", "largest", "huge"})
ROUND = frozenset({"round", "circular", "square"})
LONG = frozenset({"long", "rectangular", "oblong"})
"""Size and shape words in front of an object's label ("the small round table") pick among the
objects of that label by footprint: the smallest / largest area (within ``SIZE_TIE``), a
footprint about as deep as wide (within ``ROUND_RATIO``) or clearly longer than deep."""
SIZE_TIE = 1.15
ROUND_RATIO = 1.25


def _aspect(o: SceneObject) -> float:
    short, long_ = sorted((max(o.width, 1e-6), max(o.depth, 1e-6)))
    return long_ / short


def _by_look(group: list[SceneObject], adjectives: set[str]) -> list[SceneObject]:
    """``group`` narrowed by the size and shape words ``adjectives`` (each kept only when some
    object fits it; see ``SMALL``)."""
    out = group
    if adjectives & ROUND:
        out = [o for o in out if _aspect(o) <= ROUND_RATIO] or out
    if adjectives & LONG:
        out = [o for o in out if _aspect(o) > ROUND_RATIO] or out
    if adjectives & (SMALL | LARGE) and len(out) > 1:
        area = {o.name: o.width * o.depth for o in out}
        if adjectives & SMALL:
            least = min(area.values())
            out = [o for o in out if area[o.name] <= least * SIZE_TIE]
        else:
            most = max(area.values())
            out = [o for o in out if area[o.name] * SIZE_TIE >= most]
    return out


def _adjectives_before(text: str, label: str, span: int = 3) -> set[str]:
    """The words up to ``span`` before the first mention of ``label`` (or its last word)."""
    words = _words(text)
    parts = label.split("_")
    at = _contains(words, parts)
    if at < 0:
        at = _contains(words, parts[-1:])
    return set(words[max(0, at - span) : at]) if at > 0 else set()


def seats_around(table: SceneObject, scene: Scene) -> int:
    """How many people can sit at ``table``: the places (seat slots) of the seats within
    ``CLOSE_M`` of it."""
    return sum(max(1, len(seat_slots(o))) for o in scene.objects if o.is_seat and footprint_distance(table, o) <= CLOSE_M)


def _by_capacity(tables: list[SceneObject], scene: Scene, wanted: int) -> list[SceneObject]:
    """The tables that seat exactly ``wanted`` (else the smallest that seat more; else all)."""
    count = {t.name: seats_around(t, scene) for t in tables}
    exact = [t for t in tables if count[t.name] == wanted]
    if exact:
        return exact
    more = [count[t.name] for t in tables if count[t.name] > wanted]
    return [t for t in tables if count[t.name] == min(more)] if more else tables


def _after_proximity(text: str) -> str:
    """The words after the last proximity word: they name the landmark ("the stool at the end
    of the bar nearest the coffee maker": the coffee maker), "" when there is none."""
    words = _WORD.findall(_rewrite(text))
    lowered = " " + " ".join(words) + " "
    at = [lowered.rfind(f" {w} ") for w in (*NEAR_WORDS, *FAR_WORDS) if f" {w} " in lowered]
    return lowered[max(at):] if at else ""


def _near_filter(first: list[SceneObject], others: list[SceneObject], text: str) -> list[SceneObject]:
    lowered = " " + " ".join(_WORD.findall(text.lower())) + " "
    far = any(f" {w} " in lowered for w in FAR_WORDS)
    near = any(f" {w} " in lowered for w in NEAR_WORDS)
    if not others or not (far or near):
        return first
    gap = {o.name: min(footprint_distance(o, b) for b in others) for o in first}
    if far:
        best = max(gap.values())
        return [o for o in first if gap[o.name] == best]
    if " nearest " in lowered or " closest " in lowered:
        best = min(gap.values())
        return [o for o in first if gap[o.name] == best]
    return [o for o in first if gap[o.name] <= CLOSE_M] or first


def event_shortlist(
    scene: Scene, text: str, free_seats: Sequence[str], action_labels: Sequence[str] = (),
    others: Mapping[str, tuple[float, float]] | None = None,
) -> Shortlist:
    """The objects and free seats ``text`` (an event's activity) is about, best evidence first.
    ``others``: where the characters outside the event are; when the text names one of them
    ("sits down at Gus's table"), the free seats near them come first."""
    by_name = {o.name: o for o in scene.objects}
    text = read_as_labels(text.lower(), scene.labels)  # "the water cooler": the water dispenser
    lowered = text
    named = [o for o in scene.objects if _mentions(o.name.lower(), lowered)]
    labels = mentioned_labels(text, scene.labels)
    groups = [[o for o in scene.objects if o.label == label] for label in labels]
    if DINING.search(_rewrite(text)) and not _after_proximity(text):  # "the dining table nearest X" picks by place
        groups = [_most_chairs(g, scene) if g and g[0].label.split("_")[-1] == "table" else g for g in groups]
    if (capacity := CAPACITY.search(_rewrite(text))) is not None:  # "a small table for two"
        count = capacity.group(1) or capacity.group(2)
        wanted = int(count) if count.isdigit() else _NUMBERS[count]
        groups = [_by_capacity(g, scene, wanted) if g and g[0].label.split("_")[-1] == "table" else g for g in groups]
    groups = [_by_look(g, _adjectives_before(text, label)) if len(g) > 1 else g
              for label, g in zip(labels, groups, strict=True)]  # "the small round table"
    if len(groups) >= 2:
        after = set(mentioned_labels(_after_proximity(text), scene.labels))
        references = [g for label, g in zip(labels[1:], groups[1:], strict=True) if label in after] or groups[1:]
        groups[0] = _near_filter(groups[0], [o for g in references for o in g], text)
    words = set(_words(text))  # an action whose label names an object label: "makes coffee" -> use_coffee_maker
    acted = [a for a in action_labels if words & set(a.split("_")) - {"on", "off", "to", "use", "the"}]
    implied = [o for lab in scene.labels if lab not in labels and any(lab in a for a in acted) for o in scene.objects if o.label == lab]
    objects = list(dict.fromkeys([o.name for o in named] + [o.name for g in groups for o in g] + [o.name for o in implied]))
    # seats go by what the event is about (not its landmarks), or by any named thing when that is a seat
    anchors = [o for o in (*named, *(groups[0] if groups else implied)) if not o.is_seat]
    anchors = anchors or [o for g in groups for o in g if not o.is_seat]
    free = [by_name[s] for s in free_seats if s in by_name]
    def reach(o: SceneObject) -> float:
        return VIEWED_M if o.label.split("_")[-1] in VIEWED else CLOSE_M

    near_chosen = [s.name for s in free
                   if any(o.name != s.name and footprint_distance(s, o) <= reach(o) for o in anchors)]
    seats = [s.name for s in free if s.name in objects]
    if seats and near_chosen:  # "a chair at the table": the named seats by the named things
        seats = [s for s in seats if s in near_chosen] or seats
    elif not seats:  # sit at / by what the event names
        seats = near_chosen
    by_character = _seats_by_named_characters(text, free, others or {})
    if by_character:
        seats = [s for s in seats if s in by_character] or by_character
    return Shortlist(objects=tuple(objects), seats=tuple(seats))


def mention_pattern(word: str) -> str:
    """The pattern of ``word`` as a whole word (its characters taken literally)."""
    return rf"\b{re.escape(word)}\b"


def _mentions(word: str, text: str, flags: int = 0) -> bool:
    return re.search(mention_pattern(word), text, flags) is not None


def _seats_by_named_characters(
    text: str, free: Sequence[SceneObject], others: Mapping[str, tuple[float, float]]
) -> list[str]:
    """Free seats within ``CHARACTER_NEAR_M`` of the characters ``text`` names."""
    named = [pos for name, pos in others.items() if _mentions(name, text, re.IGNORECASE)]
    if not named:
        return []
    out = []
    for seat in free:
        points: list[tuple[float, ...]] = [tuple(float(v) for v in s.position) for s in seat_slots(seat)]
        points = points or [tuple(float(v) for v in seat.center[:2])]
        if any(math.dist(p, q) <= CHARACTER_NEAR_M for p in points for q in named):
            out.append(seat.name)
    return out

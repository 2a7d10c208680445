"""Which of the scene description's areas an event's words name ("naps in the den").

The scene description the narrator and the parser read is one line per functional area
(``- kitchen (make coffee): fridge_1, chair_2, ...``, :func:`storyteller.agents.describer.render_description`).
When an instruction places someone "in the galley", "in the boardroom" or "at the bar",
the seats that fit are the ones the description puts in that area; a 0.5B model asked to pick a
seat does not read that off the description (it picks ``chair_1``).

- :func:`described_areas` reads the areas back from the description's text (name, purpose and the
  scene objects listed on the line). A description of another form (an object list) has no
  area lines and gives none.
- :func:`named_areas` gives the areas the words name: by the area's own name, or by the name of
  its kind of room or a synonym of it in the room table (``prompts/describer/rooms.toml``: "the
  boardroom" names an area the describer called "meeting room"). A name counts only as a noun
  phrase of its own after a preposition of being inside ("in the den", "at their bar", not "the
  lamp closest to the den"), and not when the words lead away from it. Words are compared
  without an "-ing" or plural "-s" ending, so "the reading areas" name a "reading area".
- Failing a name, an area is named by what a phrase of use says the place is for ("the space
  reserved for presenting slides", "a spot where people relax"): the area whose purpose
  or kind's functions in the room table share the most words with it.
- :func:`keep_in_areas` narrows a list of objects to the named areas, kind by kind: of a label
  with instances there, only those ("the shelf in the reading nook", "between the stools at
  the bar"); a label with none there keeps all its instances.

Pure: no LLM, no I/O.
"""

from __future__ import annotations

import re
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass

from storyteller.agents.object_names import EVERYDAY_NAMES
from storyteller.agents.prompt_templates import PromptLibrary
from storyteller.agents.room_table import RoomTable, room_table

_TOKEN = re.compile(r"[A-Za-z0-9_]+")
_WORD = re.compile(r"[a-z0-9']+")

DETERMINERS = frozenset({"the", "a", "an", "this", "that", "his", "her", "their", "our", "its", "my", "your"})
"""Words before a noun phrase of its own (general English determiners and possessives)."""
INSIDE_WORDS = frozenset({"in", "inside", "within", "into", "at"})
"""Prepositions that put someone in a place ("in the den", "at the bar"); "the lamp closest to
the den" or "beside the galley" relate to the place instead, and name no area."""
AWAY_WORDS = frozenset({"from", "outside", "leaves", "leave", "leaving", "left", "exits", "exit", "beyond", "past"})
"""Words that lead away from the place after them ("away from the den", "leaves the bar")."""
AWAY_SPAN = 3
"""How many words before a place name an away word may stand ("well away from the den")."""


@dataclass(frozen=True)
class DescribedArea:
    """One area line of a scene description."""

    name: str
    purpose: str
    objects: frozenset[str]


def described_areas(text: str, object_names: Iterable[str]) -> tuple[DescribedArea, ...]:
    """The areas of a description ``text``, each with the scene objects (``object_names``) its
    line lists; lines that are not area lines are skipped."""
    known = set(object_names)
    areas: list[DescribedArea] = []
    for line in text.splitlines():
        line = line.strip()
        head, colon, listed = line.removeprefix("- ").partition(":")
        if not line.startswith("- ") or not colon:
            continue
        name, _, purpose = head.partition("(")
        objects = frozenset(n for n in _TOKEN.findall(listed) if n in known)
        if name.strip() and objects:
            areas.append(DescribedArea(name.strip(), purpose.rpartition(")")[0].strip(), objects))
    return tuple(areas)


def _stem(word: str) -> str:
    """``word`` without an "-ing" or plural "-s" ending (both sides of a comparison alike)."""
    if word.endswith("ing") and len(word) > 5:
        return word[:-3]
    if word.endswith("s") and not word.endswith("ss") and len(word) > 3:
        return word[:-1]
    return word


def _phrases(name: str) -> list[tuple[str, ...]]:
    return [tuple(_stem(w) for w in _WORD.findall(name.lower().replace("_", " ")))]


def _place_names(area: DescribedArea, table: RoomTable) -> list[tuple[str, ...]]:
    """The phrases that name ``area``: its own name, its kind's name and the kind's synonyms."""
    names = _phrases(area.name)
    kind = table.kind_of(area.name)
    if kind is not None and kind != "other":
        names += _phrases(kind)
        names += [p for s in table.kinds[kind].synonyms for p in _phrases(s)]
    return [n for n in names if n]


def _named_at(words: Sequence[str], stems: Sequence[str], name: tuple[str, ...]) -> bool:
    """Whether ``name`` (stemmed) occurs in ``words`` (``stems``: theirs) as a noun phrase of its
    own after a word of being inside ("in the den"), not led away from."""
    n = len(name)
    for i in range(1, len(words) - n + 1):
        if tuple(stems[i : i + n]) != name:
            continue
        inside = words[i - 1] in INSIDE_WORDS  # "in den": a model's short text drops the article
        if not inside and not (i >= 2 and words[i - 1] in DETERMINERS and words[i - 2] in INSIDE_WORDS):
            continue
        if i + n < len(words) and words[i + n] in ("of", "'s"):
            continue  # "the bar of the hotel" names something else
        if not any(w in AWAY_WORDS for w in words[max(0, i - 1 - AWAY_SPAN) : i - 1]):
            return True
    return False


def named_areas(
    text: str, areas: Sequence[DescribedArea], prompts: PromptLibrary | None = None, labels: Iterable[str] = (),
) -> tuple[DescribedArea, ...]:
    """The areas of ``areas`` that ``text`` names (see the module docstring), in their order. A
    phrase that names a kind of object of the scene (its label's words, or an everyday name of
    several words: "the desk", "the reception desk", "the front desk") names that object, not an
    area; an everyday name of one word ("the reception", "the bar") still names the area."""
    words = _WORD.findall(text.lower().replace("_", " "))
    stems = [_stem(w) for w in words]
    things = {p for label in labels for p in _phrases(label)}  # "the desk" is the desk, not a work area
    things |= {p for label in labels for n in EVERYDAY_NAMES.get(label, ()) for p in _phrases(n) if len(p) > 1}
    for thing in sorted(things, key=len, reverse=True):  # words naming a thing name no area: masked
        n = len(thing)
        for i in range(len(stems) - n + 1):
            if tuple(stems[i : i + n]) == thing:
                stems[i : i + n] = [""] * n
    table = room_table(prompts)
    by_name = tuple(a for a in areas if any(_named_at(words, stems, name) for name in _place_names(a, table)))
    return by_name or _named_by_use(words, areas, table)


PLACE_NOUNS = frozenset({"area", "place", "space", "spot", "zone", "corner", "section", "part"})
"""Nouns of a place that a phrase of use can describe ("the space reserved for ...")."""
USE_LINKS = frozenset({"designated", "meant", "used", "reserved", "intended", "set", "aside", "kept", "made"})
"""Words that may stand between such a noun and "for" ("the area set aside for meetings")."""
STOP_WORDS = frozenset({"a", "an", "the", "to", "of", "and", "or", "with", "for", "in", "on", "at", "their", "his",
                        "her", "people", "someone", "things", "thing", "something", "some", "it", "them"})  # fmt: skip
"""Words that say nothing about what a place is for."""
USE_SPAN = 5
"""Words after "for" / "where" that say what the place is for."""


def _uses(words: Sequence[str]) -> set[str]:
    """The stems of what a phrase of use says a place is for: "the space reserved for presenting
    slides" -> {"present", "slide"}; "a spot where people relax" -> {"relax"}."""
    out: set[str] = set()
    for i, w in enumerate(words):
        if w not in PLACE_NOUNS:
            continue
        j = i + 1
        while j < len(words) and words[j] in USE_LINKS:
            j += 1
        if j < len(words) and words[j] in ("for", "where"):
            out |= {_stem(t) for t in words[j + 1 : j + 1 + USE_SPAN] if t not in STOP_WORDS}
    return out


def _named_by_use(words: Sequence[str], areas: Sequence[DescribedArea], table: RoomTable) -> tuple[DescribedArea, ...]:
    """The areas whose purpose, or whose kind's functions in the room table, share the most words
    with what a phrase of use says the place is for (none: no such phrase, or no word shared)."""
    uses = _uses(words)
    if not uses:
        return ()

    def shared(area: DescribedArea) -> int:
        kind = table.kind_of(area.name)
        texts = [area.purpose, *(table.kinds[kind].functions if kind is not None and kind in table.kinds else ())]
        said = {_stem(t) for text in texts for t in _WORD.findall(text.lower())} - {_stem(w) for w in STOP_WORDS}
        return len(uses & said)

    scores = {a.name: shared(a) for a in areas}
    best = max(scores.values(), default=0)
    return tuple(a for a in areas if best > 0 and scores[a.name] == best)


def keep_in_areas(names: Sequence[str], labels: Mapping[str, str], in_area: Collection[str]) -> list[str]:
    """``names`` (objects; ``labels``: name -> label) narrowed, label by label, to those in
    ``in_area`` where the label has any there (see the module docstring); order kept."""
    inside = {labels[n] for n in names if n in in_area and n in labels}
    return [n for n in names if labels.get(n) not in inside or n in in_area]

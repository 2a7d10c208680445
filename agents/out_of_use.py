"""Things the words say cannot be used: "stool_2 is wobbly", "the couch is taken", "the wet bench".

An instruction may name a seat only to rule it out ("Noor lunches by table_1, but stool_2 there
has a cracked seat and is unsafe, so she picks a free one"). A small model that is asked for a
seat then picks the one named. :func:`out_of_use` finds the scene objects the words declare unusable, so the seat choice
(:mod:`storyteller.agents.place_choice`) leaves them out:

- a thing followed by a form of "be" (and adverbs such as "currently") and a word of unusability
  ("stool_2 is still wobbly", "the sofa is occupied", "bench_1 and bench_2 are wet");
- a word of unusability right before the thing ("the damaged stool_4", "the wobbly stool").

A thing is an object's name (``chair_3``) or a label the scene has exactly one of ("the couch").
The words are general English, a closed list of adjectives of state; no phrase of any case.
Pure: no LLM, no I/O.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from storyteller.agents.area_words import DETERMINERS
from storyteller.sim.scene.model import Scene

UNUSABLE = frozenset({
    "broken", "unavailable", "occupied", "taken", "wet", "dirty", "damaged", "cluttered",
    "blocked", "unusable", "wobbly", "missing", "cracked", "soaked", "stained", "filthy", "unsafe",
})  # fmt: skip
"""Adjectives saying a thing cannot be used now."""
UNUSABLE_PHRASES: tuple[tuple[str, ...], ...] = (
    ("out", "of", "order"), ("in", "use"), ("not", "available"), ("not", "free"), ("under", "repair"),
    ("being", "repaired"), ("covered", "in"), ("covered", "with"), ("full", "of"), ("occupied", "by"),
)  # fmt: skip
"""Phrases saying the same."""
BE = frozenset({"is", "are", "was", "were", "seems", "seem", "looks", "look", "remains", "remain", "'s"})
FILLERS = frozenset({"currently", "still", "already", "now", "sadly", "unfortunately", "completely", "fully", "all",
                     "both", "also", "totally", "temporarily", "a", "bit", "too"})  # fmt: skip
"""Words that may stand between the form of "be" and the adjective."""
_TOKEN = re.compile(r"[a-z0-9_']+")
MAX_LIST = 4
"""Things joined by "and" / "," before one verb ("chair_2 and chair_4 are wet")."""


def _things(scene: Scene) -> dict[tuple[str, ...], str]:
    """Token sequences that name one object: its name, or its label's words when unique."""
    out: dict[tuple[str, ...], str] = {(o.name,): o.name for o in scene.objects}
    counts: dict[str, int] = {}
    for o in scene.objects:
        counts[o.label] = counts.get(o.label, 0) + 1
    for o in scene.objects:
        if counts[o.label] == 1:
            out[tuple(o.label.split("_"))] = o.name
    return out


def _unusable_at(tokens: Sequence[str], i: int) -> bool:
    """Whether the words from ``i`` are a form of "be", fillers and a word of unusability."""
    if i >= len(tokens) or tokens[i] not in BE:
        return False
    j = i + 1
    while j < len(tokens) and tokens[j] in FILLERS:
        j += 1
    if j < len(tokens) and tokens[j] in UNUSABLE:
        return True
    return any(tuple(tokens[j : j + len(p)]) == p for p in UNUSABLE_PHRASES)


PREPOSITIONS = frozenset({"at", "to", "near", "by", "of", "beside", "with", "behind", "from", "in", "on", "under",
                          "above", "opposite", "next", "across", "around", "past", "toward", "towards", "for"})  # fmt: skip
"""Words before a thing that make it the landmark of a phrase, not what is out of use ("the
chair next to the couch is broken": the chair, not the couch)."""


def _in_a_phrase(tokens: Sequence[str], start: int) -> bool:
    """Whether the thing at ``start`` follows a preposition (determiners skipped)."""
    k = start - 1
    while k >= 0 and tokens[k] in DETERMINERS:
        k -= 1
    return k >= 0 and tokens[k] in PREPOSITIONS


def out_of_use(text: str, scene: Scene) -> frozenset[str]:
    """The names of the seats ``text`` says cannot be used (see the module docstring); a thing
    named as the landmark of a phrase ("next to the couch") is not what the words rule out."""
    names = {o.name for o in scene.objects}
    seats = {o.name for o in scene.objects if o.is_seat}
    tokens = [w for t in _TOKEN.findall(text.lower()) for w in ((t,) if t in names else t.split("_")) if w]
    things = sorted(_things(scene).items(), key=lambda kv: -len(kv[0]))
    found: list[tuple[int, int, str]] = []  # (start, end, name) of each thing named
    i = 0
    while i < len(tokens):
        for words, name in things:
            if tuple(tokens[i : i + len(words)]) == words:
                found.append((i, i + len(words), name))
                i += len(words)
                break
        else:
            i += 1
    out: set[str] = set()
    for k, (start, end, name) in enumerate(found):
        if start > 0 and tokens[start - 1] in UNUSABLE:
            out.add(name)
            continue
        if _in_a_phrase(tokens, start):
            continue
        group, last = [name], end  # "chair_2, chair_4 and chair_5 are wet"
        for s, e, n in found[k + 1 : k + MAX_LIST]:
            if s == last or (s - last == 1 and tokens[last] in ("and", "or", "nor")):  # commas are not tokens
                group.append(n)
                last = e
            else:
                break
        if _unusable_at(tokens, last):
            out.update(group)
    return frozenset(out & seats)


SIT_WORDS = frozenset({"on", "onto", "in", "into", "takes", "take", "taking", "grabs", "grab", "uses", "use"})
"""Words before a seat that make it the place an event sits ("sits on chair_1", "takes the couch")."""


def seats_taken_by(text: str, scene: Scene) -> frozenset[str]:
    """The seats ``text`` (an event's own words) sits on: named right after "on", "in", "takes"...
    (determiners skipped). A seat the event itself sits on is never ruled out by other words of
    the instruction ("chair_1 is taken" said of a later moment, "the couch is reserved")."""
    names = {o.name for o in scene.objects}
    seats = {o.name: o for o in scene.objects if o.is_seat}
    tokens = [w for t in _TOKEN.findall(text.lower()) for w in ((t,) if t in names else t.split("_")) if w]
    things = sorted(((w, n) for w, n in _things(scene).items() if n in seats), key=lambda kv: -len(kv[0]))
    out: set[str] = set()
    for i in range(len(tokens)):
        for words, name in things:
            if tuple(tokens[i : i + len(words)]) == words:
                k = i - 1
                while k >= 0 and tokens[k] in DETERMINERS:
                    k -= 1
                if k >= 0 and tokens[k] in SIT_WORDS:
                    out.add(name)
                break
    return frozenset(out)

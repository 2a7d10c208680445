"""Whether a described area's name and purpose fit the objects in it, by the room table.

Votes: every distinct label of an area's objects that the table knows (and that does not stand
"anywhere") votes for the kinds it admits, with weight 1 / (number of kinds it admits), so a
dishwasher (kitchen only) says more than a chair (almost anywhere). A kind's *score* is the
weight of the labels admitting it over the weight of all voting labels.

- A name **fits** when its kind (``RoomTable.kind_of``) scores at least
  ``min(FIT_SCORE, best score)``: a weighted majority of the labels admit it, or no kind does
  better. A name the table cannot read, or an area with no voting label, is not judged.
- A purpose **fits** unless it names more activities of other areas than of this one: its
  words are compared with the functions of the area's labels and fitting kinds (in) and with
  every other function in the table (foreign); "sleep and dress" on a couch and a TV is foreign.

:func:`area_problems_by_table` turns misfits into feedback sentences for the describer
(``prompts/feedback/describer/area_*.md``); :func:`rule_areas` renames the misfits from the
table (best kind, the labels' own functions) when the describer still disagrees;
:func:`region_choices` gives a region's fitting kinds and purposes for a grammar.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from storyteller.agents.prompt_templates import PromptLibrary, package_prompts
from storyteller.agents.room_table import RoomTable, room_table

FIT_SCORE = 0.75
"""Weighted share of an area's voting labels that must admit its kind (see the module docstring);
at 0.5 a couch, a TV and an armchair would fit a bedroom, and a table with chairs and a
whiteboard a bar."""
MAX_PURPOSES = 4
"""Purposes offered per region (the labels' functions, most specific label first)."""
RULE_PURPOSE_CHARS = 60
"""Longest purpose :func:`rule_purpose` writes (the describer's limit is 80 characters)."""
_STOP = frozenset({
    "a", "an", "the", "and", "or", "of", "to", "in", "on", "at", "for", "with", "by", "from", "up",
    "out", "down", "off", "into", "over", "while", "together", "things", "thing", "stuff", "room",
    "rooms", "area", "areas", "place", "places", "spot", "corner", "people", "person", "someone",
    "guests", "guest", "some", "their", "there", "them", "it", "its", "this", "that", "where",
    "here", "can", "may", "get", "take", "put", "keep", "use", "make", "have", "do", "go", "come",
    "hold", "set", "let", "each", "other", "all", "any", "more",
})


def _stem(word: str) -> str:
    for suffix in ("ing", "ed", "es", "s"):
        if word.endswith(suffix) and len(word) - len(suffix) >= 3 and not word.endswith("ss"):
            word = word[: -len(suffix)]
            break
    return word[:-1] if word.endswith("e") and len(word) > 3 else word


def words(text: str) -> frozenset[str]:
    """Content words of a phrase, stemmed ("Watches TV" -> {"watch", "tv"})."""
    return frozenset(_stem(w) for w in re.findall(r"[a-z]+", text.lower()) if w not in _STOP)


def area_labels(objects: Iterable[str], labels: Mapping[str, str]) -> list[str]:
    """Distinct labels of ``objects`` in order of first appearance (``labels``: name -> label)."""
    return list(dict.fromkeys(labels[o] for o in objects if o in labels))


def kind_scores(labels: Iterable[str], table: RoomTable) -> dict[str, float]:
    """Kind -> score (see the module docstring), in table order; empty when no label votes."""
    votes = [e.rooms for lab in dict.fromkeys(labels) if (e := table.label(lab)) is not None and not e.anywhere]
    total = sum(1.0 / len(r) for r in votes)
    if not votes:
        return {}
    return {k: sum(1.0 / len(r) for r in votes if k in r) / total for k in table.kinds}


def fitting_kinds(labels: Iterable[str], table: RoomTable) -> tuple[str, ...]:
    """Kinds whose name would fit, best first; () when no label votes. Ties go to the kind the
    labels list earlier among their rooms, relative to the lists' lengths (a lone bookshelf:
    reading corner; laptops on tables among chairs: work area), then table order."""
    labels = list(dict.fromkeys(labels))
    scores = kind_scores(labels, table)
    if not scores:
        return ()
    bar = min(FIT_SCORE, max(scores.values())) - 1e-9
    order = {k: i for i, k in enumerate(table.kinds)}
    rooms = [e.rooms for lab in labels if (e := table.label(lab)) is not None and not e.anywhere]

    def rank(kind: str) -> tuple[float, float, int]:  # a kind's place in each label's list, relative to its length
        return (-scores[kind], sum((r.index(kind) if kind in r else len(r)) / len(r) for r in rooms), order[kind])

    return tuple(sorted((k for k, s in scores.items() if s >= bar), key=rank))


def label_functions(labels: Iterable[str], table: RoomTable) -> list[str]:
    """The labels' functions, no repeats: every label's first function, most specific label
    first (fewest kinds; "anywhere" last), then every label's second one, and so on."""
    entries = [(i, e) for i, lab in enumerate(dict.fromkeys(labels)) if (e := table.label(lab)) is not None]
    entries.sort(key=lambda p: (p[1].anywhere, len(p[1].rooms), p[0]))
    depth = max((len(e.functions) for _, e in entries), default=0)
    return list(dict.fromkeys(e.functions[k] for k in range(depth) for _, e in entries if k < len(e.functions)))



def _vocabulary(table: RoomTable) -> frozenset[str]:
    phrases = [f for k in table.kinds.values() for f in k.functions]
    phrases += [f for e in table.labels.values() for f in e.functions]
    return frozenset(w for f in phrases for w in words(f))


def purpose_fits(purpose: str, labels: Sequence[str], kinds: Iterable[str], table: RoomTable) -> bool:
    """False when the purpose names more activities foreign to the area than of it."""
    said = words(purpose)
    if not said:
        return True
    own = [f for k in kinds if k in table.kinds for f in table.kinds[k].functions]
    own += label_functions(labels, table)
    inside = frozenset(w for f in own for w in words(f))
    foreign = (said & _vocabulary(table)) - inside
    return len(foreign) <= len(said & inside)


@dataclass(frozen=True)
class AreaFit:
    """The verdict on one area: its kind (None: a name the table cannot read), the kinds that
    would fit (best first; empty: no label votes, not judged) and whether name and purpose fit."""

    kind: str | None
    fitting: tuple[str, ...]
    name_fits: bool
    purpose_fits: bool

    @property
    def judged(self) -> bool:
        return self.kind is not None and bool(self.fitting)

    @property
    def agrees(self) -> bool:
        return self.name_fits and self.purpose_fits


def judge_area(name: str, purpose: str, labels: Sequence[str], table: RoomTable) -> AreaFit:
    kind = table.kind_of(name)
    fitting = fitting_kinds(labels, table)
    name_fits = kind is None or not fitting or kind in fitting
    kinds = fitting if not fitting or kind not in fitting else (kind, *fitting)
    return AreaFit(kind, fitting, name_fits, purpose_fits(purpose, labels, kinds, table))


def rule_purpose(labels: Sequence[str], table: RoomTable) -> str:
    """A purpose from the labels' own functions, most specific first, as many as fit in
    RULE_PURPOSE_CHARS ("wash dishes, toast bread, heat food, store food, make coffee")."""
    text = ""
    for function in label_functions(labels, table):
        longer = f"{text}, {function}" if text else function
        if len(longer) > RULE_PURPOSE_CHARS:
            break
        text = longer
    return text


def region_choices(labels: Sequence[str], scene_kinds: Sequence[str], table: RoomTable) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(area names, purposes) a region of these labels may take, best first. A region whose
    labels do not vote (a lone plant) may take any kind ``scene_kinds`` offers (the kinds the
    scene's other regions fit), so it joins one of their areas."""
    kinds = fitting_kinds(labels, table) or tuple(scene_kinds) or tuple(table.kinds)
    functions = label_functions(labels, table)
    first = rule_purpose(labels, table)
    purposes = tuple(dict.fromkeys(p for p in (first, *functions) if p))[:MAX_PURPOSES]
    return kinds, purposes


def area_problems_by_table(
    areas: Sequence[tuple[str, str, Sequence[str]]], labels: Mapping[str, str],
    table: RoomTable | None = None, prompts: PromptLibrary | None = None,
) -> list[str]:
    """Feedback sentences for the areas (name, purpose, objects) whose name or purpose does
    not fit their objects (empty when every judged area fits)."""
    lib = prompts or package_prompts()
    table = table or room_table(lib)
    problems = []
    for name, purpose, objects in areas:
        labs = area_labels(objects, labels)
        fit = judge_area(name, purpose, labs, table)
        shown = ", ".join(objects[:6]) + (", ..." if len(objects) > 6 else "")
        if not fit.name_fits:
            problems.append(lib.render_text(
                "feedback/describer/area_name_misfit.md", name=name.strip(), objects=shown, kinds=" or ".join(fit.fitting[:3]),
            ))
        elif not fit.purpose_fits:
            problems.append(lib.render_text(
                "feedback/describer/area_purpose_misfit.md", name=name.strip(), purpose=purpose.strip(), objects=shown,
                functions=", ".join(label_functions(labs, table)[:3]),
            ))
    return problems


def rule_areas(
    areas: Sequence[tuple[str, str, Sequence[str]]], labels: Mapping[str, str], table: RoomTable
) -> list[tuple[str, str, tuple[str, ...]]]:
    """The areas with every misfit renamed from the table: the best fitting kind and the
    labels' own functions (an area that fits, or that the table cannot judge, is kept)."""
    out = []
    for name, purpose, objects in areas:
        labs = area_labels(objects, labels)
        fit = judge_area(name, purpose, labs, table)
        if not fit.name_fits:
            name, purpose = fit.fitting[0], rule_purpose(labs, table)
        elif not fit.purpose_fits:
            purpose = rule_purpose(labs, table)
        out.append((name, purpose, tuple(objects)))
    return out

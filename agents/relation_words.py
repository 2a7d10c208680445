"""Relations an instruction states in plain English relation words, and what they are about.

"the stool nearest the bar", "the desk farthest from the couch", "sits opposite Goran",
"halfway between the shelf and the sofa": a relation word (:data:`RELATION_WORDS`, general
English: superlatives of distance, near / beside / next to, far / away / distant, facing /
opposite / across / towards, between / halfway / midway) followed, within the same clause, by
what it is measured against: an object label of the scene (read as ``storyteller.agents.shortlist`` reads
labels: synonyms, plurals, a label's head word) or a character's name. ``between`` takes two
such things ("between the bench and the desk", "halfway from the shelf to the sofa").

:func:`stated_relations` returns them in text order; :func:`without_relations` the text with
each relation's words and landmark taken out (what is left says what the place *is*: "a chair",
"a seat at a table"). No word here comes from a benchmark case; the lists are closed classes of
English (prepositions and distance adjectives), not phrases.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

from storyteller.agents.shortlist import mentioned_labels
from storyteller.tools.place_relations import RelationKind

RELATION_WORDS: tuple[tuple[tuple[str, ...], RelationKind], ...] = (
    (("nowhere", "near"), "farthest"), (("not", "near"), "farthest"), (("well", "away"), "farthest"),
    (("nearest",), "nearest"), (("closest",), "nearest"), (("least", "distant"), "nearest"),
    (("shortest", "distance"), "nearest"), (("smallest", "distance"), "nearest"),
    (("farthest", "away"), "farthest"), (("furthest", "away"), "farthest"), (("far", "away"), "farthest"),
    (("farther", "away"), "farthest"), (("further", "away"), "farthest"),
    (("farthest",), "farthest"), (("furthest",), "farthest"), (("most", "distant"), "farthest"),
    (("greatest", "distance"), "farthest"), (("largest", "distance"), "farthest"),
    (("longest", "distance"), "farthest"), (("far",), "farthest"), (("farther",), "farthest"),
    (("distant",), "farthest"), (("away",), "farthest"), (("avoiding",), "farthest"), (("avoids",), "farthest"),
    (("avoid",), "farthest"), (("clear", "of"), "farthest"),
    (("next", "to"), "near"), (("close", "to"), "near"), (("close", "by"), "near"), (("near",), "near"),
    (("nearby",), "near"), (("beside",), "near"), (("by",), "near"), (("adjacent",), "near"),
    (("alongside",), "near"),
    (("facing",), "facing"), (("faces",), "facing"), (("opposite",), "facing"), (("across",), "facing"),
    (("towards",), "facing"), (("toward",), "facing"),
    (("between",), "between"), (("halfway",), "between"), (("midway",), "between"),
    (("to", "the", "left", "of"), "left"), (("to", "the", "right", "of"), "right"),  # "on the left of the couch"
    # is a place on the couch, and "what is left of" no side: only "to the ... of" states one
)
"""Relation words (longest first where they overlap) and the relation each states."""

CLAUSE_ENDS = frozenset({"and", "then", "while", "so", "but", "or", "which", "who", "where", "that", "to", "as"})
"""Words that end a landmark once a thing has been named ("nearest the bar to have a drink")."""
SPAN = 7
"""Words after a relation word that may name its landmark."""
SUBJECT_SPAN = 2
"""Words before a relation word that may name what it describes ("the table beside ...")."""
POINTING_BACK = frozenset({"it"})
"""A landmark word that points back to the thing named before ("furthest from it")."""
PAIR_JOINS = frozenset({"and", "to"})
"""Words joining the two things of ``between`` ("between X and Y", "halfway from X to Y")."""

_TOKEN = re.compile(r"[A-Za-z0-9_']+|[,.;:!?()]")


@dataclass(frozen=True)
class RelationMention:
    """One stated relation: its kind, the things it is measured against (each an object label
    list, all labels the words name there, or ``("@Name",)`` for a character), and the token
    span of its words and landmark."""

    kind: RelationKind
    references: tuple[tuple[str, ...], ...]
    start: int
    end: int
    subject: tuple[str, ...] = ()
    """The labels of the thing the relation describes when the words right before it name one
    ("the table beside the couch": ``("table",)``), or the words between an attributive relation
    word and its landmark ("the most distant desk from the couch": ``("desk",)``); () when they
    do not ("sits beside the couch")."""
    kept: tuple[int, int] = (0, 0)
    """The token span inside ``start:end`` that is not the relation's: the words an attributive
    relation word describes ("desk" in "the most distant desk from the couch")."""


def _tokens(text: str) -> list[str]:
    return _TOKEN.findall(text)


def _match_at(lower: Sequence[str], i: int) -> tuple[int, RelationKind] | None:
    for words, kind in RELATION_WORDS:
        if tuple(lower[i : i + len(words)]) == words:
            return len(words), kind
    return None


def names_a_relation(text: str) -> bool:
    """Whether ``text`` has a relation word ("beside", "in front of", "farthest from" ...)."""
    lower = [t.lower() for t in _tokens(text)]
    return any(_match_at(lower, i) is not None for i in range(len(lower)))


def before_relations(text: str) -> str:
    """The words of ``text`` before its first relation word ("picks the place furthest from the
    coffee machine" -> "picks the place"): what is done, without where it is measured from."""
    tokens = _tokens(text)
    lower = [t.lower() for t in tokens]
    cut = next((i for i in range(len(tokens)) if _match_at(lower, i) is not None), len(tokens))
    return " ".join(tokens[:cut])


def _name(token: str) -> str:
    """A token without its possessive ending ("Mia's" -> "Mia")."""
    return token.removesuffix("'s").removesuffix("'")


def _first_thing(tokens: Sequence[str], labels: Sequence[str], names: Sequence[str]) -> tuple[tuple[str, ...], int] | None:
    """The first thing ``tokens`` name (a character, or the labels of the first object words)
    and the index just after it; None when they name nothing."""
    for k in range(len(tokens)):
        word = _name(tokens[k])
        if word in names:
            return (f"@{word}",), k + 1
        found = mentioned_labels(" ".join(tokens[: k + 1]), labels)
        if found:
            parts = {part for label in found for part in label.split("_")}
            end = k + 1
            while end < len(tokens) and tokens[end].lower() in parts:  # the rest of "bar counter"
                end += 1
            return tuple(found), end
    return None


LEADS = frozenset({"the", "a", "an", "from", "to", "of", "his", "her", "their", "its", "my", "your", "our", "this", "that"})
"""Words that open a landmark right after a relation word ("nearest the bar", "far from the
door"); any other word there is what the relation describes ("the most distant desk", "the
nearest chair to the door"): its landmark, if any, follows "to" or "from"."""
LANDMARK_OPENERS = frozenset({"to", "from"})


def joined_labels(text: str, labels: Sequence[str]) -> str:
    """``text`` as tokens (words and punctuation, space-separated), a several-word label written
    as one word read as its words ("whiteboard" for the label ``white_board``)."""
    joined = {"".join(parts): " ".join(parts) for parts in (label.split("_") for label in labels) if len(parts) > 1}
    return " ".join(joined.get(t.lower(), t) for t in _tokens(text))


def stated_relations(text: str, labels: Sequence[str], names: Sequence[str] = ()) -> list[RelationMention]:
    """The relations ``text`` states (see the module docstring), in text order; ``labels``: the
    scene's object labels, ``names``: the characters'. Several-word labels written as one word
    are read first (:func:`joined_labels`); token positions refer to the text as read."""
    tokens = _tokens(joined_labels(text, labels))
    lower = [t.lower() for t in tokens]
    out: list[RelationMention] = []
    i = 0
    while i < len(tokens):
        hit = _match_at(lower, i)
        if hit is None:
            i += 1
            continue
        width, kind = hit
        start, j = i, i + width
        described = (j, j)
        if (j < len(tokens) and tokens[j][0].isalnum() and lower[j] not in LEADS and lower[j] not in POINTING_BACK
                and _name(tokens[j]) not in names):
            # attributive ("the most distant desk"): the landmark, if any, comes after to / from
            k = j
            while k < len(tokens) and k < j + SPAN and tokens[k][0].isalnum() and lower[k] not in LANDMARK_OPENERS:
                k += 1
            if k >= len(tokens) or lower[k] not in LANDMARK_OPENERS:
                i += width
                continue
            described = (j, k)
            j = k
        span_start = j
        span: list[str] = []
        while j < len(tokens) and len(span) < SPAN * (2 if kind == "between" else 1):
            if not tokens[j][0].isalnum():
                break
            if span and lower[j] in CLAUSE_ENDS and not (kind == "between" and lower[j] in PAIR_JOINS):
                break
            span.append(tokens[j])
            j += 1
        refs: list[tuple[str, ...]] = []
        rest = span
        lead = next((k for k, t in enumerate(span) if t.lower() not in LEADS), len(span))
        if lead < len(span) and span[lead].lower() in POINTING_BACK and kind != "between":
            # "the table furthest from it": the thing named last before the relation word
            described_here = set(mentioned_labels(" ".join(tokens[max(0, start - SUBJECT_SPAN):start]), labels))
            named = [n for n in mentioned_labels(" ".join(tokens[:start]), labels) if n not in described_here]
            if named:
                refs.append((named[-1],))
                rest = span[lead + 1:]
        while rest and len(refs) < (2 if kind == "between" else 1):
            found = _first_thing(rest, labels, names)
            if found is None:
                break
            refs.append(found[0])
            rest = rest[found[1]:]
            if kind == "facing" and len(rest) > 1 and rest[0].lower() == "from" and (
                beyond := _first_thing(rest[1:], labels, names)
            ):  # "across the table from Mia": the table lies between, Mia is what is faced
                refs[-1] = beyond[0]
                rest = rest[1 + beyond[1]:]
        if refs:
            before: list[str] = []  # the words of the same clause right before the relation word
            for k in range(start - 1, max(-1, start - 1 - SUBJECT_SPAN), -1):
                if not tokens[k][0].isalnum():
                    break
                before.insert(0, tokens[k])
            subject = tuple(mentioned_labels(" ".join(before[-2:]), labels)) if before else ()
            if not subject and described[1] > described[0]:
                subject = tuple(mentioned_labels(" ".join(tokens[described[0]:described[1]]), labels))
            out.append(RelationMention(kind, tuple(refs), start, span_start + len(span) - len(rest), subject,
                                       kept=described))
            i = out[-1].end
        else:
            i += width
    return out


def without_relations(text: str, relations: Sequence[RelationMention], labels: Sequence[str] = ()) -> str:
    """``text`` with each relation's words and landmark removed (``labels``: as given to
    :func:`stated_relations`)."""
    tokens = _tokens(joined_labels(text, labels))
    cut = {k for r in relations for k in range(r.start, r.end) if not r.kept[0] <= k < r.kept[1]}
    return " ".join(t for k, t in enumerate(tokens) if k not in cut)


BACK_REFERENCES = frozenset({"there"})
"""Place words that point back to the last thing named before them ("Jalen sits at a table; Aino
comes over and sits down there too"), a closed class of English deixis."""
EXISTENTIAL = frozenset({"is", "are", "was", "were", "be", "'s"})
"""Words after "there" that make it existential ("there is a free chair"), not a place."""
SAME_OPENERS = frozenset({"the", "that", "this"})
"""Words before "same" that make it point back ("at that same table", "the same sofa")."""
POINTING_DETERMINERS = frozenset({"that", "this", "their"})
"""Determiners that point back when a thing of the scene follows ("at that table", "their table")."""


def _pointer(lower: Sequence[str], labels: Sequence[str]) -> int | None:
    """Where the first word that points back is (see :func:`back_references`), or None."""
    for i, t in enumerate(lower):
        if t in BACK_REFERENCES and (i + 1 >= len(lower) or lower[i + 1] not in EXISTENTIAL):
            return i
        if t == "same" and i > 0 and lower[i - 1] in SAME_OPENERS:
            return i
        if t in POINTING_DETERMINERS and i + 1 < len(lower) and mentioned_labels(lower[i + 1], labels):
            return i
    return None


def points_back(text: str, labels: Sequence[str] = ()) -> bool:
    """Whether ``text`` has a word that points back (see :func:`back_references`)."""
    return _pointer([t.lower() for t in _tokens(joined_labels(text, labels))], labels) is not None


def _last_clause(words: list[str]) -> list[str]:
    while words and not words[-1][0].isalnum():
        words.pop()
    cut = max((k for k, w in enumerate(words) if w in CLAUSE_MARKS), default=-1)
    return words[cut + 1:]


def back_references(text: str, before: str, labels: Sequence[str], names: Sequence[str] = ()) -> list[RelationMention]:
    """``near`` relations for a word of ``text`` that points back: the place word "there" (not
    existential), "the / that / this same ...", or "that / this / their" before a thing of the
    scene ("at that same table", "at their table"). What it points to: the characters of ``names``
    that ``text`` names before it ("Seeing Kim and Lu at a table, Mo sits at that same table":
    near Kim and near Lu, whose table it is), else those the clause ``before`` ends with (the
    instruction's words before ``text``: "Kim is sitting at a table; Mo sits down there too"),
    else the last object label that clause names. [] when ``text`` has no such word or nothing is
    named. The span is the pointing word's own (``text`` as read by :func:`stated_relations`)."""
    tokens = _tokens(joined_labels(text, labels))
    at = _pointer([t.lower() for t in tokens], labels)
    if at is None:
        return []
    before_clause = _last_clause(_tokens(joined_labels(before, labels)))
    for clause in (tokens[:at], before_clause):
        named = list(dict.fromkeys(w.removesuffix("'s") for w in clause if w.removesuffix("'s") in names))
        if named:
            return [RelationMention("near", ((f"@{name}",),), at, at + 1) for name in named]
    things = mentioned_labels(" ".join(before_clause), labels)
    return [RelationMention("near", ((things[-1],),), at, at + 1)] if things else []


CLAUSE_MARKS = frozenset({".", ";", "!", "?"})
"""Marks that end the clause a back reference may point to."""


def labels_about(text: str, labels: Sequence[str], names: Sequence[str] = ()) -> list[str]:
    """The object labels ``text`` is about: those it names once each stated relation's words and
    landmark are taken out ("the chair farthest from the lamp": the chair, not the lamp), in order
    of mention."""
    return mentioned_labels(without_relations(text, stated_relations(text, labels, names), labels), labels)

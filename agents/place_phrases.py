"""Ways English names a side of a thing, written in the one form the word readers know.

People say where someone stands in many ways: "on the bench's right-hand side", "on its left",
"at the cabinet's back", "right next to the fridge" ("right" there means "just", not a side).
The readers of an event's words (:mod:`storyteller.agents.shortlist`, :mod:`storyteller.agents.action_shortlist`,
:mod:`storyteller.agents.relation_words`) know "to the left of X", "in front of X", "behind X" and
"beside X". :func:`plain_places` rewrites the other forms into those:

- a possessive side, ``[at|on|by...] X's [own] left|right[-hand] [side]`` / ``front`` /
  ``back`` / ``rear`` / ``side``, becomes ``to the left of X`` / ``in front of X`` / ``behind
  X`` / ``beside X`` (so X reads as a landmark, not as the place itself: waiting "on the bench's
  right-hand side" is not sitting on the bench); X is a thing ("the wine rack") or a person's
  name ("takes the seat at Agnes's side" is the seat beside Agnes);
- ``its [own] left|right[-hand] [side]`` becomes ``to the left of it``; ``at the back of X``
  (``rear``) becomes ``behind X``, ``at the front of X`` ``in front of X``;
- a remark in parentheses is left out (a gloss restating the place another way);
- "right" as an intensifier ("right next to", "right behind") is left out;
- left and right are the thing's own (the spatial API's areas are); when the words say they are
  judged by someone facing the thing ("seen from the front", "for someone facing it"), they
  are swapped;
- a point partway along a way, ``from X to Y`` with a midpoint word in the sentence
  ("halfway", "midway", "in the middle", "the midpoint"), becomes ``between X and Y`` (a
  place between two things, to stand: not a trip to Y, nor a seat on it).

Closed classes of English (possessives, side nouns, prepositions); no phrase from a case.
Pure: no LLM, no I/O.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_SIDE_FORMS = {
    "left": "to the left of", "right": "to the right of", "front": "in front of",
    "back": "behind", "rear": "behind", "side": "beside",
}
_DETERMINERS = frozenset({"the", "a", "an", "this", "that"})
SIDE_PREPOSITIONS = frozenset({"at", "on", "by", "to", "in", "of", "with", "from", "for", "near"})
"""Prepositions: never inside a thing's words, and the one right before a possessive side ("at
Agnes's side", "on the bench's left") is part of the side phrase the rewrite replaces."""
_EMPHASIS = frozenset({"own", "very"})
THING_WORDS = 3
"""Words a possessive's thing may have after its determiner ("the wine rack's")."""
INTENSIFIED = frozenset({
    "next", "beside", "behind", "by", "in", "across", "outside", "inside", "under", "over", "above", "below",
    "beneath", "against", "at", "on", "there", "here", "near", "alongside", "opposite", "between", "where", "up",
})
"""Words after which "right" means "just" ("right next to")."""
SIDE_OWNERS = frozenset({"the", "its", "his", "her", "their", "own", "far", "my", "your", "our"})
"""Words before "right" that make it a side ("the right", "his right")."""
VIEWER_FRAME = (
    "for someone facing", "for somebody facing", "for anyone facing", "for a person facing", "for one facing",
    "for someone looking at", "for anyone looking at", "for a viewer", "to someone facing", "to anyone facing",
    "seen from the front", "seen from in front", "viewed from the front", "judged from the front",
    "looking from the front", "as you face", "as one faces", "from the viewer",
)
"""Words that say left and right are judged by someone facing the thing."""
_TOKEN = re.compile(r"[A-Za-z0-9_]+|[^\sA-Za-z0-9_]")


@dataclass(frozen=True)
class _Token:
    text: str
    start: int
    end: int

    @property
    def low(self) -> str:
        return self.text.lower()


def _tokens(text: str) -> list[_Token]:
    return [_Token(m.group(), m.start(), m.end()) for m in _TOKEN.finditer(text)]


def _side_end(tokens: list[_Token], k: int) -> tuple[str, int] | None:
    """The side named from token ``k`` on ([own] left|right|front|back|rear|side [hand] [side]
    [of it]) and the index after it; None when there is none."""
    while k < len(tokens) and tokens[k].low in _EMPHASIS:
        k += 1
    if k >= len(tokens) or tokens[k].low not in _SIDE_FORMS:
        return None
    side, k = tokens[k].low, k + 1
    if k + 1 < len(tokens) and tokens[k].text == "-" and tokens[k + 1].low == "hand":
        k += 2
    elif k < len(tokens) and tokens[k].low == "hand":
        k += 1
    if k < len(tokens) and tokens[k].low == "side" and side != "side":
        k += 1
    if k + 1 < len(tokens) and tokens[k].low == "of" and tokens[k + 1].low == "it":
        k += 2
    return side, k


def _owner(tokens: list[_Token], j: int) -> tuple[int, str] | None:
    """The owner of the possessive whose apostrophe is token ``j``: the index its words start at
    and its words as the side form names it ("the wine rack", or a name: "Agnes"). A thing's words
    run from a determiner and hold no preposition ("the seat at Agnes's" is no thing: Agnes is
    the owner); a name is one capitalised word. None when there is neither."""
    det = next((d for d in range(j - 1, max(-1, j - 2 - THING_WORDS), -1) if tokens[d].low in _DETERMINERS), None)
    if det is not None and det < j - 1 and not any(tokens[k].low in SIDE_PREPOSITIONS for k in range(det + 1, j)):
        return det, " ".join(t.text for t in tokens[det:j])
    name = tokens[j - 1]
    if name.text[:1].isupper() and name.text.isalpha() and name.low not in _DETERMINERS:
        return j - 1, name.text
    return None


def _rewrite_sides(text: str) -> str:
    tokens = _tokens(text)
    edits: list[tuple[int, int, str]] = []  # (start, end, replacement) in text
    for j in range(len(tokens) - 1):
        if tokens[j].text == "'" and tokens[j + 1].low == "s" and j > 0:  # a possessive: "the bench's"
            found = _side_end(tokens, j + 2)
            owner = _owner(tokens, j) if found is not None else None
            if found is None or owner is None:
                continue
            start = owner[0] - 1 if owner[0] > 0 and tokens[owner[0] - 1].low in SIDE_PREPOSITIONS else owner[0]
            edits.append((tokens[start].start, tokens[found[1] - 1].end, f"{_SIDE_FORMS[found[0]]} {owner[1]}"))
        elif tokens[j].low == "its" and (found := _side_end(tokens, j + 1)) is not None:
            edits.append((tokens[j].start, tokens[found[1] - 1].end, f"{_SIDE_FORMS[found[0]]} it"))
    return _apply(text, edits)


def _apply(text: str, edits: list[tuple[int, int, str]]) -> str:
    out, at = [], 0
    for start, end, new in sorted(edits):
        if start < at:
            continue
        out += [text[at:start], new]
        at = end
    return "".join([*out, text[at:]])


def _without_parentheses(text: str) -> str:
    out, depth = [], 0
    for ch in text:
        depth += ch == "("
        if depth == 0:
            out.append(ch)
        depth -= ch == ")" and depth > 0
    return " ".join("".join(out).split()).replace(" .", ".").replace(" ,", ",")


def _without_intensifier(text: str) -> str:
    tokens = _tokens(text)
    edits = [
        (t.start, tokens[i + 1].start, "")
        for i, t in enumerate(tokens[:-1])
        if t.low == "right" and tokens[i + 1].low in INTENSIFIED and (i == 0 or tokens[i - 1].low not in SIDE_OWNERS)
    ]
    return _apply(text, edits)


def _swap_sides(text: str) -> str:
    tokens = _tokens(text)
    return _apply(text, [(t.start, t.end, "right" if t.low == "left" else "left")
                         for t in tokens if t.low in ("left", "right")])


MIDPOINT_WORDS = frozenset({"halfway", "midway", "middle", "midpoint", "centre", "center", "mid"})
"""Words that put a place partway along a way ("halfway from the door to the window")."""
WAY_END_WORDS = 4
"""Words the far end of a way may have ("the big green sofa")."""
_CLAUSE_WORDS = frozenset({"and", "then", "where", "while", "before", "after", "so", "until", "when", "for", "to"})


def _midpoints(text: str) -> str:
    tokens = _tokens(text)
    if not any(t.low in MIDPOINT_WORDS or (t.low == "half" and i + 1 < len(tokens) and tokens[i + 1].low == "way")
               for i, t in enumerate(tokens)):
        return text
    edits: list[tuple[int, int, str]] = []
    for i, t in enumerate(tokens):
        if t.low != "from":
            continue
        to = next((k for k in range(i + 2, min(len(tokens), i + 2 + WAY_END_WORDS)) if tokens[k].low == "to"), None)
        if to is None or any(not tokens[k].text.isalnum() and tokens[k].text != "_" for k in range(i + 1, to)):
            continue
        end = to + 1
        while end < len(tokens) and end - to <= WAY_END_WORDS and (tokens[end].text.replace("_", "").isalnum()) \
                and tokens[end].low not in _CLAUSE_WORDS:
            end += 1
        if end == to + 1:
            continue
        near, far = text[tokens[i + 1].start : tokens[to - 1].end], text[tokens[to + 1].start : tokens[end - 1].end]
        edits.append((t.start, tokens[end - 1].end, f"between {near} and {far}"))
    return _apply(text, edits)


_SIDE_OF = re.compile(
    r"\b(?:at|to|round|around|by) the (back|rear|front) of\b"
    r"(?! (?:the |this |that )?(?:room|kitchen|office|restaurant|house|hall|lounge|cafe|building|area|space|corner|queue|line)\b)",
    re.IGNORECASE,
)
"""A side of a thing ("at the back of the settee"), not the back of a room or a queue."""


def _sides_of(text: str) -> str:
    """"at the back of the settee" is behind it, "at the front of the stage" in front of it."""
    return _SIDE_OF.sub(lambda m: "in front of" if m.group(1).lower() == "front" else "behind", text)


def plain_places(text: str) -> str:
    """``text`` with the place phrases of the module docstring rewritten (names keep their case)."""
    out = _sides_of(_without_intensifier(_without_parentheses(text.replace("\u2019", "'"))))
    if any(phrase in " ".join(t.low for t in _tokens(out)) for phrase in VIEWER_FRAME):
        out = _swap_sides(out)
    return _midpoints(_rewrite_sides(out))

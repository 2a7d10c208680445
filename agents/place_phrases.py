"""Ways English names a side of a thing, written in the one form the word readers know.

People say where someone stands in many ways: "on the bench's right-hand side", "on its left",
"at the cabinet's back", "right next to the fridge" ("right" there means "just", not a side).
The readers of an event's words (:mod:`agents.shortlist`, :mod:`agents.action_shortlist`,
:mod:`agents.relation_words`) know "to the left of X", "in front of X", "behind X" and
"beside X". :func:`plain_places` rewrites the other forms into those:

- a possessive side, ``X's [own] left|right[-hand] [side]`` / ``front`` / ``back`` /
  ``rear`` / ``side``, becomes ``to the left of X`` / ``in front of X`` / ``behind X`` /
  ``beside X`` (so X reads as a landmark, not as the place itself: waiting "on the bench's
  right-hand side" is not sitting on the bench);
- ``its [own] left|right[-hand] [side]`` becomes ``to the left of it``;
- a remark in parentheses is left out (a gloss restating the place another way);
- "right" as an intensifier ("right next to", "right behind") is left out;
- left and right are the thing's own (the spatial API's areas are); when the words say they are
  judged by someone facing the thing ("seen from the front", "for someone facing it"), they
  are swapped.

Closed classes of English (possessives, side nouns, prepositions); no phrase from a case.
Pure: no LLM, no I/O.
"""

from __future__ import annotations

import re

_SIDE_FORMS = {
    "left": "to the left of", "right": "to the right of", "front": "in front of",
    "back": "behind", "rear": "behind", "side": "beside",
}
_SIDE = r"(?P<side>left|right|front|back|rear|side)(?:\s*-?\s*hand)?(?:\s+side)?(?:\s+of\s+it)?"
_NOUN = r"(?P<thing>(?:[a-z0-9]+\s+){0,2}?[a-z0-9]+)"
POSSESSIVE_SIDE = re.compile(rf"\b(?P<det>the|a|an|this|that)\s+{_NOUN}'s\s+(?:own\s+|very\s+)?{_SIDE}\b", re.IGNORECASE)
"""``the wine rack's own right-hand side``: a side of a thing named by a possessive."""
PRONOUN_SIDE = re.compile(rf"\bits\s+(?:own\s+|very\s+)?{_SIDE}\b", re.IGNORECASE)
"""``its left``: a side of the thing the sentence is about."""
PARENTHESES = re.compile(r"\s*\([^()]*\)")
INTENSIFIER = re.compile(
    r"(?P<before>\b[a-z']+\s+)?\bright\s+"
    r"(?=(?:next|beside|behind|by|in|across|outside|inside|under|over|above|below|beneath|against|at|on|"
    r"there|here|near|alongside|opposite|between|where|up|beneath)\b)",
    re.IGNORECASE,
)
"""``right next to``: "right" meaning "just", not the side (unless a word before makes it a
side: ``the right``, ``his right``)."""
SIDE_OWNERS = frozenset({"the", "its", "his", "her", "their", "own", "far", "my", "your", "our"})
VIEWER_FRAME = re.compile(
    r"\b(?:for|to|by)\s+(?:someone|somebody|anyone|a\s+person|one|you|people|a\s+viewer|an\s+onlooker)\s+"
    r"(?:who\s+is\s+|who's\s+)?(?:facing|looking\s+at|standing\s+in\s+front\s+of)\b"
    r"|\b(?:seen|viewed|looking|judged)\s+from\s+(?:the\s+|its\s+)?front\b"
    r"|\bas\s+(?:you|one)\s+face\b|\bfrom\s+the\s+viewer'?s\b",
    re.IGNORECASE,
)
"""Words that say left and right are judged by someone facing the thing."""


def _possessive(match: re.Match[str]) -> str:
    return f"{_SIDE_FORMS[match['side'].lower()]} {match['det']} {match['thing']}"


def _without_intensifier(match: re.Match[str]) -> str:
    before = match["before"] or ""
    return match[0] if before.strip().lower() in SIDE_OWNERS else before


def _swap_sides(text: str) -> str:
    return re.sub(r"\b(left|right)\b", lambda m: "right" if m.group(1).lower() == "left" else "left", text,
                  flags=re.IGNORECASE)


def plain_places(text: str) -> str:
    """``text`` with the side phrases of the module docstring rewritten (names keep their case)."""
    out = PARENTHESES.sub("", text.replace("\u2019", "'"))
    out = INTENSIFIER.sub(_without_intensifier, out)
    if VIEWER_FRAME.search(out):
        out = _swap_sides(out)
    out = POSSESSIVE_SIDE.sub(_possessive, out)
    return PRONOUN_SIDE.sub(lambda m: f"{_SIDE_FORMS[m['side'].lower()]} it", out)

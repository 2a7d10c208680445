"""Where a part of the instruction is in the instruction's own words, and the words around it.

A part's text may differ from what the user wrote: the splitter adds "Then", writes a name for
a pronoun ("She then sits." -> "Then Ava sits.") and makes a relative clause a sentence ("Ben,
who waits on the bench" -> "Ben waits on the bench.", :mod:`storyteller.agents.instruction_subjects`).
:func:`part_span` finds the part as written, else its words after the names that open it.
"""

from __future__ import annotations

import re

WORDS_SO_FAR_CHARS = 400
"""At most this many characters of the instruction up to the part are quoted in the prompt."""


_LEADING_NAMES = re.compile(r"^[A-Z][a-z]*+(?:(?:,\s*+|\s++and\s++)[A-Z][a-z]*+)*+\s++")


def part_span(instruction: str, part: str) -> tuple[int, int] | None:
    """Where ``part`` (its words, without a leading "Then" the part split may have added) is in
    ``instruction``: (start, end), else where its words after the names that open it are
    ("Then Ava sits down." in "She then sits down."); None when neither is found."""
    core = re.sub(r"^then,?\s+", "", part.strip(), flags=re.IGNORECASE).rstrip(".!?; ")
    at = instruction.lower().find(core.lower()) if core else -1
    if at < 0:  # a name written for a pronoun, or a relative clause made a sentence: the words after the names
        names = _LEADING_NAMES.match(core)
        core = core[names.end() :] if names else ""
        at = instruction.lower().find(core.lower()) if len(core.split()) >= 2 else -1
    return None if at < 0 else (at, at + len(core))


def words_so_far(instruction: str, part: str) -> str:
    """The instruction up to the end of ``part`` (its last :data:`WORDS_SO_FAR_CHARS` characters),
    so words that point back ("Jalen sits at a table; Aino comes over and sits down there too")
    keep what they point to; ``part`` alone when it is not found in the instruction as written."""
    span = part_span(instruction, part)
    if span is None:
        return part
    so_far = instruction[: span[1]].strip()
    if len(so_far) > WORDS_SO_FAR_CHARS:
        so_far = so_far[-WORDS_SO_FAR_CHARS:].split(" ", 1)[-1]
    return so_far + instruction[span[1] : span[1] + 1].strip(" ")


def words_before(instruction: str, part: str) -> str:
    """The instruction's words before ``part`` ("" when it is not found as written)."""
    span = part_span(instruction, part)
    return "" if span is None else instruction[: span[0]][-WORDS_SO_FAR_CHARS:]

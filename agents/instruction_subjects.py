"""Who a sentence of the instruction is about when it does not open with a name.

Two everyday ways of writing hide the actor of a step from the part splitter
(:mod:`storyteller.agents.instruction_parts`), which takes a part's actors from the names that
open it:

- a sentence that opens with a pronoun ("Ava makes coffee. She then sits on the couch.",
  "After that, they sit at the table.", "Afterwards the two of them talk"): the part named
  nobody, so any free character could be given it. :func:`with_named_subject` writes the
  actors of the part before in place of the pronoun ("Then Ava sits on the couch.") when the
  number agrees (*she* / *he*: its one actor; *they*, *the two of them*, *both of them*: the
  two or more characters it names);
- a relative clause about someone the sentence acts on ("Ava brings a coffee to Ben, who
  waits on the bench with his phone"): what Ben does was no part of anyone's.
  :func:`relative_clause_parts` makes it Ben's own sentence ("Ben waits on the bench with his
  phone."), said before the rest, and takes it out of the sentence it was in. Only a clause
  that says what the person does or where they sit or stand (:func:`activity_kind`,
  :func:`posture`) becomes a part: "Ben, who is tired" says who Ben is, not what he does, and
  a clause about the sentence's own subject ("Cleo, who waits tables here, jots down ...")
  stays where it is, and so does one about what someone is already doing ("Gus, who is
  still eating").

Both are plain text processing of the user's words; the patterns are linear (no nested
repeats), as ``tests/test_regex_linear.py`` requires of patterns run on the user's text.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from storyteller.agents.action_shortlist import posture
from storyteller.agents.step_words import activity_kind

_LEAD = re.compile(
    r"(?:(then|after that|after this|afterwards|afterward|later on|later|next|eventually|finally)\b\s*+,?\s*+)?"
    r"(she|he|they|the two of them|both of them|the pair|the two)(\s++then\b)?\s++(?=[a-z])",
    re.IGNORECASE,
)
_PLURAL_ONLY = frozenset({"the two of them", "both of them", "the pair", "the two"})
_ONGOING = frozenset({"already", "still"})
"""Words of a clause that says what someone is in the middle of ("Gus, who is already eating"):
the scene's state, not a step to plan."""
_JOINING = frozenset({"and", "then", "but", "while", "before", "after", "so", "as", "until"})


def names_text(names: Sequence[str]) -> str:
    """"Ava", "Ava and Ben", "Ava, Ben and Cleo"."""
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"


def with_named_subject(clause: str, actors: Sequence[str], mentioned: Sequence[str], then: str) -> str:
    """``clause`` with a leading pronoun (after an optional "then" / "after that" / ...) replaced
    by the names of the part before when its number agrees: *she* / *he* its one actor, a plural
    the two or more characters it mentions ("Ava joins Ben. Then they chat.": Ava and Ben; after
    "Cy asks what they fancy." it may be the guests: left alone). A clause that said "then" or "after that" reads ``then`` (the prompts' "Then
    {part}" template, with ``\\0`` for the part). Unchanged when nothing matches."""
    m = _LEAD.match(clause)
    if m is None or not actors:
        return clause
    pronoun = " ".join(m.group(2).lower().split())
    before = actors if pronoun in ("she", "he") else mentioned
    if len(before) != 1 if pronoun in ("she", "he") else len(before) < 2:  # "they" after one name: unsure
        return clause
    rest = f"{names_text(before)} {clause[m.end():]}"
    return then.replace("\0", rest) if m.group(1) or m.group(3) else rest


def clause_pattern(names: Sequence[str]) -> re.Pattern[str] | None:
    """"<name>, who <clause>" up to the next punctuation (None: no names)."""
    if not names:
        return None
    run = "|".join(re.escape(n) for n in sorted(names, key=len, reverse=True))
    return re.compile(rf"(?<![A-Za-z])({run}),\s*+who\s++([^,.;!?]+)([,.;!?]|$)")


def relative_clause_parts(clause: str, names: Sequence[str], subject: Sequence[str]) -> tuple[list[str], str]:
    """The sentences a relative clause about a character other than the ``subject`` (the names
    that open ``clause``) says that character does, and ``clause`` without those clauses."""
    pattern = clause_pattern(names)
    if pattern is None:
        return [], clause
    own: list[str] = []
    kept: list[str] = []
    start = 0
    for m in pattern.finditer(clause):
        name, body, end = m.group(1), m.group(2).strip(), m.group(3)
        words = body.lower().split()[:3]
        if (name in subject or words[:1] == ["then"] or _ONGOING & set(words)
                or not (activity_kind(body) or posture(body))):
            continue
        own.append(f"{name} {body}.")
        kept.append(clause[start : m.end(1)])
        start = m.end()
        if end == ",":  # "..., who waits, and then sits": the comma stays before a joining word
            after = clause[m.end() :].split(maxsplit=1)
            kept.append("," if after and after[0].lower() in _JOINING else "")
        elif end:
            kept.append(end)
    if not own:
        return [], clause
    kept.append(clause[start:])
    return own, "".join(kept)

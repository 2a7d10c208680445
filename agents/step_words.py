"""Which clauses of an instruction are steps of their own, from their words.

An instruction is cut into parts (:mod:`storyteller.agents.instruction_parts`): one part per step a
character takes. Some clauses are no step: going somewhere is the way to what is done there
("Rosa goes over to the corner and sits down there to read"), a clause that says how something
is gives the reason for the next step ("Femi's bottle is empty, and it gets refilled"), and a
phrase with no verb sets the scene ("Quinn, free for a moment. Switches the TV on."). The
readers here say so; the splitter keeps such a clause with the step it belongs to.

Every function takes the clause's text and its leading subject (the run of character names
that opens it, "" when none: the caller knows the names). Word lists are closed classes of
general English (verbs of going, forms of *be*, degree adverbs), no phrase of a case. Pure:
no LLM, no I/O, no regular expression that backtracks.
"""

from __future__ import annotations

import functools
import re

from storyteller.agents.action_shortlist import CUES, posture, rank_action_labels
from storyteller.agents.english_words import may_be_verb
from storyteller.agents.relation_words import before_relations

_WORD = re.compile(r"[A-Za-z]+")

MOTION_VERBS = frozenset(str.split(
    "go goes walk walks head heads come comes wander wanders stroll strolls move moves hurry hurries "
    "rush rushes step steps return returns cross crosses pop pops nip nips amble ambles saunter saunters "
    "drift drifts stride strides dash dashes"
))
"""Verbs of going somewhere."""
_TOWARDS = frozenset(str.split("to into towards toward over across up down back along around round off out in"))
_SKIPPED_BEFORE_VERB = frozenset(str.split("then first just now quickly slowly soon also he she they"))
STATE_VERBS = frozenset(str.split("is are was were seem seems feel feels look looks remain remains stay stays"))
"""Verbs that say how something is."""
_DEGREE = frozenset(str.split("still now already quite very rather too not so a bit little"))
_NOT_VERBS_IN_S = frozenset(str.split(
    "is was has his hers its this as us yes less unless plus always perhaps afterwards towards upstairs downstairs "
    "sometimes besides news series glass class dress chess bus"
))
"""Words ending in -s that are no verb of an action (closed-class words and a few nouns)."""


@functools.lru_cache(maxsize=1024)
def activity_kind(text: str) -> str | None:
    """The action label the words of ``text`` point to most among every label the action
    vocabulary knows (:data:`storyteller.agents.action_shortlist.CUES`: "munch a sandwich by table_2" and
    "tucks into her lunch" are both ``eat``), or None when they point to none."""
    ranked = rank_action_labels(text, tuple(CUES))
    return ranked[0].label if ranked else None


def _words(text: str) -> list[str]:
    return [w.lower() for w in _WORD.findall(text)]


def moves_only(text: str, subject: str = "") -> bool:
    """Whether ``text`` only takes its subject somewhere ("Rosa goes over to the corner", "he
    makes his way to the bar"): its verb is a verb of going and a word of direction follows
    ("goes through his emails" is no going)."""
    words = _words(text[len(subject):])
    while words and (words[0] in _SKIPPED_BEFORE_VERB or words[0].endswith("ly")):
        words = words[1:]
    if len(words) >= 3 and words[0] in ("make", "makes") and words[2] == "way":
        return True
    return len(words) >= 2 and words[0] in MOTION_VERBS and words[1] in _TOWARDS


def has_verb(text: str, subject: str = "", names: frozenset[str] = frozenset()) -> bool:
    """Whether ``text`` after its subject has a word that may be a verb: the word right after a
    named subject ("Ava and Ben cook"; "Quinn, free ..." has none), or one ending in -s or -ed
    (a plural noun counts too, which only keeps a clause as it is). ``names``: lower-case
    character names, never verbs."""
    rest = text[len(subject):]
    if subject and rest[:1].isspace() and rest.lstrip()[:1].islower():
        return True
    return any(w not in names and w not in _NOT_VERBS_IN_S and len(w) > 2 and w.endswith(("s", "ed"))
               for w in _words(rest))


def states_only(text: str, subject: str = "", names: frozenset[str] = frozenset()) -> bool:
    """Whether ``text`` only says how something is ("Femi's bottle is empty", "Ava is hungry",
    "the TV is still on"): a form of *be* (or *seem*, *feel*, *look*, *remain*, *stay*), then a
    word that is no *-ing* form, no verb before it ("Chidi waits on the side that is ..." acts)
    and no action the words after it point to."""
    tokens = [(m.group().lower(), m.start(), m.end()) for m in _WORD.finditer(text)]
    for i, (word, start, _) in enumerate(tokens):
        if word not in STATE_VERBS:
            continue
        k = i + 1
        while k < len(tokens) and tokens[k][0] in _DEGREE:
            k += 1
        if k >= len(tokens) or tokens[k][0].endswith("ing"):
            return False
        before = text[:start]
        return (not has_verb(before, subject if before.startswith(subject) else "", names)
                and activity_kind(before_relations(text[tokens[k][2]:])) is None)
    return False


INTENT_VERBS = frozenset(str.split(
    "want wants wanted wish wishes fancy fancies need needs hope hopes plan plans decide decides intend intends"
))
"""Verbs of wanting or meaning to do something."""


def intends_only(text: str, subject: str = "") -> bool:
    """Whether ``text`` says what its subject wants or means to do ("Noor wants to read a
    book", "he decides he needs a coffee"): its verb is one of wanting. The sentence after it
    ("She takes the chair furthest from the fridge.") is where and how it is done."""
    words = _words(text[len(subject):])
    while words and (words[0] in _SKIPPED_BEFORE_VERB or words[0].endswith("ly")):
        words = words[1:]
    return bool(words) and (words[0] in INTENT_VERBS or words[:2] == ["would", "like"])


def no_action(text: str, subject: str = "", names: frozenset[str] = frozenset()) -> bool:
    """Whether a clause states no step of its own: it only says how something is
    (:func:`states_only`), or it has no verb and its words point to no action, no posture and
    no going somewhere ("Quinn, free for a moment.")."""
    return states_only(text, subject, names) or (
        activity_kind(before_relations(text)) is None and posture(text) is None
        and not moves_only(text, subject) and not has_verb(text, subject, names))


AND_WORD = re.compile(r",?(?<!\s)\s+and\s+(?=([a-z]+)\b)")
"""An "and" between words, with the word after it (a second verb or not)."""
NOT_A_VERB = frozenset(str.split(
    "a an the this that these those some any all both each every no his her their its my your our "
    "one two three four five then also so later afterwards after before with without in on at by to "
    "from into onto near it them him me us"
))
"""Closed-class words that, right after "and", show it joins things, not a second verb ("a soda
and some chips", "and then" is "then"'s)."""


_COMMA_WORD = re.compile(r",\s*(?=([a-z]+)\b)")


def _verb_like(word: str) -> bool:
    """Whether ``word`` may be a verb of the third person opening an item of a list of steps
    ("curls", "turns"; not "bananas"): it ends in -s, is no closed-class word, and the lexicon
    knows it as a verb (:func:`storyteller.agents.english_words.may_be_verb`)."""
    return (len(word) > 2 and word.endswith("s") and word not in NOT_A_VERB and word not in _NOT_VERBS_IN_S
            and may_be_verb(word))


def list_steps(piece: str) -> list[str]:
    """``piece`` cut into its items when it lists steps ("Ben switches the TV on, curls up in
    the armchair to watch a film, and turns it off again": three): at least three items, each
    after the first opening with a verb (:func:`_verb_like`), the last after "and", and the
    items not all of one kind of activity (a list of things eaten is one step). An item whose
    words point to no action (:func:`activity_kind`: it goes somewhere, sits down, says how
    something is) or to the same one as the next item stays with the item after it."""
    cuts = [(m.start(), m.end()) for m in _COMMA_WORD.finditer(piece) if _verb_like(m.group(1))]
    last = [(m.start(), m.end()) for m in AND_WORD.finditer(piece) if _verb_like(m.group(1))]
    if not cuts or not last or last[-1][0] <= cuts[-1][0]:
        return [piece]
    bounds = [*(c for c in cuts if c[0] < last[-1][0]), last[-1]]
    spans = list(zip([0, *(end for _, end in bounds)], [*(start for start, _ in bounds), len(piece)], strict=True))
    items = [piece[start:end].strip() for start, end in spans]
    if len(items) < 3 or any(len(item.split()) < 2 for item in items):
        return [piece]
    kinds = [activity_kind(item) for item in items]  # the ranker passes over landmarks itself
    if len(set(kinds)) < 2:
        return [piece]
    steps: list[str] = []
    first = 0  # the item the step being built starts with; joined items keep their own words between
    for k in range(len(items)):
        if k + 1 < len(items) and (kinds[k] is None or kinds[k] == kinds[k + 1]):
            continue
        steps.append(piece[spans[first][0] : spans[k][1]].strip())
        first = k + 1
    return steps

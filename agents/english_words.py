"""English word forms from a lexicon (``lemminflect``, whose data ships in its wheel; no download).

The instruction readers need two facts about a word no hand list covers well: whether it may
be a verb ("curls", "munches" may; "bananas", "pears" may not) and, for a word that is only a
verb, its dictionary forms ("carries" -> carry, "ate" -> eat, "brought" -> bring). Lookups are cached; a word the lexicon
does not know has no lemmas and is no verb. Pure: no LLM, no I/O after the lexicon loads.
"""

from __future__ import annotations

import functools

import lemminflect


@functools.lru_cache(maxsize=8192)
def verb_lemmas(word: str) -> frozenset[str]:
    """The dictionary forms of ``word`` read as a verb ("carries" -> carry, "ate" -> eat); empty
    when the lexicon does not know it as a verb, or knows it as a noun too ("a bit of peace" is
    no biting, "the news" no using)."""
    low = word.lower()
    if lemminflect.getAllLemmas(low, upos="NOUN"):
        return frozenset()
    return frozenset(lemminflect.getAllLemmas(low, upos="VERB").get("VERB", ()))


@functools.lru_cache(maxsize=8192)
def may_be_verb(word: str) -> bool:
    """Whether the lexicon knows ``word`` as a form of a verb ("turns", "ate"; not "bananas")."""
    return bool(lemminflect.getAllLemmas(word.lower(), upos="VERB"))

"""Word forms from the packaged lexicon (storyteller.agents.english_words): verbs known, nouns not taken for verbs."""

from __future__ import annotations

from storyteller.agents.english_words import may_be_verb, verb_lemmas


def test_verbs_and_nouns_of_an_instruction() -> None:
    assert all(may_be_verb(w) for w in ("curls", "munches", "turns", "ate", "Switches"))
    assert not any(may_be_verb(w) for w in ("bananas", "pears", "cookies", "xyzzy"))


def test_forms_of_a_word_that_is_only_a_verb() -> None:
    assert verb_lemmas("carries") == {"carry"}
    assert verb_lemmas("ate") == {"eat"}
    assert verb_lemmas("brought") == {"bring"}
    assert verb_lemmas("bit") == frozenset()  # "a bit of peace": a noun too, so no biting
    assert verb_lemmas("xyzzy") == frozenset()

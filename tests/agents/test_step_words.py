"""Which clauses are steps of their own (storyteller.agents.step_words). General English, no case's words."""

from __future__ import annotations

import pytest

from storyteller.agents.step_words import has_verb, moves_only, no_action, states_only

NAMES = frozenset({"ava", "ben"})


@pytest.mark.parametrize(("text", "subject", "expected"), [
    ("Ava heads over to the window", "Ava", True),
    ("Ava slowly makes her way to the bar", "Ava", True),
    ("Ava goes through her notes", "Ava", False),
    ("Ava walks the dog", "Ava", False),
])
def test_going_somewhere(text: str, subject: str, expected: bool) -> None:
    assert moves_only(text, subject) is expected


@pytest.mark.parametrize(("text", "subject", "expected"), [
    ("Ava's cup is empty", "Ava", True),
    ("The lamp is still on", "", True),
    ("Ava is a bit tired", "Ava", True),
    ("Ava is making tea", "Ava", False),                    # an -ing form acts
    ("Ava waits where the light is brightest", "Ava", False),  # a verb before the copula
    ("Ava reads", "Ava", False),                            # no form of be
])
def test_saying_how_something_is(text: str, subject: str, expected: bool) -> None:
    assert states_only(text, subject, NAMES) is expected


def test_a_verbless_phrase_is_no_step_and_a_plural_subject_s_verb_is_a_verb() -> None:
    assert no_action("Ava, free for a moment.", "Ava", NAMES)
    assert has_verb("Ava and Ben cook", "Ava and Ben", NAMES)
    assert not no_action("Ava and Ben cook.", "Ava and Ben", NAMES)

"""Everyday object names and side phrases read the way the word readers know (storyteller.agents.object_names,
storyteller.agents.place_phrases). Wording here is general English, not any benchmark case's."""

from __future__ import annotations

import pytest

from storyteller.agents.action_shortlist import posture, rank_action_labels
from storyteller.agents.object_names import read_as_labels
from storyteller.agents.place_phrases import plain_places
from storyteller.agents.shortlist import mentioned_labels, relation_areas

LABELS = ("couch", "bookshelf", "water_dispenser", "bar_counter", "stool", "fridge", "chair", "table", "tv")


@pytest.mark.parametrize(("text", "label"), [
    ("she stops at the water cooler", "water_dispenser"),
    ("a book from the bookcase", "bookshelf"),
    ("naps on the sofa", "couch"),
    ("leans on the bar", "bar_counter"),
    ("climbs onto a barstool", "stool"),
    ("checks the refrigerator", "fridge"),
])
def test_an_everyday_name_reads_as_the_label(text: str, label: str) -> None:
    assert mentioned_labels(text, LABELS)[:1] == [label]


def test_a_label_s_own_words_stay_and_a_name_that_is_a_label_is_not_rewritten() -> None:
    assert read_as_labels("a stool by the bar counter", LABELS) == "a stool by the bar counter"
    assert read_as_labels("two chairs", LABELS) == "two chairs"  # the plural stays for the capacity reader
    assert read_as_labels("at the bar", ("bar", "counter")) == "at the bar"  # a scene with a bar label
    assert read_as_labels("the telly", ("couch",)) == "the telly"  # no tv in this scene: nothing to name


@pytest.mark.parametrize(("text", "areas"), [
    ("Kim waits on the lamp's own left-hand side.", ("get_area_left_of",)),
    ("Kim waits on its right.", ("get_area_right_of",)),
    ("Kim stands at the cabinet's back.", ("get_area_behind",)),
    ("Seen from the front, Kim stands on the lamp's left.", ("get_area_right_of",)),  # the lamp's own right
    ("Kim waits on the lamp's right side (the left, as you look at it).", ("get_area_right_of",)),
    ("Kim waits right next to the lamp.", ("get_area_adjacent_to", "get_area_close_to")),
    ("Midway from the lamp to the window, Kim pauses.", ("get_area_between",)),
    ("Kim goes half way from the fridge to the big sink and waits.", ("get_area_between",)),
    ("Kim rests at the midpoint of the path from the door to the stove.", ("get_area_between",)),
])
def test_sides_of_things_name_one_area_function(text: str, areas: tuple[str, ...]) -> None:
    assert relation_areas(plain_places(text)) == areas


def test_waiting_on_a_bench_s_side_is_not_sitting_on_it_and_names_keep_their_case() -> None:
    assert posture("Kim waits on the bench.") == "sit"
    assert posture(plain_places("Kim waits on the bench's right-hand side.")) != "sit"
    assert plain_places("Kim sits to her right at the table.") == "Kim sits to her right at the table."


@pytest.mark.parametrize(("text", "label"), [
    ("Kim sits down to have a cold lemonade", "drink"),
    ("Kim has a bowl of porridge", "eat"),
    ("Kim waits for the waiter", "idle"),
])
def test_things_people_drink_and_eat_rank_the_action(text: str, label: str) -> None:
    ranked = rank_action_labels(text, ("idle", "chat", "eat", "drink", "use_laptop"))
    assert ranked and ranked[0].label == label


def test_a_trip_from_one_thing_to_another_stays_a_trip_and_a_midpoint_is_a_place_to_stand() -> None:
    assert plain_places("Kim walks from the door to the window and waits.") == "Kim walks from the door to the window and waits."
    assert plain_places("Kim stands in the middle of the room.") == "Kim stands in the middle of the room."
    assert plain_places("Halfway from the rug to the sofa, Kim listens.") == "Halfway between the rug and the sofa, Kim listens."
    assert posture(plain_places("Kim waits halfway from the rug to the sofa.")) != "sit"


@pytest.mark.parametrize(("text", "plain"), [
    ("Kim takes the chair at Bo's side to read.", "Kim takes the chair beside Bo to read."),
    ("Kim waits by Bo's side.", "Kim waits beside Bo."),
    ("Kim sits on Bo's left.", "Kim sits to the left of Bo."),
    ("Kim stands at the lamp's back.", "Kim stands behind the lamp."),
    ("Kim reads Bo's book on the sofa.", "Kim reads Bo's book on the sofa."),  # no side: unchanged
])
def test_a_person_s_side_is_beside_the_person(text: str, plain: str) -> None:
    """A thing's words never run over a preposition ("the chair at Bo's" is no thing): the owner
    is the name, and the preposition before the side goes with it."""
    assert plain_places(text) == plain


def test_taking_the_seat_at_someone_s_side_is_sitting() -> None:
    assert posture(plain_places("Kim takes the seat at Bo's side to have a tea.")) == "sit"


@pytest.mark.parametrize(("text", "plain"), [
    ("Kim waits at the back of the sofa.", "Kim waits behind the sofa."),
    ("Kim stands at the front of the desk.", "Kim stands in front of the desk."),
    ("Kim sits at the back of the room.", "Kim sits at the back of the room."),  # a room has no back side to stand at
])
def test_the_back_of_a_thing_is_behind_it(text: str, plain: str) -> None:
    assert plain_places(text) == plain

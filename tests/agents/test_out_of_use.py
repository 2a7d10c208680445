"""Things the words say cannot be used, and the seat choice that leaves them out: a named seat
that is broken or taken, a unique label ("the couch is wet"), lists, adjectives before the thing,
and another seat at the table of the one ruled out."""

from __future__ import annotations

from storyteller.agents.out_of_use import out_of_use, seats_taken_by
from storyteller.agents.place_choice import seat_candidates
from storyteller.sim.scene.model import Scene
from tests.support.scene_objects import box


def cafe() -> Scene:
    """Two tables 4 m apart with two chairs each (chair_1, chair_2 at table_1; chair_3, chair_4 at
    table_2) and one couch away from both."""
    return Scene(name="cafe", bounds_min=(-4.0, -4.0), bounds_max=(10.0, 6.0), objects=(
        box("table", 1, 0.0, 0.0, size=(1.2, 0.8, 0.75)), box("table", 2, 4.0, 0.0, size=(1.2, 0.8, 0.75)),
        box("chair", 1, -0.3, -0.7, seat=True), box("chair", 2, 0.3, -0.7, seat=True),
        box("chair", 3, 3.7, -0.7, seat=True), box("chair", 4, 4.3, -0.7, seat=True),
        box("couch", 1, 8.0, 4.0, seat=True, size=(1.8, 0.8, 0.8)),
    ))  # fmt: skip


CAFE = cafe()


def test_a_thing_followed_by_be_and_a_word_of_unusability_is_out_of_use() -> None:
    assert out_of_use("Chair_3 is sadly wobbly since Monday.", CAFE) == {"chair_3"}
    assert out_of_use("Ida sits down; the couch is wet.", CAFE) == {"couch_1"}  # the only couch
    assert out_of_use("chair_1, chair_2 and chair_4 are all taken", CAFE) == {"chair_1", "chair_2", "chair_4"}
    assert out_of_use("Ida avoids the broken chair_2.", CAFE) == {"chair_2"}
    assert out_of_use("The couch is out of order.", CAFE) == {"couch_1"}


def test_a_thing_merely_named_or_a_label_of_several_is_not_out_of_use() -> None:
    assert out_of_use("Ida sits on chair_3 and reads.", CAFE) == frozenset()
    assert out_of_use("The chair is broken.", CAFE) == frozenset()  # four chairs: which one is not said
    assert out_of_use("Chair_3 is where Ida sits; the wet floor is mopped.", CAFE) == frozenset()


def test_the_seat_choice_leaves_out_a_ruled_out_seat_and_keeps_its_table() -> None:
    free = ["chair_1", "chair_2", "chair_3", "chair_4", "couch_1"]
    text = "Ida lunches by table_2. Its chair_3 is cracked, so she picks a free seat by that table."
    seats = seat_candidates(CAFE, text, free, {}, unusable=out_of_use(text, CAFE))
    assert seats.candidates == ("chair_4",)
    plain = seat_candidates(CAFE, text, free, {})
    assert "chair_3" in plain.candidates  # without the rule the broken chair is a candidate
    only = seat_candidates(CAFE, "Ida sits; chair_3 is taken.", ["chair_3"], {}, unusable={"chair_3"})
    assert only.candidates == ("chair_3",)  # nothing else is free: the rule gives way


def test_a_landmark_or_a_seat_the_event_sits_on_is_not_ruled_out() -> None:
    assert out_of_use("The chair next to the couch is broken, so Ida sits on the couch.", CAFE) == frozenset()
    assert out_of_use("Ida leans on table_1, which is wet.", CAFE) == frozenset()  # not a seat
    assert out_of_use("The couch is reserved for Mia.", CAFE) == frozenset()  # reserved for someone: usable
    assert seats_taken_by("Ben sits on chair_1.", CAFE) == {"chair_1"}
    assert seats_taken_by("Ida takes the couch.", CAFE) == {"couch_1"}
    assert seats_taken_by("lunch by table_2 next to the chair_3", CAFE) == frozenset()


def test_another_table_is_not_the_table_of_the_seat_ruled_out() -> None:
    free = ["chair_1", "chair_3", "chair_4", "couch_1"]
    text = "Chair_2 is taken, so Mo sits at the other table."
    seats = seat_candidates(CAFE, text, free, {}, unusable=out_of_use(text, CAFE))
    assert "chair_3" in seats.candidates and "chair_4" in seats.candidates

"""Shortlists of an event's objects and seats from its words and the scene's geometry."""

from __future__ import annotations

import pytest

from storyteller.agents.event_parser import scene_action_labels
from storyteller.agents.shortlist import event_shortlist, mentioned_labels
from storyteller.sim.scene.bundled import resolve_scene
from storyteller.sim.scene.model import Scene
from storyteller.tools.scene_graph import footprint_distance

HOME = resolve_scene("home")
RESTAURANT = resolve_scene("restaurant")


def seats(scene: Scene) -> list[str]:
    return [o.name for o in scene.objects if o.is_seat]


def test_labels_are_found_by_full_name_head_word_plural_and_common_synonym() -> None:
    labels = ["coffee_table", "dining_table", "couch", "tv", "tv_stand", "plate", "record_player"]
    assert mentioned_labels("puts the cup on the coffee table", labels) == ["coffee_table"]
    assert mentioned_labels("sits at a table", labels) == ["coffee_table", "dining_table"]
    assert mentioned_labels("watches television from the sofa", labels) == ["tv", "couch"]
    assert mentioned_labels("clears the plates", labels) == ["plate"]
    assert mentioned_labels("switches on the turntable", labels) == ["record_player"]
    assert mentioned_labels("waits for a friend", labels) == []


def test_named_objects_and_objects_implied_by_the_action_are_candidates() -> None:
    s = event_shortlist(HOME, "make coffee sitting on couch_1", seats(HOME), scene_action_labels(HOME))
    assert s.objects == ("couch_1", "coffee_maker_1") and s.seats == ("couch_1",)
    assert event_shortlist(HOME, "Ava makes coffee", seats(HOME), scene_action_labels(HOME)).objects == ("coffee_maker_1",)


def test_seats_follow_what_the_event_is_about_and_only_free_ones() -> None:
    laptop = next(o for o in HOME.objects if o.label == "laptop")
    s = event_shortlist(HOME, "types an email on the laptop", seats(HOME))
    assert s.seats and all(footprint_distance(next(o for o in HOME.objects if o.name == n), laptop) <= 1.0 for n in s.seats)
    free = [n for n in seats(HOME) if n != "couch_1"]
    assert "couch_1" not in event_shortlist(HOME, "sits on the couch", free).seats
    tv = event_shortlist(HOME, "watches TV", seats(HOME))
    assert "couch_1" in tv.seats  # a TV is watched from across the room


def test_nearest_and_farthest_pick_by_distance_to_the_landmark() -> None:
    tables = [o for o in RESTAURANT.objects if o.label == "table"]
    bar = [o for o in RESTAURANT.objects if o.label == "bar_counter"]
    gap = {t.name: min(footprint_distance(t, b) for b in bar) for t in tables}
    near = event_shortlist(RESTAURANT, "eats at the table nearest the bar counter", seats(RESTAURANT))
    far = event_shortlist(RESTAURANT, "eats at the table farthest from the bar counter", seats(RESTAURANT))
    assert [n for n in near.objects if n in gap] == [min(gap, key=gap.__getitem__)]
    assert [n for n in far.objects if n in gap] == [max(gap, key=gap.__getitem__)]
    assert near.seats != far.seats


def test_words_that_name_nothing_give_an_empty_shortlist() -> None:
    s = event_shortlist(HOME, "chats with a friend", seats(HOME), scene_action_labels(HOME))
    assert s.objects == () and s.seats == ()


def test_the_landmark_is_what_follows_the_last_place_word() -> None:
    """"the stool at the end of the bar nearest the espresso machine": the bar runs along every
    stool, so the espresso machine (after "nearest") is what picks the stool."""
    stools = [o for o in RESTAURANT.objects if o.label == "stool"]
    maker = [o for o in RESTAURANT.objects if o.label == "coffee_maker"]
    gap = {s.name: min(footprint_distance(s, m) for m in maker) for s in stools}
    s = event_shortlist(RESTAURANT, "orders a drink from the stool at the end of the bar nearest the espresso machine",
                        seats(RESTAURANT), ("order_drink",))
    assert s.seats == (min(gap, key=gap.__getitem__),)
    assert mentioned_labels("leans on the bar", RESTAURANT.labels) == ["bar_counter"]
    assert mentioned_labels("takes a bar stool", RESTAURANT.labels) == ["stool"]


def test_a_named_character_brings_the_seats_near_them() -> None:
    """"sits down at Gus's table": the free seats next to where Gus is, not every chair."""
    chair = next(o for o in RESTAURANT.objects if o.label == "chair")
    gus = (float(chair.center[0]) + 0.9, float(chair.center[1]))
    s = event_shortlist(RESTAURANT, "joins Gus and sits down at his table", seats(RESTAURANT), ("eat",),
                        others={"Gus": gus, "Ida": (100.0, 100.0)})
    assert chair.name in s.seats and 0 < len(s.seats) < len(seats(RESTAURANT))
    far = event_shortlist(RESTAURANT, "joins Gus and sits down at his table", seats(RESTAURANT), ("eat",),
                          others={"Ida": gus})
    assert chair.name not in far.seats or len(far.seats) > len(s.seats)


def test_a_dining_table_is_one_with_chairs_around_it() -> None:
    """"the dining table" in the home scene: the table with the chairs, not the coffee table by
    the couch (whose nearest seat is the couch)."""
    s = event_shortlist(HOME, "sits down at the dining table to eat", seats(HOME), ("eat",))
    assert "couch_1" not in s.seats and s.seats and all(n.startswith("chair_") for n in s.seats)
    assert len([o for o in s.objects if o.startswith("table_")]) == 1


@pytest.mark.parametrize(("text", "tables"), [
    ("Two friends eat at one of the small tables for two", {"table_3", "table_4"}),
    ("The family sits down at a table for 4", {"table_1", "table_2"}),
    ("Three guests take the table for three", {"table_1", "table_2"}),  # none seats exactly three: the next size up
])
def test_a_table_named_by_how_many_it_seats(text: str, tables: set[str]) -> None:
    from storyteller.agents.shortlist import seats_around

    assert {t: seats_around(o, RESTAURANT) for t, o in ((o.name, o) for o in RESTAURANT.objects if o.label == "table")} \
        == {"table_1": 4, "table_2": 4, "table_3": 2, "table_4": 2}
    short = event_shortlist(RESTAURANT, text, seats(RESTAURANT), ["eat"])
    assert {o for o in short.objects if o.startswith("table_")} == tables
    near = {f"chair_{i}" for i in ((9, 10, 11, 12) if tables == {"table_3", "table_4"} else range(1, 9))}
    assert set(short.seats) == near


def test_a_conference_table_is_the_one_people_sit_around() -> None:
    office = resolve_scene("office")
    short = event_shortlist(office, "Four colleagues meet around the conference table", seats(office), ["attend_meeting"])
    assert short.objects == ("table_1",)
    assert set(short.seats) == {f"chair_{i}" for i in range(1, 7)}


@pytest.mark.parametrize(("text", "tables"), [
    ("sit at the small round table and chat", {"table_3"}),  # round: 0.8 x 0.8; the coffee table is smaller but long
    ("eats at the little table with two chairs", {"table_3"}),  # two chairs around it
    ("puts the magazine on the small table", {"table_2"}),  # the smallest footprint
    ("spreads the plans on the big table", {"table_1"}),
    ("waits by the long table", {"table_1", "table_2"}),
    ("sits at a table", {"table_1", "table_2", "table_3"}),  # no size or shape word: every table
])
def test_size_and_shape_words_pick_among_objects_of_a_label(text: str, tables: set[str]) -> None:
    office = resolve_scene("office")
    short = event_shortlist(office, text, seats(office), ["eat", "chat"])
    assert {o for o in short.objects if o.startswith("table_")} == tables


def test_a_round_table_brings_only_its_own_chairs() -> None:
    office = resolve_scene("office")
    short = event_shortlist(office, "sit at the small round table and chat", seats(office), ["chat"])
    assert set(short.seats) == {"chair_7", "chair_8"}

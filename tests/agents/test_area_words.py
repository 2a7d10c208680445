"""Which of the scene description's areas an event's words name, and the seat candidates it
leaves: reading area lines back from a description, naming an area by its name or its kind's
synonyms, leading away from it, and the seat choice limited to the named area's seats."""

from __future__ import annotations

from storyteller.agents.area_words import DescribedArea, described_areas, keep_in_areas, named_areas
from storyteller.agents.place_choice import seat_candidates
from storyteller.agents.program_grammar import event_options
from storyteller.sim.scene.model import Scene
from tests.support.scene_objects import box


def flat() -> Scene:
    """Two rooms side by side: a galley with a table and two stools (west), a den with a sofa, a
    table and three chairs (east); the chairs are the first seats by name."""
    return Scene(name="flat", bounds_min=(-6.0, -4.0), bounds_max=(8.0, 4.0), objects=(
        box("chair", 1, 4.0, 0.0, seat=True), box("chair", 2, 5.0, 0.0, seat=True), box("chair", 3, 6.0, 0.0, seat=True),
        box("table", 1, 5.0, 1.0, size=(3.0, 0.9, 0.75)),
        box("couch", 1, 5.0, -2.5, seat=True, size=(1.8, 0.8, 0.8)),
        box("stool", 1, -4.0, 0.0, seat=True), box("stool", 2, -3.0, 0.0, seat=True),
        box("table", 2, -3.5, 1.0, size=(2.0, 0.9, 0.75)),
        box("fridge", 1, -5.5, 2.0, size=(0.7, 0.7, 1.8)),
    ))  # fmt: skip


FLAT = flat()
DESCRIPTION = (
    "- kitchen (store food, eat): fridge_1, table_2 (with nothing on it), stool_1, stool_2\n"
    "- living room (sit and relax): chair_1, chair_2, chair_3, couch_1, table_1\n"
    "Some line that is no area line: chair_9"
)


def test_area_lines_are_read_back_with_the_scene_objects_they_list() -> None:
    kitchen, living = described_areas(DESCRIPTION, FLAT.object_names)
    assert (kitchen.name, kitchen.purpose) == ("kitchen", "store food, eat")
    assert kitchen.objects == {"fridge_1", "table_2", "stool_1", "stool_2"}
    assert living.objects == {"chair_1", "chair_2", "chair_3", "couch_1", "table_1"}
    assert described_areas("- object list: none of these exist", FLAT.object_names) == ()
    assert described_areas("- lounge: chair_1, ghost_7", ["chair_1"])[0].objects == {"chair_1"}  # unknown names dropped


def test_an_area_is_named_by_its_own_name_or_by_a_synonym_of_its_kind() -> None:
    areas = described_areas(DESCRIPTION, FLAT.object_names)
    assert [a.name for a in named_areas("Ina snacks perched in the kitchen.", areas)] == ["kitchen"]
    assert [a.name for a in named_areas("Ina reads in the sitting room.", areas)] == ["living room"]  # a synonym
    assert [a.name for a in named_areas("Ina reads in the family room", areas)] == ["living room"]
    meeting = (DescribedArea("meeting room", "", frozenset({"chair_1"})),)
    assert named_areas("Ina presents her plan in the boardroom.", meeting) == meeting


def test_a_place_word_without_an_article_or_led_away_from_names_no_area() -> None:
    areas = described_areas(DESCRIPTION, FLAT.object_names)
    assert named_areas("Ina sits far away from the kitchen.", areas) == ()
    assert named_areas("Ina leaves the kitchen and sits down.", areas) == ()
    assert named_areas("Ina sits by the kitchen's door.", areas) == ()
    assert named_areas("Ina likes kitchen gadgets.", areas) == ()  # no determiner: not a place


def test_the_seat_choice_keeps_the_named_areas_seats() -> None:
    areas = described_areas(DESCRIPTION, FLAT.object_names)
    free = [o.name for o in FLAT.objects if o.is_seat]
    seats = seat_candidates(FLAT, "Ina has soup perched in the kitchen.", free, {}, areas=areas)
    assert set(seats.candidates) == {"stool_1", "stool_2"}
    anywhere = seat_candidates(FLAT, "Ina has soup perched somewhere.", free, {}, areas=areas)
    assert {"chair_1", "stool_1"} <= set(anywhere.candidates)  # no area named: every seat stays
    unlimited = seat_candidates(FLAT, "Ina has soup perched in the kitchen.", free, {})
    assert "chair_1" in unlimited.candidates  # without a description's areas nothing is limited


def test_an_area_whose_seats_are_all_taken_limits_nothing() -> None:
    areas = described_areas(DESCRIPTION, FLAT.object_names)
    free = ["chair_1", "chair_2", "chair_3", "couch_1"]  # both stools taken
    seats = seat_candidates(FLAT, "Ina sits in the kitchen.", free, {}, areas=areas)
    assert set(seats.candidates) == set(free)


def test_a_named_kind_of_seat_outweighs_an_area_without_one() -> None:
    areas = described_areas(DESCRIPTION, FLAT.object_names)
    free = [o.name for o in FLAT.objects if o.is_seat]
    seats = seat_candidates(FLAT, "Ina sits on the couch in the kitchen.", free, {}, areas=areas)
    assert seats.candidates == ("couch_1",)  # the kitchen has no couch: the couch it is


def test_keep_in_areas_narrows_each_kind_with_instances_in_the_area() -> None:
    labels = {o.name: o.label for o in FLAT.objects}
    kitchen = {"fridge_1", "table_2", "stool_1", "stool_2"}
    assert keep_in_areas(["table_1", "table_2", "chair_1", "fridge_1"], labels, kitchen) == ["table_2", "chair_1", "fridge_1"]
    assert keep_in_areas(["chair_1", "chair_2"], labels, kitchen) == ["chair_1", "chair_2"]  # no chair in the kitchen


def test_the_event_grammar_offers_the_named_areas_things_of_each_kind() -> None:
    areas = described_areas(DESCRIPTION, FLAT.object_names)
    text = "Ina idles midway between two tables in the sitting room"
    options = event_options(FLAT, ["Ina"], [], [], ["idle", "eat"], activity=text, areas=areas)
    assert "table_1" in options.objects and "table_2" not in options.objects
    plain = event_options(FLAT, ["Ina"], [], [], ["idle", "eat"], activity=text)
    assert {"table_1", "table_2"} <= set(plain.objects)
    retry = event_options(FLAT, ["Ina"], [], [], ["idle", "eat"], activity=text, areas=areas, widen=True)
    assert {"table_1", "table_2"} <= set(retry.objects)  # a retry after "no room" is not narrowed


def test_inflected_area_words_name_the_area() -> None:
    rest = (DescribedArea("rest area", "", frozenset({"chair_1"})),)
    assert named_areas("Ina dozes in the resting areas by the window.", rest) == rest
    assert named_areas("Ina steps out of the rest area.", rest) == ()  # out of it, not in it


def test_a_phrase_naming_a_kind_of_object_names_no_area() -> None:
    reception = (DescribedArea("reception", "", frozenset({"chair_1"})),)
    text = "Ina orders at the reception desk."
    assert named_areas(text, reception) == reception  # "reception desk" is a synonym of the reception kind
    assert named_areas(text, reception, labels=["reception_desk", "chair"]) == ()  # but here it is a thing
    assert named_areas("Ina waits at the front desk.", reception, labels=["reception_desk"]) == ()  # an everyday name
    assert named_areas("Ina waits in the reception.", reception, labels=["reception_desk"]) == reception


def test_a_label_of_the_scene_is_that_thing_not_an_area_of_its_kind() -> None:
    work = (DescribedArea("work area", "", frozenset({"chair_1"})),)
    assert named_areas("Ina sits at the desks.", work) == work  # "desks": a synonym of a work area
    assert named_areas("Ina sits at the desk.", work, labels=["desk", "chair"]) == ()  # the scene's desk


def test_a_relation_to_an_area_names_no_area_to_be_in() -> None:
    meeting = (DescribedArea("meeting room", "", frozenset({"chair_1"})),)
    assert named_areas("Ava works at the desk nearest the meeting room.", meeting) == ()
    assert named_areas("Ava waits close to the meeting room.", meeting) == ()
    assert named_areas("Ava works within the meeting room.", meeting) == meeting


def test_a_short_text_without_an_article_still_names_the_area() -> None:
    meeting = (DescribedArea("meeting room", "", frozenset({"chair_1"})),)
    assert named_areas("present plan seated in boardroom seat", meeting) == meeting
    assert named_areas("present plan near boardroom", meeting) == ()


def test_an_area_is_named_by_what_a_phrase_of_use_says_it_is_for() -> None:
    areas = (DescribedArea("meeting room", "write on the whiteboard", frozenset({"chair_1"})),
             DescribedArea("lounge", "sit and relax", frozenset({"couch_1"})),
             DescribedArea("work area", "use a laptop", frozenset({"chair_2"})))  # fmt: skip
    assert [a.name for a in named_areas("Bo sits in the space reserved for holding meetings.", areas)] == [
        "meeting room"]  # fmt: skip
    assert [a.name for a in named_areas("Bo finds a spot where people relax.", areas)] == ["lounge"]
    assert named_areas("Bo sits down for a while.", areas) == ()  # no place noun: no phrase of use
    assert named_areas("Bo saves a spot for his friend.", areas) == ()  # for a person: nothing shared

"""How far a stated relation reaches in the words, and the place one sits at: an attributive
relation word keeps the thing it describes and drops all of its landmark ("the most distant
desk from the couch"), "across the table from Mia" faces Mia, a direction word introduces a
landmark for the action's words, and "at the table" keeps the seats at tables."""

from __future__ import annotations

from storyteller.agents.action_shortlist import rank_action_labels
from storyteller.agents.place_choice import places_sat_at, seat_candidates
from storyteller.agents.relation_words import stated_relations, without_relations
from storyteller.sim.scene.model import Scene
from tests.support.scene_objects import box

LABELS = ("desk", "couch", "table", "chair", "office_chair", "tv")


def studio() -> Scene:
    """A table with two chairs (chair_1, chair_2), a desk 5 m off with office_chair_1, a couch
    between them and a TV."""
    return Scene(name="studio", bounds_min=(-3.0, -3.0), bounds_max=(9.0, 5.0), objects=(
        box("table", 1, 0.0, 0.0, size=(1.2, 0.8, 0.75)),
        box("chair", 1, -0.3, -0.7, seat=True), box("chair", 2, 0.3, 0.7, seat=True, facing=(0.0, -1.0)),
        box("desk", 1, 5.0, 0.0, size=(1.4, 0.7, 0.75)),
        box("office_chair", 1, 5.0, -0.6, seat=True),
        box("couch", 1, 2.5, 3.0, seat=True, size=(1.8, 0.8, 0.8)),
        box("tv", 1, 2.5, 4.5, size=(1.2, 0.1, 0.7)),
    ))  # fmt: skip


STUDIO = studio()


def test_an_attributive_relation_drops_its_whole_landmark_and_keeps_what_it_describes() -> None:
    text = "Pia works at the desk lying furthest away from the sofa."
    (mention,) = stated_relations(text, LABELS)
    assert mention.kind == "farthest" and mention.references == (("couch",),)
    assert "sofa" not in without_relations(text, [mention], LABELS) and "desk" in without_relations(text, [mention], LABELS)
    text = "She picks the most distant desk from the couch, to write."
    (mention,) = stated_relations(text, LABELS)
    assert mention.subject == ("desk",)
    assert without_relations(text, [mention], LABELS).split() == ["She", "picks", "the", "desk", ",", "to", "write", "."]


def test_across_a_thing_from_someone_faces_that_someone() -> None:
    (mention,) = stated_relations("Ola takes a seat across the table from Mia for tea.", LABELS, ["Mia"])
    assert mention.kind == "facing" and mention.references == (("@Mia",),)
    (plain,) = stated_relations("Ola sits across from the couch.", LABELS, ["Mia"])
    assert plain.references == (("couch",),)


def test_what_one_looks_toward_is_a_landmark_not_the_activity() -> None:
    ranked = rank_action_labels("scrolls through messages on a phone in a seat that looks toward the tv",
                                ["watch_tv", "use_smartphone", "idle"])
    assert ranked[0].label == "use_smartphone"


def test_at_the_table_keeps_the_seats_at_tables() -> None:
    assert places_sat_at("Rui finds a free spot at the big table, to eat", STUDIO) == ("table",)
    assert places_sat_at("Rui sits on the couch near the table", STUDIO) == ()  # not "at"
    assert places_sat_at("Rui looks at the tv", STUDIO) == ()  # nobody sits at a TV
    free = ["chair_1", "chair_2", "office_chair_1", "couch_1"]
    seats = seat_candidates(STUDIO, "Rui finds a free spot at the big table, to eat", free, {})
    assert set(seats.candidates) == {"chair_1", "chair_2"}
    seats = seat_candidates(STUDIO, "Rui sits at the desk furthest away from the sofa", free, {})
    assert seats.allowed == ("office_chair_1",)


def test_a_relation_to_someones_seat_is_a_relation_to_them() -> None:
    (mention,) = stated_relations("Ada takes the chair next to Bo's and reads.", LABELS, ["Ada", "Bo"])
    assert mention.kind == "near" and mention.references == (("@Bo",),)
    (mention,) = stated_relations("Ada settles beside Bo's, to read.", LABELS, ["Ada", "Bo"])
    assert mention.references == (("@Bo",),)


def test_a_switch_with_one_direction_left_needs_no_direction_word() -> None:
    labels = ["listen_to_music", "turn_off_record_player", "idle"]  # the record player is on: no turn_on
    assert rank_action_labels("Jo sees to the record player.", labels)[0].label == "turn_off_record_player"
    assert rank_action_labels("Jo listens to the record player.", labels)[0].label == "listen_to_music"
    both = ["listen_to_music", "turn_on_record_player", "turn_off_record_player"]
    assert rank_action_labels("Jo wants silence and sees to the record player.", both)[0].label == "turn_off_record_player"
    assert rank_action_labels("Jo switches the record player on.", both)[0].label == "turn_on_record_player"


def test_nowhere_near_is_far_and_it_is_the_thing_named_before() -> None:
    """"nowhere near the lamp" keeps away from it; "the desk furthest from it" measures from the
    thing named before (not from the desk the relation describes)."""
    labels = ("lamp", "desk", "stool")
    found = stated_relations("Ivo wants to be nowhere near the lamp, so he works at the desk furthest from it.",
                             labels, ["Ivo"])
    assert [(m.kind, m.references) for m in found] == [("farthest", (("lamp",),)), ("farthest", (("lamp",),))]
    assert [(m.kind, m.references) for m in stated_relations("Ivo takes a stool and sits next to it.", labels)] == [
        ("near", (("stool",),))]
    assert stated_relations("Ivo waits near it.", labels) == []  # nothing named before: no relation

"""The thing an event uses, narrowed by the relations its words state about it: "the sink
nearest the window" is one sink, and the window is where it is, not what is used."""

from __future__ import annotations

import re

from storyteller.agents.messages import CharacterStatus
from storyteller.agents.program_grammar import event_program_grammar
from storyteller.agents.related_objects import related_objects
from storyteller.sim.scene.model import Scene
from tests.support.scene_objects import box


def galley() -> Scene:
    """Two sinks 4 m apart, a window by the first, a shelf by the second; a stool."""
    return Scene(name="galley", bounds_min=(-2.0, -2.0), bounds_max=(8.0, 4.0), objects=(
        box("sink", 1, 0.0, 0.0, size=(0.8, 0.6, 0.9)), box("sink", 2, 4.0, 0.0, size=(0.8, 0.6, 0.9)),
        box("window", 1, 0.0, 1.2, size=(1.0, 0.1, 1.0)), box("shelf", 1, 4.0, 1.2, size=(1.0, 0.4, 1.8)),
        box("stool", 1, 2.0, -1.0, seat=True),
    ))  # fmt: skip


GALLEY = galley()
ALL = [o.name for o in GALLEY.objects if not o.is_seat]


def test_the_relation_keeps_the_instance_it_singles_out_and_marks_its_landmark() -> None:
    near = related_objects(GALLEY, "Kai scrubs out the sink nearest the window", ALL, {})
    assert near.objects == ("sink_1", "window_1", "shelf_1") and near.landmarks == ("window_1",)
    far = related_objects(GALLEY, "Kai rinses the cups in the sink farthest from the window", ALL, {})
    assert "sink_1" not in far.objects and "sink_2" in far.objects and far.landmarks == ("window_1",)
    by_someone = related_objects(GALLEY, "Kai uses the sink closest to Uma", ALL, {"Uma": (4.2, -0.8)})
    assert "sink_1" not in by_someone.objects and by_someone.landmarks == ()


def test_words_without_a_described_thing_change_nothing() -> None:
    for text in ("Kai stands by the window", "Kai washes up at a sink", "Kai waits near the shelf and hums"):
        assert related_objects(GALLEY, text, ALL, {}).objects == tuple(ALL), text
        assert related_objects(GALLEY, text, ALL, {}).landmarks == (), text
    # a seat has its own choice; a relation about it leaves the objects alone
    assert related_objects(GALLEY, "Kai takes the stool nearest the shelf", ALL, {}).objects == tuple(ALL)


def _alternatives(grammar: str, rule: str) -> set[str]:
    rules = dict(line.split(" ::= ", 1) for line in grammar.strip().splitlines())
    return set(re.findall(r'\\"([^"\\]+)\\"', rules[rule]))


def test_the_program_may_use_only_the_singled_out_thing_and_may_look_at_the_landmark() -> None:
    roster = (CharacterStatus(name="Kai", position=(2.0, 2.0)),)
    labels = ("wash_dishes", "idle")
    # the shelf is named first, so the sinks are not the words' first thing: only the relation says which
    text = "Kai leaves the shelf and scrubs the sink farthest from the window"
    grammar = event_program_grammar(GALLEY, ("Kai",), roster, (), labels, activity=text)
    assert _alternatives(grammar, "interactobject") == {"sink_2", "shelf_1"}
    assert {"window_1", "sink_2"} <= _alternatives(grammar, "look") and "sink_1" not in _alternatives(grammar, "look")
    plain = event_program_grammar(GALLEY, ("Kai",), roster, (), labels, activity="Kai leaves the shelf and scrubs a sink")
    assert {"sink_1", "sink_2"} <= _alternatives(plain, "object")


def diner() -> Scene:
    """Two tables 5 m apart with a chair each, a bar counter between them."""
    return Scene(name="diner", bounds_min=(-2.0, -2.0), bounds_max=(8.0, 4.0), objects=(
        box("table", 1, 0.0, 0.0, size=(1.0, 1.0, 0.75)), box("chair", 1, 0.0, -0.8, seat=True),
        box("table", 2, 5.0, 0.0, size=(1.0, 1.0, 0.75)), box("chair", 2, 5.0, -0.8, seat=True),
        box("bar_counter", 1, 2.5, 2.5, size=(2.0, 0.6, 1.05)),
    ))  # fmt: skip


def test_a_serving_action_is_at_the_table_of_the_people_served() -> None:
    scene = diner()
    roster = (CharacterStatus(name="Cleo", position=(2.5, 1.5)),
              CharacterStatus(name="Ava", position=(5.0, -0.8), seat="chair_2", busy=True))
    labels = ("deliver_menu", "take_order", "idle")
    text = "Cleo brings them menus at the table"
    served = event_program_grammar(scene, ("Cleo",), roster, ("chair_2",), labels, activity=text, served=("Ava",))
    assert _alternatives(served, "object") == {"table_2"}  # the only thing offered: no separate interact rule
    unknown = event_program_grammar(scene, ("Cleo",), roster, ("chair_2",), labels, activity=text)
    assert _alternatives(unknown, "object") == {"table_1", "table_2"}
    # a guest still walking to her seat is served where she is heading, not where she is now
    walking = (roster[0], CharacterStatus(name="Ava", position=(0.3, 0.9), busy=True))
    heading = event_program_grammar(scene, ("Cleo",), walking, ("chair_2",), labels, activity=text, served=("Ava",),
                                    heading={"Ava": (5.0, -0.8)})
    assert _alternatives(heading, "object") == {"table_2"}
    # words that name no table ("takes their order"): the guests' table is offered all the same
    order = related_objects(scene, "Cleo takes their order", ["bar_counter_1", "chair_1"], {}, action="take_order",
                            served_at=[(5.0, -0.8)])
    assert order.objects == ("table_2",)  # and nothing else: the order is taken at the guests' table
    # not a serving action: where the guests sit says nothing about which table one wipes
    wipe = related_objects(scene, "Cleo wipes a table", ["table_1", "table_2"], {}, action="clean_table",
                           served_at=[(5.0, -0.8)])
    assert wipe.objects == ("table_1", "table_2")

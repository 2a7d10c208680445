""""To the left / right of" as a stated relation of the seat choice: read from the words, measured
in the reference's own frame (an object's facing, or the facing of the seat a character sits on),
and a reference with no front states no side."""

from __future__ import annotations

from storyteller.agents.place_choice import seat_candidates
from storyteller.agents.relation_words import stated_relations
from storyteller.sim.scene.model import Scene
from storyteller.tools.place_relations import Reference, StatedRelation, satisfying, side_offset
from tests.support.scene_objects import box


def row(facing: tuple[float, float]) -> Scene:
    """Five chairs in a row along x (x = 0, 1, 2, 3, 4), all facing ``facing``; a lamp (no front)
    and a TV facing north at (2, -3)."""
    chairs = [box("chair", i + 1, float(i), 0.0, seat=True, facing=facing) for i in range(5)]
    return Scene(name="row", bounds_min=(-3.0, -5.0), bounds_max=(7.0, 4.0), objects=(
        *chairs, box("lamp", 1, 2.0, 2.0), box("tv", 1, 2.0, -3.0, size=(1.2, 0.2, 0.7), front=True),
    ))  # fmt: skip


def test_the_words_state_a_side_and_its_landmark() -> None:
    (right,) = stated_relations("Jo picks a chair to the right of Kim.", ["chair"], ["Kim", "Jo"])
    assert (right.kind, right.references) == ("right", (("@Kim",),))
    (left,) = stated_relations("Jo takes the chair to the left of the tv.", ["chair", "tv"])
    assert (left.kind, left.references) == ("left", (("tv",),))
    assert stated_relations("Jo sits on the left of the couch.", ["couch"]) == []  # a place on the couch
    assert stated_relations("Jo eats what is left of the cake.", ["cake"]) == []


def test_the_side_is_the_references_own_facing_turned() -> None:
    north = row((0.0, 1.0))  # facing +y: the right is +x
    kim = Reference("Kim", point=(2.0, 0.0), facing=(0.0, 1.0))
    chairs = [o for o in north.objects if o.label == "chair"]
    right = StatedRelation("right", ((kim,),))
    assert [c.name for c in satisfying(right, chairs)] == ["chair_4", "chair_5"]
    south = Reference("Kim", point=(2.0, 0.0), facing=(0.0, -1.0))  # turned round: the right is -x
    assert [c.name for c in satisfying(StatedRelation("right", ((south,),)), chairs)] == ["chair_1", "chair_2"]
    lamp = next(o for o in north.objects if o.label == "lamp")
    assert side_offset(chairs[0], Reference("lamp_1", obj=lamp)) is None  # no front: no side
    assert satisfying(StatedRelation("left", ((Reference("x", point=(2.0, 0.0)),),)), chairs) == []


def test_the_seat_choice_keeps_the_seats_on_the_named_side_of_a_seated_character() -> None:
    north = row((0.0, 1.0))
    free = ["chair_1", "chair_2", "chair_4", "chair_5"]
    kim_on_chair_3 = {"Kim": (2.0, 0.1)}
    seats = seat_candidates(north, "Jo has lunch on a chair to the right of Kim.", free, kim_on_chair_3)
    assert set(seats.allowed) == {"chair_4", "chair_5"}
    lefts = seat_candidates(north, "Jo eats sitting to the left of Kim.", free, kim_on_chair_3)
    assert set(lefts.allowed) == {"chair_1", "chair_2"}

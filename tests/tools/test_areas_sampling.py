"""Areas, area-conditioned sampling, and the world view read from reference test cases."""

from __future__ import annotations

import json
from typing import Any, cast

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene, SceneObject, Vec2, Vec3
from storyteller.tools import areas
from storyteller.tools.character_states import (
    ReferenceCaseError,
    area_from_text,
    world_view_from_reference_case,
)
from storyteller.tools.errors import UnsatisfiableAreaError
from storyteller.tools.position_sampling import Constraints, FloorMap, sample_position
from storyteller.tools.scene_graph import point_footprint_distance
from tests.support.reference import REFERENCE as REF
from tests.support.reference import reference_or_skip

CASES = sorted((REF / "benchmark" / "test_cases").glob("*/*.json"))


@pytest.fixture(scope="module")
def scenes() -> dict[str, Scene]:
    return {
        n: load_scene(reference_or_skip() / "configs" / "scenes" / n) for n in ("House", "Office", "Restaurant")
    }


def obj(name: str, center: Vec3, size: Vec3, facing: Vec2 = (0.0, 1.0), **kw: Any) -> SceneObject:
    label, idx = name.rsplit("_", 1)
    return SceneObject(
        name=name,
        label=label,
        idx=int(idx),
        center=center,
        size=size,
        facing=facing,
        has_facing=True,
        **kw,
    )


ROOM = Scene(
    name="room",
    bounds_min=(0.0, 0.0),
    bounds_max=(6.0, 6.0),
    objects=(
        obj("fridge_1", (1.0, 0.4, 0.9), (0.8, 0.7, 1.8)),
        obj("table_1", (3.0, 3.0, 0.4), (1.2, 0.8, 0.8)),
        obj(
            "chair_1",
            (3.0, 2.2, 0.45),
            (0.45, 0.45, 0.9),
            sit_offset_horizontal=0.1,
            sit_offset_vertical=0.45,
        ),
        obj(
            "couch_1",
            (3.0, 5.4, 0.4),
            (2.0, 0.8, 0.8),
            facing=(0.0, -1.0),
            sit_offset_horizontal=0.2,
            sit_offset_vertical=0.4,
        ),
        obj("cup_1", (3.0, 3.0, 0.85), (0.1, 0.1, 0.1)),
    ),
)
FLOOR = FloorMap(ROOM)


def _area(name: str) -> areas.Area:
    o = ROOM.by_name
    return {
        "front": areas.directional(o["fridge_1"], "in front of"),
        "left": areas.directional(o["table_1"], "to the left of"),
        "behind": areas.directional(o["chair_1"], "behind"),
        "adjacent": areas.adjacent_to(o["table_1"]),
        "close": areas.close_to(o["cup_1"]),
        "interact": areas.to_interact_with(o["fridge_1"]),
        "between": areas.between(o["fridge_1"], o["table_1"]),
        "both": areas.close_to(o["table_1"]).intersect(areas.directional(o["chair_1"], "behind")),
        "either": areas.adjacent_to(o["fridge_1"]).union(
            areas.directional(o["couch_1"], "in front of")
        ),
    }[name]


AREA_NAMES = [
    "front",
    "left",
    "behind",
    "adjacent",
    "close",
    "interact",
    "between",
    "both",
    "either",
]


@settings(max_examples=40, deadline=None)
@given(
    st.sampled_from(AREA_NAMES),
    st.integers(0, 2**31),
    st.lists(st.tuples(st.floats(0.5, 5.5), st.floats(0.5, 5.5)), max_size=3),
)
def test_samples_lie_in_the_area_on_free_floor_away_from_others(
    name: str, seed: int, avoid: list[tuple[float, float]]
) -> None:
    area = _area(name)
    c = Constraints(avoid=tuple(avoid))
    try:
        placement = sample_position(area, FLOOR, c, np.random.default_rng(seed))
    except UnsatisfiableAreaError:
        assert avoid  # only the other characters can make these areas unsatisfiable
        return
    p = np.array([placement.position])
    assert area.contains(p)[0]
    assert FLOOR.free(p)[0]
    assert FLOOR.colliding_objects(placement.position) == []
    for q in avoid:
        assert np.linalg.norm(p[0] - np.array(q)) >= 0.5 - 1e-9
    again = sample_position(area, FLOOR, c, np.random.default_rng(seed))
    assert again == placement  # deterministic for a seed


def test_area_semantics_and_distances() -> None:
    o = ROOM.by_name
    front = areas.directional(o["fridge_1"], "in front of")
    assert front.contains(
        np.array([[1.0, 1.0], [1.0, 2.2], [1.0, 2.3], [1.5, 1.0], [1.0, 0.4]])
    ).tolist() == [True, True, False, False, False]
    adjacent = areas.adjacent_to(o["table_1"])
    assert adjacent.contains(np.array([[3.0, 3.85], [3.0, 3.95]])).tolist() == [True, False]
    between = areas.between(o["fridge_1"], o["table_1"])
    assert between.contains(np.array([[2.0, 1.7], [2.0, 2.7], [0.5, 0.0]])).tolist() == [
        True,
        False,
        False,
    ]
    assert front.intersect(adjacent).description == "in front of fridge_1 && adjacent to table_1"
    assert (
        front.union(adjacent).intersect(between).description
        == "(in front of fridge_1 || adjacent to table_1) && between fridge_1 and table_1"
    )
    assert areas.Area.sandbox_attributes == frozenset({"description", "intersect", "union"})


def test_seats_are_exact_and_face_the_seat_front() -> None:
    chair = ROOM.by_name["chair_1"]
    placement = sample_position(
        areas.to_sit_on(chair), FLOOR, Constraints(), np.random.default_rng(0)
    )
    assert placement.seat == "chair_1"
    assert np.allclose(placement.position, chair.seat_point())
    assert placement.seat_facing == pytest.approx(chair.facing)
    # the seat is taken: by object, or by a character sitting there
    for c in (
        Constraints(taken_objects=frozenset({"chair_1"})),
        Constraints(avoid=(tuple(chair.seat_point()),)),
    ):
        with pytest.raises(UnsatisfiableAreaError, match="no free seat"):
            sample_position(areas.to_sit_on(chair), FLOOR, c, np.random.default_rng(0))


def test_couch_has_several_slots_and_fills_up() -> None:
    couch = ROOM.by_name["couch_1"]
    slots = areas.seat_slots(couch)
    assert len(slots) == 3
    taken: list[tuple[float, float]] = []
    for seed in range(3):
        p = sample_position(
            areas.to_sit_on(couch),
            FLOOR,
            Constraints(avoid=tuple(taken)),
            np.random.default_rng(seed),
        )
        assert p.seat == "couch_1" and p.position not in taken
        taken.append(p.position)
    with pytest.raises(UnsatisfiableAreaError):
        sample_position(
            areas.to_sit_on(couch), FLOOR, Constraints(avoid=tuple(taken)), np.random.default_rng(9)
        )


def test_unsatisfiable_areas_raise_never_a_random_point() -> None:
    o = ROOM.by_name
    # entirely under furniture: near the cup that stands on the table
    with pytest.raises(UnsatisfiableAreaError, match=r"no free floor|empty"):
        sample_position(
            areas.within_distance(o["cup_1"], 0.2, "close to"),
            FLOOR,
            Constraints(),
            np.random.default_rng(0),
        )
    # two areas that do not overlap
    disjoint = areas.directional(o["fridge_1"], "in front of").intersect(
        areas.directional(o["couch_1"], "in front of")
    )
    with pytest.raises(UnsatisfiableAreaError, match="empty"):
        sample_position(disjoint, FLOOR, Constraints(), np.random.default_rng(0))
    # behind the fridge is outside the room
    with pytest.raises(UnsatisfiableAreaError):
        sample_position(
            areas.directional(o["fridge_1"], "behind"),
            FLOOR,
            Constraints(),
            np.random.default_rng(0),
        )
    # other characters fill the area
    crowd = tuple((x, y) for x in np.arange(0.0, 2.5, 0.3) for y in np.arange(0.7, 2.6, 0.3))
    with pytest.raises(UnsatisfiableAreaError, match="another character"):
        sample_position(
            areas.directional(o["fridge_1"], "in front of"),
            FLOOR,
            Constraints(avoid=crowd),
            np.random.default_rng(0),
        )


def test_group_members_are_kept_near_each_other() -> None:
    area = areas.close_to(ROOM.by_name["table_1"])
    first = sample_position(area, FLOOR, Constraints(), np.random.default_rng(1))
    for seed in range(10):
        p = sample_position(
            area,
            FLOOR,
            Constraints(avoid=(first.position,), group=(first.position,)),
            np.random.default_rng(seed),
        )
        d = float(np.linalg.norm(np.subtract(p.position, first.position)))
        assert 0.5 <= d <= 1.5


def test_seeds_give_different_positions() -> None:
    area = areas.close_to(ROOM.by_name["table_1"])
    positions = {
        sample_position(area, FLOOR, Constraints(), np.random.default_rng(s)).position
        for s in range(10)
    }
    assert len(positions) >= 8


# ----- world view from the reference test cases ------------------------------------------------
def test_world_view_reads_all_reference_cases(scenes: dict[str, Scene]) -> None:
    assert len(CASES) == 40
    for path in CASES:
        data = json.loads(path.read_text())
        scene = scenes[data["scene_name"]]
        world = world_view_from_reference_case(data, scene)
        assert world.names == [s["name"] for s in data["current_states"]]
        floor = FloorMap(scene)
        for state, raw in zip(world.characters, data["current_states"], strict=True):
            assert state.action == raw["current_action"]
            looping = any(
                e["state"] == "looping" and state.name in e["characters"]
                for e in data["planning_history"]
            )
            assert state.busy == (raw["state"] != "idle" and not looping)
            if not raw["position"]:
                assert state.position is None
                continue
            assert state.position is not None and state.facing is not None
            text = raw["position"][0]
            if text.startswith(("sit on", "lie on")):
                seat_name = text.split()[-1]
                assert state.seat == seat_name
                assert world.objects_in_use[seat_name] in {
                    c.name for c in world.characters if c.seat == seat_name
                }
                seat = scene.by_name[seat_name]
                assert float(point_footprint_distance(seat, np.array(state.position))) == 0.0
            else:
                assert state.seat is None
                assert floor.free(np.array([state.position]))[0]
                anchor = scene.by_name[text.split()[-1]]
                assert (
                    float(point_footprint_distance(anchor, np.array(state.position))) <= 1.5 + 1e-9
                )  # directional reach


def test_world_view_case_0_details(scenes: dict[str, Scene]) -> None:
    data = json.loads((REF / "benchmark/test_cases/0_OA/testcase_0.json").read_text())
    world = world_view_from_reference_case(data, scenes["House"])
    assert world.objects_in_use == {
        "chair_2": "Norma",
        "chair_6": "Jason",
        "coffee_maker_1": "Deanna",
    }
    jason = world.character("Jason")
    assert jason is not None and jason.busy and jason.seat == "chair_6"
    ryan = world.character("Ryan")
    assert ryan is not None and ryan.position is None and not ryan.busy
    # points to avoid: every placed character except those excluded
    assert len(world.points_to_avoid()) == 4
    assert len(world.points_to_avoid({"Jason"})) == 3
    assert world_view_from_reference_case(data, scenes["House"]) == world  # deterministic


@pytest.mark.parametrize(
    "data, match",
    [
        ([], "expected a JSON object"),
        ({"current_states": 3}, "current_states"),
        ({"current_states": [{"name": ""}]}, "current_states\\[0\\]"),
        ({"current_states": [{"name": "A", "position": ["sit on throne_1"]}]}, "throne_1"),
        (
            {"current_states": [{"name": "A", "position": ["hovering near fridge_1"]}]},
            "unknown position",
        ),
        ({"current_states": [{"name": "A", "position": "sit on chair_1"}]}, "list of strings"),
        (
            {"current_states": [], "planning_history": [{"details": [{"x": 1}]}]},
            "planning_history\\[0\\]",
        ),
    ],
)
def test_bad_reference_cases_raise_typed_errors(
    scenes: dict[str, Scene], data: object, match: str
) -> None:
    with pytest.raises(ReferenceCaseError, match=match):
        world_view_from_reference_case(cast(dict[str, Any], data), scenes["House"])  # ill-typed JSON on purpose


def test_area_from_text(scenes: dict[str, Scene]) -> None:
    house = scenes["House"]
    assert area_from_text("between chair_1 and chair_3", house).anchors == ("chair_1", "chair_3")
    assert area_from_text("to the left of chair_4", house).description == "to the left of chair_4"
    assert area_from_text("lie on couch_1", house).seats


def test_combining_is_bounded_and_typed() -> None:
    from storyteller.tools.areas import MAX_PARTS
    from storyteller.tools.errors import ToolArgumentError

    a = areas.close_to(ROOM.by_name["table_1"])
    combined = a
    for _ in range(MAX_PARTS - 1):
        combined = combined.union(a)
    assert combined.parts == MAX_PARTS
    with pytest.raises(ToolArgumentError, match="at most"):
        combined.intersect(a)
    with pytest.raises(ToolArgumentError, match="expects an Area"):
        a.union(cast(areas.Area, "table_1"))  # a name instead of an Area on purpose, as a program might pass

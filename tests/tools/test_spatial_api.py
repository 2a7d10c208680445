"""Spatial API: queries, areas, handles, typed errors, and programs run through the sandbox."""

from __future__ import annotations

import inspect
import json
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene
from storyteller.tools.areas import Area
from storyteller.tools.character_states import WorldView, world_view_from_reference_case
from storyteller.tools.errors import (
    BlockedPositionError,
    EventProgramError,
    ToolArgumentError,
    UnknownActionError,
    UnknownCharacterError,
    UnknownObjectError,
    UnsatisfiableAreaError,
)
from storyteller.tools.event_program import run_event_program
from storyteller.tools.position_sampling import FloorMap
from storyteller.tools.scene_graph import build_scene_graph
from storyteller.tools.spatial_api import MAX_NEW_CHARACTERS, CharacterHandle, SpatialAPI
from tests.support.reference import REFERENCE as REF
from tests.support.reference import reference_or_skip


@pytest.fixture(scope="module")
def house() -> Scene:
    return load_scene(reference_or_skip() / "configs" / "scenes" / "House")


@pytest.fixture(scope="module")
def case0(house: Scene) -> tuple[WorldView, list[str]]:
    data = json.loads((REF / "benchmark/test_cases/0_OA/testcase_0.json").read_text())
    return world_view_from_reference_case(data, house), data["action_labels"]


@pytest.fixture()
def api(house: Scene, case0: tuple[WorldView, list[str]]) -> SpatialAPI:
    world, labels = case0
    return SpatialAPI(house, build_scene_graph(house), world, labels)


def test_namespace_has_documented_functions(api: SpatialAPI) -> None:
    """Which functions exist is stated once, by SpatialAPI (tests/agents/test_spatial_api_listing.py)."""
    ns = api.namespace()
    assert set(ns) == {f.name for f in SpatialAPI.functions()}
    for name, fn in ns.items():
        doc = inspect.getdoc(fn)
        assert doc and len(doc) < 300, name
    assert CharacterHandle.sandbox_attributes == {
        "name",
        "set_position",
        "set_orientation",
        "set_target_action",
    }
    assert "predicate" not in Area.sandbox_attributes


def test_object_queries_on_house(api: SpatialAPI) -> None:
    ns = api.namespace()
    assert ns["get_object_supporting"]("coffee_maker_1") == "cabinet_1"
    assert ns["get_object_supporting"]("cabinet_1") is None
    assert sorted(ns["get_objects_supported_by"]("cabinet_1")) == ["coffee_maker_1", "microwave_1"]
    assert ns["get_objects_supported_by"]("table_1", "tv") == ["tv_1"]
    assert set(ns["get_objects_in_front_of"]("couch_1")) == {"table_3"}
    assert ns["get_objects_left_of"]("cabinet_1") == ["dishwasher_1"]
    assert ns["get_objects_right_of"]("cabinet_1") == ["fridge_1"]
    assert ns["get_objects_behind"]("loudspeaker_1") == ["tv_1"]
    assert set(ns["get_objects_associated_with"]("table_4", "chair")) == {
        "chair_2",
        "chair_4",
        "chair_5",
        "chair_6",
    }
    assert "toaster_1" in ns["get_objects_associated_with"]("table_4")
    assert ns["get_objects_associated_with"]("toaster_1") == ["table_4"]
    assert ns["get_objects_between"]("chair_1", "chair_3") == ["table_3"]
    close = ns["get_objects_close_to"]("table_3")
    assert set(close) == {"couch_1", "potted_plant_2", "chair_1", "chair_3"}
    assert ns["get_closest_object"]("couch_1", "chair") == "chair_3"
    assert ns["get_distance_between"]("coffee_maker_1", "cabinet_1") == 0.0
    assert ns["get_distance_between"]("chair_1", "table_3") > 0.3
    assert ns["is_object_of_label"]("chair_3", "chair") and not ns["is_object_of_label"](
        "chair_3", "table"
    )
    assert ns["is_object_occupied"]("chair_6") and ns["is_object_occupied"]("coffee_maker_1")
    assert not ns["is_object_occupied"]("chair_5")
    # results are copies: changing them changes nothing
    first = ns["get_objects_supported_by"]("cabinet_1")
    first.clear()
    assert ns["get_objects_supported_by"]("cabinet_1")


@pytest.mark.parametrize(
    "call, error, message",
    [
        (
            lambda ns: ns["get_area_close_to"]("chiar_1"),
            UnknownObjectError,
            "unknown object 'chiar_1'; did you mean 'chair_1'",
        ),
        (
            lambda ns: ns["get_area_close_to"]("spaceship_1"),
            UnknownObjectError,
            "not in this scene",
        ),
        (lambda ns: ns["get_area_close_to"]("Jason"), UnknownObjectError, "'Jason' is a character"),
        (lambda ns: ns["get_area_close_to"](3), ToolArgumentError, "object name string"),
        (
            lambda ns: ns["get_objects_close_to"]("table_3", "chiar"),
            UnknownObjectError,
            "did you mean 'chair'",
        ),
        (
            lambda ns: ns["get_character"]("Rian"),
            UnknownCharacterError,
            "unknown character 'Rian'; did you mean 'Ryan'?",
        ),
        (lambda ns: ns["get_character"]("chair_1"), UnknownCharacterError, "is an object"),
        (
            lambda ns: ns["get_character"]("Ryan").set_target_action("use_phone"),
            UnknownActionError,
            "did you mean 'use_smartphone'",
        ),
        (
            lambda ns: ns["get_character"]("Ryan").set_position([float("nan"), 1.0]),
            ToolArgumentError,
            "non-finite",
        ),
        (
            lambda ns: ns["get_character"]("Ryan").set_position([float("inf"), 1.0]),
            ToolArgumentError,
            "non-finite",
        ),
        (
            lambda ns: ns["get_character"]("Ryan").set_position([True, 1.0]),
            ToolArgumentError,
            "Area or \\[x, y\\]",
        ),
        (
            lambda ns: ns["get_character"]("Ryan").set_position("table_3"),
            ToolArgumentError,
            "Area or \\[x, y\\]",
        ),
        (
            lambda ns: ns["get_character"]("Ryan").set_position([99.0, 1.0]),
            ToolArgumentError,
            "outside the scene",
        ),
        (
            lambda ns: ns["get_character"]("Ryan").set_orientation("fridge"),
            UnknownObjectError,
            "did you mean 'fridge_1'",
        ),
        (lambda ns: ns["get_area_to_sit_on"]("table_4"), ToolArgumentError, "not a seat"),
        (lambda ns: ns["get_area_in_front_of"]("table_3"), ToolArgumentError, "no front"),
        (
            lambda ns: ns["get_area_between"]("chair_1", "chair_1"),
            ToolArgumentError,
            "different places",
        ),
        (
            lambda ns: ns["get_intersected_area"](ns["get_area_close_to"]("table_3"), "table_4"),
            ToolArgumentError,
            "Area values",
        ),
        (
            lambda ns: ns["get_character"]("Ryan").set_position(
                ns["get_area_to_sit_on"]("chair_6")
            ),
            UnsatisfiableAreaError,
            "no free seat",
        ),
    ],
)
def test_bad_calls_raise_typed_errors_with_feedback(
    api: SpatialAPI, call: Callable[[dict[str, Callable[..., Any]]], object], error: type[Exception], message: str
) -> None:
    with pytest.raises(error, match=message):
        call(api.namespace())


def test_effects_are_collected_and_resolved_after_the_program(
    api: SpatialAPI, house: Scene
) -> None:
    ns = api.namespace()
    ryan = ns["get_character"]("Ryan")
    assert ns["get_character"]("Ryan") is ryan and ryan.name == "Ryan"
    ryan.set_position(ns["get_area_to_sit_on"]("chair_5"))
    ryan.set_target_action("eat")
    assert ns["is_object_occupied"]("chair_5")  # this program's own seat counts
    jorge = ns["get_character"]("Jorge")
    jorge.set_position(ns["get_area_close_to"]("table_4"))
    jorge.set_orientation("Ryan")
    plans = api.resolve(seed=7)
    assert [p.character for p in plans] == ["Ryan", "Jorge"]
    ryan_plan, jorge_plan = plans
    chair = house.by_name["chair_5"]
    assert ryan_plan.seat == "chair_5" and np.allclose(ryan_plan.position, chair.seat_point())
    assert ryan_plan.facing == pytest.approx(chair.facing) and ryan_plan.action == "eat"
    assert jorge_plan.action == "idle" and jorge_plan.area == "close to table_4"
    to_ryan = np.subtract(ryan_plan.position, jorge_plan.position)
    assert np.dot(to_ryan / np.linalg.norm(to_ryan), jorge_plan.facing) == pytest.approx(1.0)
    assert 0.5 <= np.linalg.norm(to_ryan) <= 1.5  # same event: near each other, not on top
    assert FloorMap(house).free(np.array([jorge_plan.position]))[0]
    assert api.resolve(seed=7) == plans  # deterministic for a seed


def test_second_character_cannot_take_the_same_seat(api: SpatialAPI) -> None:
    """Sent to one chair, the second member of the event gets the nearest free chair (the group
    sits together), never the same one; with no such chair near, the area is refused."""
    from storyteller.tools import position_sampling

    ns = api.namespace()
    ns["get_character"]("Ryan").set_position(ns["get_area_to_sit_on"]("chair_4"))
    ns["get_character"]("Jorge").set_position(ns["get_area_to_sit_on"]("chair_4"))
    ryan, jorge = api.resolve(seed=0)
    assert ryan.seat == "chair_4" and jorge.seat is not None and jorge.seat.startswith("chair_") and jorge.seat != "chair_4"
    try:
        position_sampling.NEIGHBOUR_SEAT_M = 0.0
        with pytest.raises(UnsatisfiableAreaError, match="Jorge: no free seat"):
            api.resolve(seed=0)
    finally:
        position_sampling.NEIGHBOUR_SEAT_M = 1.5


def test_moving_a_seated_character_frees_its_own_seat(api: SpatialAPI) -> None:
    ns = api.namespace()
    jason = ns["get_character"]("Jason")
    jason.set_position(ns["get_area_to_sit_on"]("chair_6"))  # he already sits there
    assert api.resolve(seed=0)[0].seat == "chair_6"


def test_orientation_targets(api: SpatialAPI) -> None:
    ns = api.namespace()
    ryan = ns["get_character"]("Ryan")
    ryan.set_position([2.0, 5.0])
    ryan.set_orientation([3.0, 5.0])
    assert api.resolve(seed=0)[0].facing == pytest.approx((1.0, 0.0))
    ryan.set_orientation(ns["get_area_close_to"]("fridge_1"))
    facing = api.resolve(seed=0)[0].facing
    to_fridge = np.subtract(api.scene.by_name["fridge_1"].center[:2], (2.0, 5.0))
    assert facing == pytest.approx(
        tuple(to_fridge / np.linalg.norm(to_fridge))
    )  # the area's anchor
    plan = api.resolve(seed=0)[0]
    assert plan.position == (2.0, 5.0) and plan.area == "[2.00, 5.00]"


def test_new_characters_allowed_only_without_states(house: Scene) -> None:
    open_api = SpatialAPI(house)
    zed = open_api.namespace()["get_character"]("Zed")
    assert zed.name == "Zed" and open_api.resolve(seed=0) == []  # untouched handles plan nothing
    zed.set_target_action("dance")  # any label when none are given
    with pytest.raises(ToolArgumentError, match="no position"):
        open_api.resolve(seed=0)


# ----- through the sandbox -------------------------------------------------------------------
FREE_CHAIR = """
def parse_event():
    # Ryan sits on a free chair at the dining table and texts
    ryan = get_character("Ryan")
    chairs = get_objects_associated_with("table_4", "chair")
    free = [c for c in chairs if not is_object_occupied(c)]
    ryan.set_position(get_area_to_sit_on(free[0]))
    ryan.set_target_action("use_smartphone")
    return [ryan]
"""


def test_program_through_the_sandbox(house: Scene, case0: tuple[WorldView, list[str]]) -> None:
    world, labels = case0
    plans = run_event_program(house, FREE_CHAIR, world, seed=1, action_labels=labels)
    assert (
        len(plans) == 1
        and plans[0].seat in {"chair_4", "chair_5"}
        and plans[0].action == "use_smartphone"
    )


def test_failing_program_gives_no_plans_and_names_the_line(
    house: Scene, case0: tuple[WorldView, list[str]]
) -> None:
    world, labels = case0
    source = FREE_CHAIR.replace('"use_smartphone"', '"text_message"')
    with pytest.raises(UnknownActionError) as info:
        run_event_program(house, source, world, seed=1, action_labels=labels)
    assert info.value.line == 8 and "available: idle, drink" in info.value.feedback
    with pytest.raises(EventProgramError, match="did not position any character"):
        run_event_program(
            house, "def parse_event():\n    return []\n", world, seed=1, action_labels=labels
        )
    # a program may catch a tool error and fall back
    fallback = (
        "def parse_event():\n    a = get_character('Ryan')\n    try:\n        a.set_position(get_area_to_sit_on('chair_6'))\n"
        "    except ToolError:\n        a.set_position(get_area_close_to('table_4'))\n    return [a]\n"
    )
    plans = run_event_program(house, fallback, world, seed=2, action_labels=labels)
    assert plans[0].area == "close to table_4"


@pytest.mark.parametrize(
    "body",
    [
        "get_area_close_to('table_4').predicate",
        "get_area_close_to('table_4').seats",
        "get_character('Ryan')._api",
        "get_character('Ryan')._records",
        "get_area_close_to('table_4').contains([[1.0, 1.0]])",
    ],
)
def test_programs_reach_only_declared_attributes(
    house: Scene, case0: tuple[WorldView, list[str]], body: str
) -> None:
    world, labels = case0
    source = f"def parse_event():\n    x = {body}\n    get_character('Ryan').set_position(get_area_close_to('table_4'))\n"
    with pytest.raises(EventProgramError) as info:
        run_event_program(house, source, world, seed=0, action_labels=labels)
    assert not isinstance(info.value, ToolArgumentError)
    assert info.value.line == 2


def test_interacting_with_a_seat_sits_and_objects_on_furniture_are_reached_from_its_edge(
    api: SpatialAPI,
) -> None:
    from storyteller.tools.areas import inset_depth

    ns = api.namespace()
    assert ns["get_area_to_interact_with"]("chair_5").seats
    house = api.scene
    tv, stand = house.by_name["tv_1"], house.by_name["table_1"]
    assert 0.0 <= inset_depth(tv, stand) <= stand.depth
    ryan = ns["get_character"]("Ryan")
    ryan.set_position(ns["get_area_to_interact_with"]("tv_1"))
    plan = api.resolve(seed=3)[0]
    assert plan.area == "interact with tv_1" and plan.seat is None
    local = tv.to_local(np.array(plan.position))
    assert local[1] >= tv.depth / 2  # on the screen's side


# ----- explicit [x, y] positions ---------------------------------------------------------------
def _program(*lines: str) -> str:
    return "def parse_event():\n" + "".join(f"    {line}\n" for line in lines)


def test_raw_point_inside_furniture_is_refused_at_its_line(
    house: Scene, case0: tuple[WorldView, list[str]]
) -> None:
    world, labels = case0
    source = _program("r = get_character('Ryan')", "r.set_position([2.94, 3.0])")
    with pytest.raises(BlockedPositionError) as info:
        run_event_program(house, source, world, seed=0, action_labels=labels)
    assert info.value.line == 3
    assert info.value.feedback.startswith(
        "line 3: position [2.94, 3.00] for Ryan is inside table_4"
    )
    assert "get_area_close_to('table_4')" in info.value.feedback


def test_raw_point_against_furniture_or_the_edge_is_refused(api: SpatialAPI) -> None:
    ryan = api.namespace()["get_character"]("Ryan")
    table = api.scene.by_name["table_4"]
    beside = (table.center[0], table.center[1] + table.depth / 2 + 0.1)  # 0.1 m off its side
    with pytest.raises(BlockedPositionError, match=r"within 0\.25 m of table_4"):
        ryan.set_position(list(beside))
    with pytest.raises(BlockedPositionError, match="edge of the scene"):
        ryan.set_position([0.1, 5.0])
    assert api.resolve(seed=0) == []  # nothing was recorded


def test_raw_point_on_another_character_is_refused_naming_the_line(
    house: Scene, case0: tuple[WorldView, list[str]]
) -> None:
    world, labels = case0
    deanna = world.character("Deanna")
    assert deanna is not None and deanna.position is not None
    x, y = deanna.position
    source = _program(
        "r = get_character('Ryan')",
        f"r.set_position([{x + 0.2}, {y}])",
        "r.set_target_action('idle')"
        if "idle" in labels
        else f"r.set_target_action('{labels[0]}')",
    )
    with pytest.raises(BlockedPositionError) as info:
        run_event_program(house, source, world, seed=0, action_labels=labels)
    assert info.value.line == 3
    assert "for Ryan is 0.20 m from Deanna's position" in info.value.feedback


def test_many_characters_on_one_point_are_refused(house: Scene) -> None:
    source = _program(*(f"get_character('c{i}').set_position([2.0, 5.5])" for i in range(5)))
    with pytest.raises(BlockedPositionError) as info:
        run_event_program(house, source, WorldView(), seed=0)
    assert info.value.line == 3  # the second character on the point
    assert "for c1 is 0.00 m from c0's planned position" in info.value.feedback


def test_raw_points_half_a_metre_apart_are_accepted(house: Scene) -> None:
    source = _program(
        "get_character('a').set_position([2.0, 5.0])", "get_character('b').set_position([2.0, 5.5])"
    )
    plans = run_event_program(house, source, WorldView(), seed=0)
    assert [p.position for p in plans] == [(2.0, 5.0), (2.0, 5.5)]


def test_area_placements_keep_clear_of_later_raw_points(house: Scene) -> None:
    # 'a' samples first; 'b' asks for an exact point inside the same area afterwards.
    # The point is inside the area, near where 'a' lands for most seeds if it ignores 'b'.
    for seed in range(10):
        source = _program(
            "get_character('a').set_position(get_area_to_interact_with('fridge_1'))",
            "get_character('b').set_position([4.34, 1.26])",
        )
        a, b = run_event_program(house, source, WorldView(), seed=seed)
        assert np.hypot(a.position[0] - 4.34, a.position[1] - 1.26) >= 0.5 - 1e-9
        assert b.position == (4.34, 1.26)


def test_raw_point_may_take_the_spot_of_a_character_who_moves_away(
    house: Scene, case0: tuple[WorldView, list[str]]
) -> None:
    world, _labels = case0
    deanna = world.character("Deanna")
    assert deanna is not None and deanna.position is not None
    x, y = deanna.position
    source = _program(
        f"get_character('Ryan').set_position([{x}, {y}])",
        "get_character('Deanna').set_position(get_area_close_to('table_1'))",
    )
    plans = {p.character: p for p in run_event_program(house, source, world, seed=0)}
    assert plans["Ryan"].position == (x, y)
    # ...but not of one who is touched and stays put
    source = _program(
        f"get_character('Ryan').set_position([{x}, {y}])",
        "get_character('Deanna').set_orientation('fridge_1')",
    )
    with pytest.raises(BlockedPositionError, match="from Deanna's position"):
        run_event_program(house, source, world, seed=0)


def test_characters_outside_the_roster_and_too_many_new_ones(
    house: Scene, case0: tuple[WorldView, list[str]]
) -> None:
    world, _labels = case0
    with pytest.raises(UnknownCharacterError, match="unknown character 'Zoe'"):
        run_event_program(
            house, _program("get_character('Zoe').set_position([2.0, 5.5])"), world, seed=0
        )
    many = _program(
        "hs = [get_character(f'c{i}') for i in range(MAX)]".replace("MAX", str(MAX_NEW_CHARACTERS)),
        "hs[0].set_position([2.0, 5.5])",
        "get_character('c0')",  # a known handle again is fine
        "get_character('one_too_many')",
    )
    with pytest.raises(ToolArgumentError, match=f"at most {MAX_NEW_CHARACTERS} characters") as info:
        run_event_program(house, many, WorldView(), seed=0)
    assert info.value.line == 5


@pytest.mark.parametrize(
    "call",
    [
        "get_character([0] * 20000)",
        "get_area_to_sit_on(['a' * 20000] * 90)",
        "get_character('x').set_orientation('a' * 20000)",
        "get_objects_close_to('chair_1', 'a' * 20000)",
        "get_character('a' * 20000)",
        "get_character('two\\nlines')",
        "get_character('x').set_target_action('a' * 20000)",
        "get_character('x').set_position([2**1100, 1.0])",
    ],
)
def test_huge_or_odd_arguments_give_short_typed_errors(house: Scene, call: str) -> None:
    with pytest.raises(EventProgramError) as info:
        run_event_program(house, _program(call), WorldView(), seed=0)
    assert isinstance(info.value, ToolArgumentError | UnknownObjectError), info.value.feedback
    assert len(info.value.feedback) <= 520 and "\n" not in info.value.feedback

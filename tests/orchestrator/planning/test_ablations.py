"""The paper's ablations as variants of the planning graph, with scripted LLM replies and the
real sandboxed event-program runner on a bundled scene: one planning step each, driven by
the plan job (``storyteller.orchestrator.session.plan_job.run_plan``) as ``storyteller plan`` drives it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from storyteller.agents.ablations.descriptions import object_list_description, scene_graph_description
from storyteller.agents.ablations.direct import (
    DirectPlans,
    blocked_positions,
    check_direct_reply,
    direct_program,
)
from storyteller.agents.messages import CharacterStatus, Event, ParsedEvent, PlanningFailure, SceneDescription
from storyteller.orchestrator.planning.ablation_graph import Ablation
from storyteller.orchestrator.planning.kinds import PlannerKind
from storyteller.orchestrator.session.plan_job import StepOutcome, run_plan
from storyteller.orchestrator.session.roster import RosterWorld, initial_roster
from storyteller.sim.scene.bundled import resolve_scene
from storyteller.tools.errors import BlockedPositionError, ToolArgumentError
from tests.support.scripted_llm import ScriptedLLM

SCENE = resolve_scene("home")
DESCRIPTION = SceneDescription(scene="home", text="- kitchen: coffee_maker_1, fridge_1")


async def plan_one(
    port: ScriptedLLM,
    planner: PlannerKind = "event",
    roster: tuple[CharacterStatus, ...] | None = None,
    instruction: str = "Ava makes coffee.",
    max_retries: int = 3,
) -> StepOutcome:
    """One planning step of the ``planner`` variant of the graph, from a preset description."""
    result = await run_plan(
        scene=SCENE, port=port, instruction=instruction, events=1, seed=4, runs_db=":memory:", thread_id="t",
        roster=roster or initial_roster(SCENE, 2, seed=1), description=DESCRIPTION,
        ablation=Ablation(planner=planner), max_retries=max_retries,
    )
    ((index, outcome),) = result.outcomes
    assert index == 0
    return outcome


COFFEE = (
    '```python\ndef parse_event():\n    a = get_character("Ava")\n'
    '    a.set_position(get_area_to_interact_with("coffee_maker_1"))\n'
    '    a.set_orientation("coffee_maker_1")\n    a.set_target_action("use_coffee_maker")\n```'
)
NARRATION = json.dumps({"reasoning": "r", "event": {"characters": ["Ava"], "activity": "make coffee with coffee_maker_1"}})


def test_description_ablations() -> None:
    listing = object_list_description(SCENE)
    assert listing.source == "object_list" and "coffee_maker_1: position [" in listing.text
    graph = scene_graph_description(SCENE)
    assert graph.source == "scene_graph" and "coffee_maker_1" in json.loads(graph.text)


async def test_event_driven_planner() -> None:
    port = ScriptedLLM([NARRATION, COFFEE])
    out = await plan_one(port)
    assert isinstance(out, ParsedEvent) and out.plans[0].action == "use_coffee_maker"
    assert [r.node for r in port.requests] == ["narrator", "event_parser"]


async def test_unified_planner_without_events() -> None:
    port = ScriptedLLM([COFFEE])
    out = await plan_one(port, "unified")
    assert isinstance(out, ParsedEvent) and out.event.characters == ("Ava",)
    assert "use_coffee_maker" in out.event.activity
    assert port.requests[0].node == "planner" and "Instruction: Ava makes coffee." in port.requests[0].messages[1].content


async def test_unified_planner_sums_up_four_characters_within_the_event_s_length() -> None:
    """Four characters' plans summed up run past an event's 160 characters: the activity is cut
    at a word, not refused (a sweep run once failed on this). Their action is a shared one, so
    no character is refused an object another one uses."""
    roster = initial_roster(SCENE, 4, seed=1)
    names = [c.name for c in roster]
    blocks = "".join(
        f'    c = get_character("{n}")\n    c.set_target_action("listen_to_music")\n'
        f'    c.set_position(get_area_adjacent_to("{obj}"))\n    c.set_orientation("{obj}")\n'
        for n, obj in zip(names, ("record_player_1", "potted_plant_2", "potted_plant_1", "floor_lamp_1"), strict=True)
    )
    port = ScriptedLLM([f"```python\ndef parse_event():\n{blocks}```"])
    out = await plan_one(port, "unified", roster, instruction="Everyone listens to the music.")
    assert isinstance(out, ParsedEvent) and out.event.characters == tuple(names)
    assert len(out.event.activity) <= 160 and out.event.activity.endswith("...")


async def test_unified_planner_rejects_busy_characters_and_can_wait() -> None:
    roster = initial_roster(SCENE, 2, seed=1)
    roster = (roster[0].model_copy(update={"busy": True}), roster[1])
    port = ScriptedLLM([COFFEE, "```python\ndef parse_event():\n    pass\n```"])
    out = await plan_one(port, "unified", roster, instruction="Someone makes coffee.")
    assert out is None and len(port.requests) == 2
    assert "Ava is busy" in port.requests[1].messages[-1].content


async def test_direct_inference_outputs_coordinates() -> None:
    x, y = 1.0, 1.0
    # find a free floor point near the coffee maker from the scene itself
    from storyteller.tools.position_sampling import FloorMap

    floor = FloorMap(SCENE)
    cm = SCENE.get("coffee_maker_1")
    for dx in (0.0, 0.6, -0.6, 1.0, -1.0):
        for dy in (0.6, -0.6, 1.0, -1.0, 0.0):
            if floor.free(np.array([[cm.center[0] + dx, cm.center[1] + dy]]))[0]:
                x, y = cm.center[0] + dx, cm.center[1] + dy
                break
        else:
            continue
        break
    coords = json.dumps({"plans": [{"character": "Ava", "action": "use_coffee_maker", "x": x, "y": y, "look_at": "coffee_maker_1"}]})
    port = ScriptedLLM([NARRATION, coords])
    out = await plan_one(port, "direct")
    assert isinstance(out, ParsedEvent), out
    assert out.plans[0].position == pytest.approx((x, y))
    req = port.requests[1]
    assert req.json_schema is not None, "the coordinates are schema-constrained"
    schema = req.json_schema["properties"]["plans"]
    assert schema["maxItems"] == 1 and schema["items"]["properties"]["character"]["enum"] == ["Ava"]
    assert "coffee_maker_1: position [" in req.messages[0].content  # coordinates available to the model


def test_direct_program_quotes_names_safely() -> None:
    plans = DirectPlans.model_validate({"plans": [{"character": 'A"); import os; ("', "action": "idle", "x": 1.0, "y": 2.0, "look_at": ""}]})
    program = direct_program(plans)
    compile(program, "<direct>", "exec")
    assert "import os" in program.splitlines()[1] and program.splitlines()[1].count('"') == 4


async def test_failures_are_outcomes_not_exceptions() -> None:
    port = ScriptedLLM([json.dumps({"reasoning": "", "event": {"characters": ["Zed"], "activity": "x"}})] * 2)
    out = await plan_one(port, max_retries=1)
    assert isinstance(out, PlanningFailure) and out.node == "narrator" and out.attempts == 2


def test_direct_program_turns_a_point_on_a_seat_into_sitting() -> None:
    chair = SCENE.get("chair_1").center
    plans = DirectPlans.model_validate(
        {"plans": [{"character": "Ava", "action": "eat", "x": chair[0], "y": chair[1], "look_at": "table_1"}]}
    )
    assert 'set_position(get_area_to_sit_on("chair_1"))' in direct_program(plans, SCENE)
    assert "set_position([" in direct_program(plans)  # without the scene: plain coordinates


def test_direct_points_near_other_characters_or_off_the_floor_are_blocked() -> None:
    roster = initial_roster(SCENE, 2, seed=1)
    world = RosterWorld().world_view(roster)
    assert roster[1].position is not None
    bx, by = roster[1].position
    near_ben = DirectPlans.model_validate({"plans": [{"character": "Ava", "action": "idle", "x": bx + 0.2, "y": by, "look_at": ""}]})
    (problem,) = blocked_positions(SCENE, world, near_ben)
    assert problem.startswith(f"Ava at [{bx + 0.2:.2f}, {by:.2f}] is 0.20 m from Ben")
    x0 = SCENE.bounds_min[0]
    edge = DirectPlans.model_validate({"plans": [{"character": "Ava", "action": "idle", "x": x0 + 0.05, "y": by, "look_at": ""}]})
    assert any("off the free floor" in p or "inside" in p for p in blocked_positions(SCENE, world, edge))
    far = DirectPlans.model_validate({"plans": [{"character": "Ben", "action": "idle", "x": bx, "y": by, "look_at": ""}]})
    assert blocked_positions(SCENE, world, far) == []  # Ben may stay where he is


def test_a_blocked_direct_point_raises_the_spatial_apis_error_so_one_except_catches_both() -> None:
    roster = initial_roster(SCENE, 2, seed=1)
    world = RosterWorld().world_view(roster)
    table = SCENE.get("table_1").center
    reply = json.dumps({"plans": [{"character": "Ava", "action": "idle", "x": table[0], "y": table[1], "look_at": ""}]})
    with pytest.raises(ToolArgumentError) as info:  # the spatial API's base class catches the ablation's error
        check_direct_reply(reply, scene=SCENE, event=Event(characters=("Ava",), activity="stand"), world=world,
                           seed=0, action_labels=("idle",))
    assert type(info.value) is BlockedPositionError and info.value.kind == "blocked_position"
    assert "inside table_1" in info.value.feedback

"""Commands and reports between the planner and the world (storyteller.sim.world.events)."""

from __future__ import annotations

import math

import pytest
from pydantic import TypeAdapter, ValidationError

from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.world.events import (
    AssignEvent,
    Assignment,
    Command,
    EventFailure,
    ReleaseCharacters,
    StepOutput,
)
from storyteller.tools.character_states import CharacterPlan


def _scene() -> Scene:
    chair = SceneObject(name="chair_1", label="chair", idx=1, center=(2.0, 2.0, 0.45), size=(0.5, 0.5, 0.9),
                        facing=(0.0, 1.0), has_facing=True, sit_offset_horizontal=0.1, sit_offset_vertical=0.45)
    return Scene(name="t", bounds_min=(0.0, 0.0), bounds_max=(4.0, 4.0), objects=(chair,))


def test_assignment_normalises_facing_and_rejects_bad_input() -> None:
    a = Assignment(character="ann", action="drink", target_xy=(1.0, 2.0), facing_xy=(0.0, 2.0))
    assert a.facing_xy == (0.0, 1.0)
    assert math.isclose(a.facing_angle, math.pi / 2)
    with pytest.raises(ValidationError, match="non-zero"):
        Assignment(character="ann", action="drink", target_xy=(1.0, 2.0), facing_xy=(0.0, 0.0))
    with pytest.raises(ValidationError, match="did you mean 'drink'"):
        Assignment(character="ann", action="drnk", target_xy=(1.0, 2.0), facing_xy=(1.0, 0.0))
    with pytest.raises(ValidationError, match="unknown action label 'wave@seated'"):
        Assignment(character="ann", action="wave", target_xy=(1.0, 2.0), facing_xy=(1.0, 0.0), seat="chair_1")
    with pytest.raises(ValidationError, match="own partner"):
        Assignment(character="ann", action="chat", target_xy=(1.0, 2.0), facing_xy=(1.0, 0.0), partners=("ann",))
    with pytest.raises(ValidationError):
        Assignment(character="ann", action="drink", target_xy=(math.nan, 2.0), facing_xy=(1.0, 0.0))
    with pytest.raises(ValidationError):
        Assignment.model_validate(  # as untyped data arrives: an unknown field
            {"character": "ann", "action": "drink", "target_xy": (1.0, 2.0), "facing_xy": (1.0, 0.0), "mood": "happy"}
        )
    with pytest.raises(ValidationError):
        a.__setattr__("character", "bob")  # assigning to a frozen model is what is tested


def test_event_rejects_a_character_assigned_twice() -> None:
    a = Assignment(character="ann", action="drink", target_xy=(1.0, 2.0), facing_xy=(1.0, 0.0))
    with pytest.raises(ValidationError, match="assigned twice"):
        AssignEvent(event_id="e", assignments=(a, a))
    with pytest.raises(ValidationError):
        AssignEvent(event_id="e", assignments=())


def test_from_plans_converts_planner_output_with_partners_and_seat_height() -> None:
    plans = [
        CharacterPlan(character="ann", action="chat", position=(2.0, 2.05), facing=(0.0, 1.0), area="sit on chair_1", seat="chair_1"),
        CharacterPlan(character="bob", action="chat", position=(2.0, 3.2), facing=(0.0, -1.0), area="in front of chair_1"),
    ]
    ev = AssignEvent.from_plans("e7", plans, scene=_scene())
    assert ev.characters == ("ann", "bob")
    ann, bob = ev.assignments
    assert ann.partners == ("bob",) and bob.partners == ("ann",)
    assert ann.seat == "chair_1" and ann.seat_height == pytest.approx(0.45)  # bottom 0.0 + offset 0.45
    assert bob.seat is None and bob.seat_height is None
    assert ann.target_xy == (2.0, 2.05) and bob.facing_xy == (0.0, -1.0)


def test_command_union_parses_by_kind() -> None:
    adapter = TypeAdapter(Command)
    cmd = adapter.validate_python({"kind": "release", "characters": ["ann"]})
    assert isinstance(cmd, ReleaseCharacters)
    cmd = adapter.validate_python({"kind": "assign_event", "event_id": "e", "assignments": [
        {"character": "ann", "action": "wave", "target_xy": [1, 1], "facing_xy": [1, 0]}]})
    assert isinstance(cmd, AssignEvent) and cmd.assignments[0].action == "wave"
    with pytest.raises(ValidationError):
        adapter.validate_python({"kind": "teleport", "characters": ["ann"]})


def test_reports_are_frozen_values() -> None:
    f = EventFailure(event_id="e", character="ann", reason="no_path", message="ann cannot reach it")
    out = StepOutput(frame=3, failures=(f,), available=("bob",))
    assert out.failures[0].reason == "no_path"
    with pytest.raises(ValidationError):
        EventFailure.model_validate({"event_id": "e", "character": "ann", "reason": "bored", "message": "x"})
    with pytest.raises(ValidationError):
        out.__setattr__("frame", 4)  # assigning to a frozen model is what is tested

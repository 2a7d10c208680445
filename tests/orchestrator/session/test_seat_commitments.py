"""A seated character sent to another seat: the planner sees the seat it is heading for as
taken, not the one it is leaving.

Before: the new assignment waits aside while the character stands up (``pending``), and the
planning request reported the old assignment's seat and target; the next step gave the new
seat to a second character (story suite, three office runs: two people in one chair for
1,488 frames).
"""

from __future__ import annotations

from storyteller.orchestrator.session.story_history import world_commitments, world_roster
from storyteller.sim.scene.bundled import resolve_scene
from storyteller.sim.world.events import AssignEvent, Assignment
from storyteller.sim.world.step import World, WorldConfig, step
from tests.support.stand_in_motion import RestPoseMotion


def _sit(name: str, seat: str, world: World, eid: str) -> AssignEvent:
    xy = tuple(float(v) for v in world.scene.by_name[seat].seat_point())
    return AssignEvent(
        event_id=eid,
        assignments=(
            Assignment(
                character=name, action="use_laptop", target_xy=(xy[0], xy[1]), facing_xy=(0.0, 1.0), seat=seat
            ),
        ),
    )


def test_a_seated_character_sent_elsewhere_commits_its_new_seat_at_once() -> None:
    scene = resolve_scene("office")
    world = World(
        scene,
        {"Ava": ((9.26, 0.269), 0.0), "Ben": ((9.322, 4.332), 0.0)},
        RestPoseMotion(record=False),
        config=WorldConfig(foot_ik=False),
    )
    step(world, [_sit("Ava", "chair_1", world, "e0")], world.dt)
    for _ in range(1800):
        step(world, (), world.dt)
        if world.characters["Ava"].seated and world.characters["Ava"].phase == "interacting":
            break
    assert world.characters["Ava"].seated, "Ava never sat down"
    assert world_commitments(world)[1] == {"chair_1": "Ava"}

    step(world, [_sit("Ava", "chair_2", world, "e1")], world.dt)  # still seated: she stands up first
    ava = world.characters["Ava"]
    assert ava.pending is not None and ava.event_id == "e1"
    targets, seats = world_commitments(world)
    assert seats == {"chair_2": "Ava"}
    goal = scene.by_name["chair_2"].seat_point()
    assert targets["Ava"] == (round(float(goal[0]), 3), round(float(goal[1]), 3))
    # the chair she is leaving still shows as hers while she sits on it
    assert {c.name: c.seat for c in world_roster(world, {})}["Ava"] == "chair_1"

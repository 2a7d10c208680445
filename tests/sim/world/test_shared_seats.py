"""Two people sent to one couch, or to two chairs at one table corner, both get to sit.

Before: a seated assignment walked to the seat object's one approach point whatever place on
the seat it named, and two chairs at a table corner shared an approach cell; the first body
parked there and the second waited until it counted as stuck (story suite: couch_1 in the
office, chair_1 and chair_3 in the restaurant).
"""

from __future__ import annotations

import numpy as np

from storyteller.sim.scene.bundled import resolve_scene
from storyteller.sim.world.events import AssignEvent, Assignment
from storyteller.sim.world.navigation import seat_place
from storyteller.sim.world.step import World, WorldConfig, step
from tests.support.stand_in_motion import RestPoseMotion


def _sit_together(scene_name: str, starts: dict[str, tuple[float, float]],
                  seats: dict[str, tuple[str, tuple[float, float], tuple[float, float]]]) -> World:
    scene = resolve_scene(scene_name)
    world = World(scene, {n: (p, 0.0) for n, p in starts.items()}, RestPoseMotion(record=True), config=WorldConfig(foot_ik=False))
    event = AssignEvent(event_id="sit", assignments=tuple(
        Assignment(character=n, action="chat", target_xy=xy, facing_xy=f, seat=seat, partners=tuple(set(seats) - {n}))
        for n, (seat, xy, f) in seats.items()))
    for _ in range(900):
        _, out = step(world, [event] if world.frame == 0 else (), world.dt)
        assert out.failures == ()
        if out.started_events:
            return world
    raise AssertionError("the members never all arrived")


def test_two_people_sit_side_by_side_on_one_couch() -> None:
    world = _sit_together("office", {"Ben": (9.26, 0.269), "Cleo": (9.322, 4.332)}, {
        "Ben": ("couch_1", (8.0, 7.41), (0.0, -1.0)), "Cleo": ("couch_1", (7.333, 7.41), (0.0, -1.0))})
    ben, cleo = world.characters["Ben"], world.characters["Cleo"]
    assert ben.target is not None and cleo.target is not None
    assert float(np.linalg.norm(np.subtract(ben.target.xy, cleo.target.xy))) >= 0.5
    for _ in range(120):  # both sit down, each on its own place
        step(world, (), world.dt)
    assert ben.seat_xy is not None and cleo.seat_xy is not None
    assert np.allclose(ben.seat_xy, (8.0, 7.41)) and np.allclose(cleo.seat_xy, (7.333, 7.41), atol=1e-6)


def test_two_chairs_at_one_table_corner_are_both_reached() -> None:
    world = _sit_together("restaurant", {"Ava": (3.0, 8.0), "Ben": (5.0, 8.0)}, {
        "Ava": ("chair_1", (1.8, 1.63), (0.0, 1.0)), "Ben": ("chair_3", (1.03, 2.4), (1.0, 0.0))})
    a, b = world.characters["Ava"].target, world.characters["Ben"].target
    assert a is not None and b is not None and a.cell != b.cell


def test_seat_place_is_the_seat_point_of_a_chair_and_the_nearest_place_on_a_couch() -> None:
    office = resolve_scene("office")
    chair, couch = office.by_name["chair_1"], office.by_name["couch_1"]
    assert seat_place(chair, (0.0, 0.0)) == tuple(float(v) for v in chair.seat_point())
    assert np.allclose(seat_place(couch, (7.333, 7.41)), (7.333, 7.41))
    assert np.allclose(seat_place(couch, (0.0, 7.41)), (7.3, 7.41))  # half a place inside the end


def test_a_group_larger_than_the_couch_sends_the_last_one_to_the_nearest_other_seat() -> None:
    from storyteller.sim.scene.bundled import load_bundled_scene
    from storyteller.tools.character_states import WorldView
    from storyteller.tools.event_program import run_event_program

    home = load_bundled_scene("home")  # couch_1 has three places; armchair_1 stands beside it
    program = "def parse_event():\n" + "".join(
        f'    c{i} = get_character("{n}")\n    c{i}.set_target_action("watch_tv")\n'
        f'    c{i}.set_position(get_area_to_sit_on("couch_1"))\n'
        for i, n in enumerate(["Ava", "Ben", "Cleo", "Dan"], 1)
    )
    plans = run_event_program(home, program, WorldView(), seed=0)
    assert [p.seat for p in plans] == ["couch_1", "couch_1", "couch_1", "armchair_1"]

"""A seat whose usual sitting point lies inside other furniture (a stool pushed into a plant's
leaves) is sat on at the nearest point of its own footprint clear of it, by the planner and by
the simulation alike; every other seat keeps its usual point.

Found on the authors' Office scene: ``stool_2``'s seat point is 0.32 m inside
``potted_plant_1``'s footprint, so every plan that sat someone on it collided."""

from __future__ import annotations

import numpy as np

from storyteller.benchmark.position_check import object_collision
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.world.navigation import seat_place
from storyteller.tools.areas import seat_slots
from storyteller.tools.character_states import WorldView
from storyteller.tools.event_program import run_event_program


def _obj(name: str, center: tuple[float, float, float], size: tuple[float, float, float],
         facing: tuple[float, float] = (0.0, 1.0), **kw: float) -> SceneObject:
    label, idx = name.rsplit("_", 1)
    return SceneObject(name=name, label=label, idx=int(idx), center=center, size=size, facing=facing,
                       has_facing=True, **kw)


STOOL = _obj("stool_1", (3.0, 3.0, 0.2), (0.7, 0.7, 0.4), facing=(0.0, -1.0), sit_offset_horizontal=0.3,
             sit_offset_vertical=0.4)
CHAIR = _obj("chair_1", (1.0, 4.5, 0.45), (0.45, 0.45, 0.9), sit_offset_horizontal=0.1, sit_offset_vertical=0.45)
PLANT = _obj("potted_plant_1", (3.0, 2.25, 1.0), (1.2, 1.2, 2.0))  # its leaves reach over the stool's front
ROOM = Scene(name="room", bounds_min=(0.0, 0.0), bounds_max=(6.0, 6.0), objects=(STOOL, CHAIR, PLANT))


def _sit(seat: str) -> tuple[float, float]:
    program = ('def parse_event():\n    c1 = get_character("Ava")\n    c1.set_target_action("eat")\n'
               f'    c1.set_position(get_area_to_sit_on("{seat}"))\n')
    (plan,) = run_event_program(ROOM, program, WorldView(), seed=0)
    assert plan.seat == seat
    return (float(plan.position[0]), float(plan.position[1]))


def test_the_usual_point_of_a_covered_seat_collides_and_the_planned_one_does_not() -> None:
    (slot,) = seat_slots(STOOL)
    assert object_collision(ROOM, np.array(slot.position), {"stool_1"}) is not None  # the scene is as described
    sat = _sit("stool_1")
    assert object_collision(ROOM, np.array(sat), {"stool_1"}) is None
    assert bool(STOOL.contains_xy(np.array(sat)))  # still on the stool
    assert float(np.linalg.norm(np.subtract(sat, slot.position))) < 0.5  # the nearest clear part of it


def test_a_seat_nobody_covers_keeps_its_usual_point_in_the_plan_and_the_simulation() -> None:
    (slot,) = seat_slots(CHAIR)
    assert _sit("chair_1") == slot.position
    assert seat_place(CHAIR, (0.0, 0.0), ROOM) == slot.position  # not sent off the chair either
    assert seat_place(CHAIR, (1.05, 4.5), ROOM) == slot.position  # on the chair, but nothing covers it


def test_the_simulation_sits_where_the_planner_moved_the_point() -> None:
    sat = _sit("stool_1")
    assert seat_place(STOOL, sat, ROOM) == sat
    assert seat_place(STOOL, sat) == tuple(float(v) for v in STOOL.seat_point())  # no scene: the usual point
    assert seat_place(STOOL, (0.0, 0.0), ROOM) == tuple(float(v) for v in STOOL.seat_point())  # off the stool

"""A seated body's legs stay out of the furniture around its seat (issue 25: body-furniture
penetration).

Before: a stool 5 cm from a bar counter's solid face was sat on facing the counter, with the
knees 12 cm and the feet 21-25 cm inside the counter's box (``restaurant_bar_drink``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from storyteller.orchestrator.cache_paths import motion_cache_dir
from storyteller.sim.body.skeleton import JOINT_INDEX
from storyteller.sim.motion.database import load_databases
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.world.events import AssignEvent, Assignment
from storyteller.sim.world.legroom import (
    along_way,
    feet_clear_of,
    is_backless,
    legroom_taken,
    sit_via,
    sitting_yaw,
)
from storyteller.sim.world.step import World, WorldConfig, step

LEG_JOINTS = ("left_knee", "right_knee", "left_ankle", "right_ankle", "left_foot", "right_foot")


def _box(name: str, label: str, center: tuple[float, float, float], size: tuple[float, float, float],
         facing: tuple[float, float] = (0.0, 1.0), seat: float = 0.0) -> SceneObject:
    return SceneObject(name=name, label=label, idx=1, center=center, size=size, facing=facing, has_facing=True,
                       sit_offset_vertical=seat)


COUNTER = _box("counter_1", "counter", (2.5, 3.0, 0.525), (3.0, 0.7, 1.05), facing=(0.0, -1.0))
STOOL = _box("stool_1", "stool", (2.5, 2.4, 0.375), (0.4, 0.4, 0.75), seat=0.75)  # front 5 cm from the counter


def _inside(obj: SceneObject, p: np.ndarray) -> float:
    """How deep (m) point ``p`` (3,) lies inside ``obj``'s box (negative: its distance outside)."""
    local = np.array([*obj.to_local(p[None, :2])[0], p[2] - obj.center[2]])
    q = np.abs(local) - np.array(obj.size) / 2.0
    outside = float(np.linalg.norm(np.maximum(q, 0.0)))
    return -outside if outside > 0 else float(-q.max())


def test_a_stool_against_a_counter_is_sat_on_turned_and_a_chair_or_open_stool_as_planned() -> None:
    planned = math.pi / 2  # towards the counter
    place = STOOL.seat_point()
    assert is_backless(STOOL)
    assert legroom_taken(STOOL, (COUNTER, STOOL), place, planned) > 0.2
    yaw = sitting_yaw(STOOL, (COUNTER, STOOL), place, planned)
    assert yaw is not None and legroom_taken(STOOL, (COUNTER, STOOL), place, yaw) == 0.0
    assert abs(math.remainder(yaw - planned, 2 * math.pi)) == pytest.approx(math.pi / 2)  # the least turn that clears
    for stood, away in (((1.9, 2.4), math.pi), ((3.1, 2.4), 0.0), ((2.5, 1.8), -math.pi / 2)):  # backs onto it
        assert sitting_yaw(STOOL, (COUNTER, STOOL), place, planned, stood) == pytest.approx(away)
    assert sitting_yaw(STOOL, (STOOL,), place, planned) is None  # nothing in front: as planned
    chair = _box("chair_1", "chair", (2.5, 2.4, 0.45), (0.45, 0.45, 0.9), seat=0.45)  # a back: never turned
    assert not is_backless(chair) and sitting_yaw(chair, (COUNTER, chair), chair.seat_point(), planned) is None
    table = _box("table_1", "table", (2.5, 2.9, 0.375), (1.2, 0.6, 0.75))  # its box under the top is legroom
    bench = _box("bench_1", "bench", (2.5, 2.4, 0.225), (1.0, 0.4, 0.45), seat=0.45)
    assert sitting_yaw(bench, (table, bench), bench.seat_point(), planned) is None


def test_a_foot_under_the_next_seat_moves_out_of_its_footprint() -> None:
    couch = _box("couch_1", "couch", (3.0, 2.0, 0.4), (2.0, 0.9, 0.8))
    ankles = np.array([[2.1, 2.0, 0.08], [1.9, 2.0, 0.08]])  # the first 0.1 m inside the couch's left end
    out = feet_clear_of(ankles, np.array([True, True]), STOOL, (couch, STOOL))
    assert out[0, 0] == pytest.approx(2.0 - 0.08) and out[0, 1] == pytest.approx(2.0)  # out by the least way
    assert np.array_equal(out[1], ankles[1])  # clear already: untouched
    assert np.array_equal(feet_clear_of(ankles, np.array([False, True]), STOOL, (couch, STOOL)), ankles)  # lifted
    toes = np.array([[0.0, 0.0, -0.05], [0.15, 0.0, -0.05]])  # the second foot points into the couch
    out = feet_clear_of(ankles, np.array([True, True]), STOOL, (couch, STOOL), toes)
    assert out[1, 0] + 0.15 == pytest.approx(2.0 - 0.08) and out[1, 1] == pytest.approx(2.0)  # the toe out too


def test_knees_and_feet_stay_out_of_a_counter_in_front_of_the_stool() -> None:
    scene = Scene(name="bar", bounds_min=(0.0, 0.0), bounds_max=(5.0, 4.0), objects=(COUNTER, STOOL))
    motion = MotionMatcher(load_databases(cache_dir=motion_cache_dir()))
    world = World(scene, {"Ben": ((1.0, 1.0), 0.0)}, motion, config=WorldConfig())
    sit = AssignEvent(event_id="sit", assignments=(Assignment(
        character="Ben", action="drink", target_xy=tuple(float(v) for v in STOOL.seat_point()),
        facing_xy=(0.0, 1.0), seat="stool_1"),))
    seated_frames = 0
    for frame in range(600):
        _, out = step(world, [sit] if frame == 0 else (), world.dt)
        assert out.failures == ()
        seated_frames += bool(world.characters["Ben"].seated)
    assert seated_frames > 60
    track = world.track("Ben")
    joints = track.joint_positions()
    labels = list(track.action_labels or ())
    seated = [i for i, lab in enumerate(labels) if lab.endswith("@seated") or lab == "sit_idle"]
    assert seated
    deepest = max(_inside(COUNTER, joints[i, JOINT_INDEX[j]]) for i in seated for j in LEG_JOINTS)
    assert deepest < -0.05, f"a seated leg joint {100 * deepest:+.1f} cm into the counter (want 5 cm clear)"


def test_the_way_onto_a_chair_tucked_under_a_table_goes_round_the_table_s_corner() -> None:
    table = _box("table_1", "table", (2.2, 2.6, 0.375), (1.6, 0.9, 0.75))
    chair = _box("chair_1", "chair", (1.8, 1.74, 0.475), (0.48, 0.52, 0.95), seat=0.45)
    place, anchor = chair.seat_point(), np.array([1.15, 2.29])  # stood beside the table's end
    via = sit_via(chair, (table, chair), anchor, place)
    assert via is not None and np.allclose(via, (1.15, place[1]))  # back first, then sideways onto the seat
    for u in np.linspace(0.0, 1.0, 41):  # the hips stay clear of the top's footprint all the way
        p = along_way(anchor, via, place, float(u))
        assert np.max(np.abs(table.to_local(p[None])[0]) - np.array([0.8, 0.45])) > 0.1
    assert sit_via(chair, (table, chair), np.array([1.8, 1.2]), place) is None  # from in front: straight
    assert sit_via(chair, (table, chair), anchor, place, [(1.4, 1.75)]) is None  # not past someone in the way

"""storyteller.benchmark.motion_metrics: each measure on synthetic tracks whose answers are known."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from storyteller.benchmark.motion_metrics.bodies import (
    SEAT_SINK_M,
    Box,
    body_overlap,
    crowd_overlaps,
    furniture_penetration,
    signed_distance,
    sphere_body,
)
from storyteller.benchmark.motion_metrics.feet import (
    FOOT_JOINTS,
    floor_contact,
    foot_skating,
    lowest_foot_height,
    resample,
)
from storyteller.benchmark.motion_metrics.gait import (
    GaitWindow,
    arm_swing,
    compare_gait,
    step_cadence,
    sway,
    walking_windows,
)
from storyteller.benchmark.motion_metrics.interactions import (
    PELVIS_ABOVE_SEAT_M,
    hand_distance,
    seat_errors,
    transition_times,
)
from storyteller.sim.body.skeleton import (
    JOINT_INDEX,
    NUM_JOINTS,
    REST_OFFSETS,
    forward_kinematics,
    heading_to_root,
)
from storyteller.sim.scene.model import Scene, SceneObject, Vec2, Vec3
from storyteller.sim.world.legroom import TABLE_TOP_M


def rest_joints(frames: int = 1, xy: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """World joints (frames, 22, 3) of the rest pose facing +x at ``xy``."""
    rot = np.broadcast_to(np.eye(3), (frames, NUM_JOINTS, 3, 3)).copy()
    rot[:, 0] = heading_to_root(0.0)
    root = np.tile([xy[0], xy[1], REST_OFFSETS[0, 1]], (frames, 1))
    return forward_kinematics(rot, root)[0]


def sliding_feet(frames: int, step_m: float, height_m: float) -> np.ndarray:
    """Joints whose two ball-of-foot joints move ``step_m`` along x every frame at ``height_m``."""
    j = np.zeros((frames, NUM_JOINTS, 3))
    j[..., 2] = 1.0
    for k in FOOT_JOINTS:
        j[:, k, 0] = np.arange(frames) * step_m
        j[:, k, 2] = height_m
    return j


def box(
    name: str = "table_1",
    center: Vec3 = (0.0, 0.0, 0.5),
    size: Vec3 = (1.0, 1.0, 1.0),
    facing: Vec2 = (0.0, 1.0),
    **kw: Any,
) -> SceneObject:
    label, idx = name.rsplit("_", 1)
    return SceneObject(name=name, label=label, idx=int(idx), center=center, size=size, facing=facing, **kw)


# ----- feet -------------------------------------------------------------------------------------
def test_resample_keeps_a_linear_ramp_and_the_span() -> None:
    a = np.arange(31, dtype=float)[:, None] * 0.1  # 1 s at 30 fps
    r = resample(a, 30.0, 20.0)
    assert len(r) == 21
    np.testing.assert_allclose(r[:, 0], np.arange(21) * 0.15)


@pytest.mark.parametrize(("step", "height", "ratio"), [(0.03, 0.02, 1.0), (0.03, 0.10, 0.0), (0.02, 0.02, 0.0)])
def test_skating_counts_a_low_foot_moving_more_than_2_5_cm(step: float, height: float, ratio: float) -> None:
    assert foot_skating(sliding_feet(41, step, height), fps=20.0).ratio == ratio


def test_skating_is_evaluated_at_20_fps() -> None:
    # 2 cm per frame at 30 fps is 3 cm per frame at 20 fps: skating
    s = foot_skating(sliding_feet(61, 0.02, 0.02), fps=30.0)
    assert s.frames == 40 and s.skating == 40


def test_planted_feet_do_not_skate() -> None:
    assert foot_skating(rest_joints(30), fps=30.0).ratio == 0.0


def test_floor_penetration_and_float_in_mm() -> None:
    j = rest_joints(10)
    h = lowest_foot_height(j)
    assert h[0] == pytest.approx(0.01)
    fc = floor_contact(np.array([-0.005, 0.01, 0.02, 0.01]))
    assert fc.penetration_max == pytest.approx(5.0)
    assert fc.penetrating_share == pytest.approx(0.25)
    assert fc.float_median == pytest.approx(10.0)


# ----- bodies -----------------------------------------------------------------------------------
def test_signed_distance_of_an_oriented_box() -> None:
    b = Box.of(box(facing=(1.0, 0.0), size=(2.0, 1.0, 1.0)))  # width 2 along y now, depth 1 along x
    d = signed_distance(np.array([[0.0, 0.0, 1.05], [0.0, 0.0, 0.95], [0.6, 0.0, 0.5], [0.0, 1.2, 0.5]]), b)
    np.testing.assert_allclose(d, [0.05, -0.05, 0.1, 0.2], atol=1e-12)


def test_a_box_penetrated_by_5_cm_gives_5_cm() -> None:
    body = sphere_body()
    pts = rest_joints(1)
    centres = body.centres(pts)
    # a table whose top is 5 cm above the lowest point of the deepest-reaching sphere
    lowest = float((centres[0, :, 2] - body.radii).min())
    table = box(center=(0.0, 0.0, (lowest + 0.05) / 2.0), size=(0.3, 0.3, lowest + 0.05))
    pen = furniture_penetration(centres, body, [table])
    assert pen[0] == pytest.approx(0.05, abs=1e-9)


def test_a_far_box_gives_nothing_and_a_seat_counts_up_to_its_surface() -> None:
    body = sphere_body()
    centres = body.centres(rest_joints(2))
    far = box(center=(5.0, 5.0, 0.5))
    assert furniture_penetration(centres, body, [far]).tolist() == [0.0, 0.0]
    # a couch 0.9 m high (backrest) whose seat surface is 0.45 m high, the body standing in it
    couch = box("couch_1", center=(0.0, 0.0, 0.45), size=(1.0, 1.0, 0.9), sit_offset_vertical=0.45)
    pen = furniture_penetration(centres, body, [couch], seated=np.array([False, True]))
    top = 0.45 - SEAT_SINK_M  # a seated body may sink that far into what it sits on
    cushion = box("couch_1", center=(0.0, 0.0, top / 2.0), size=(1.0, 1.0, top))
    assert pen[0] > 0.3  # the pelvis deep in the backrest's box
    assert pen[1] == pytest.approx(furniture_penetration(centres[1:], body, [cushion])[0])
    assert pen[1] < pen[0]


def test_a_table_counts_as_its_top_the_space_under_it_is_legroom() -> None:
    body = sphere_body()
    centres = body.centres(rest_joints(1))
    legs = float((centres[0, :, 2] + body.radii).max())  # the highest sphere's top
    assert legs > 0.9
    # a 0.75 m table and a 0.75 m cabinet around the standing body: the cabinet's box holds the
    # legs and hips; the table's holds them under its top, which the trunk is above
    table = box("table_1", center=(0.0, 0.0, 0.375), size=(1.0, 1.0, 0.75))
    cabinet = box("cabinet_1", center=(0.0, 0.0, 0.375), size=(1.0, 1.0, 0.75))
    assert furniture_penetration(centres, body, [cabinet])[0] > 0.3
    slab = box("cabinet_1", center=(0.0, 0.0, 0.75 - TABLE_TOP_M / 2.0), size=(1.0, 1.0, TABLE_TOP_M))
    assert furniture_penetration(centres, body, [table])[0] == pytest.approx(furniture_penetration(centres, body, [slab])[0])
    low = box("desk_1", center=(0.0, 0.0, 0.25), size=(1.0, 1.0, 0.5))  # a top at 0.5 m cuts the thighs
    assert furniture_penetration(centres, body, [low])[0] > 0.05


def test_hands_working_on_an_object_do_not_count() -> None:
    body = sphere_body()
    j = rest_joints(2)
    wrist = j[0, JOINT_INDEX["left_wrist"]]
    obj = box("coffee_maker_1", center=tuple(wrist), size=(0.1, 0.1, 0.1))
    centres = body.centres(j)
    pen = furniture_penetration(centres, body, [obj], hands_free=np.array([False, True]))
    assert pen[0] > 0.04 and pen[1] == 0.0


def test_two_bodies_overlap_only_when_close() -> None:
    body = sphere_body()
    a = body.centres(rest_joints(1))
    assert body_overlap(a, body.centres(rest_joints(1, (0.1, 0.0))), body)[0] > 0.1
    assert body_overlap(a, body.centres(rest_joints(1, (2.0, 0.0))), body)[0] == 0.0
    # 0.30 m apart, pelvis spheres 0.085 + 0.085 and hip spheres 0.08 + 0.08: no contact
    assert body_overlap(a, body.centres(rest_joints(1, (0.0, 0.6))), body)[0] == 0.0


# ----- gait -------------------------------------------------------------------------------------
def test_sway_and_arm_swing_of_a_synthetic_walk() -> None:
    fps, n = 30.0, 300
    t = np.arange(n) / fps
    xy = np.stack([t * 1.0, 0.03 * np.sin(2 * np.pi * 1.0 * t)], axis=-1)
    assert sway(np.stack([t, np.zeros(n)], axis=-1), fps) == pytest.approx(0.0, abs=1e-9)
    assert sway(xy, fps) == pytest.approx(0.03 / math.sqrt(2), rel=0.1)
    j = np.zeros((n, NUM_JOINTS, 3))
    j[:, :, 0] = t[:, None]
    for w, sign in ((JOINT_INDEX["left_wrist"], 1), (JOINT_INDEX["right_wrist"], -1)):
        j[:, w, 0] += sign * 0.2 * np.sin(2 * np.pi * 0.9 * t)
    assert arm_swing(j, fps) == pytest.approx(0.4 * math.sin(math.radians(90 * 0.9)), rel=0.05)


def test_cadence_from_alternating_foot_strikes() -> None:
    c = np.zeros((120, 2), dtype=bool)
    for k, start in enumerate(range(0, 120, 15)):  # a strike every 15 frames, feet alternating
        c[start: start + 10, k % 2] = True
    assert step_cadence(c, 30.0) == pytest.approx(120.0)


def test_walking_windows_trim_starts_and_split_long_walks() -> None:
    fps = 30.0
    n = 300
    xy = np.stack([np.arange(n) / fps, np.zeros(n)], axis=-1)
    labels = ["walk"] * n
    wins = walking_windows(labels, xy, fps)
    assert wins[0][0] == 15 and wins[-1][1] == n - 15
    assert all(b - a <= 4 * fps for a, b in wins)
    assert walking_windows(["idle"] * n, xy, fps) == []


def test_gait_compares_at_the_same_speed() -> None:
    def w(speed: float, cadence: float) -> GaitWindow:
        return GaitWindow(90, speed, cadence, speed / (cadence / 60), 0.02, 0.02, 0.3, 100.0)

    real = [w(0.8, 100.0), w(1.2, 120.0)]
    cmp = compare_gait([w(1.0, 110.0 * 0.8)], real)
    assert cmp.real["cadence"] == pytest.approx(110.0)
    assert cmp.ratio["cadence"] == pytest.approx(0.8)
    assert cmp.ratio["bob"] == pytest.approx(1.0)


# ----- interactions -----------------------------------------------------------------------------
def test_hand_distance_to_a_box() -> None:
    obj = box("coffee_maker_1", center=(1.0, 0.0, 1.0), size=(0.2, 0.2, 0.2))
    wrists = np.array([[[0.5, 0.0, 1.0], [0.85, 0.0, 1.0]], [[0.5, 0.0, 1.0], [0.95, 0.0, 1.0]]])
    frame, metres = hand_distance(wrists, obj)
    assert frame == 1 and metres == pytest.approx(0.0)
    assert hand_distance(wrists[:1], obj)[1] == pytest.approx(0.05)


def test_seat_height_error_and_transition_times() -> None:
    chair = box("chair_1", center=(0.0, 0.0, 0.45), size=(0.5, 0.5, 0.9), sit_offset_vertical=0.45)
    scene = Scene(name="t", bounds_min=(-3.0, -3.0), bounds_max=(3.0, 3.0), objects=(chair,))
    j = rest_joints(40)
    j[:, :, 2] -= j[:, 0:1, 2] - (0.45 + PELVIS_ABOVE_SEAT_M + 0.02)  # pelvis 2 cm too high
    labels = ["sit_down"] * 15 + ["sit_idle"] * 10 + ["drink@seated"] * 5 + ["stand_up"] * 10
    assert seat_errors(j, labels, scene) == [pytest.approx(0.02)]
    assert transition_times(labels, 30.0) == {"sit_down": [0.5], "stand_up": [pytest.approx(1 / 3)]}


def test_crowd_overlaps_agree_with_the_pairwise_measure() -> None:
    body = sphere_body()
    n = 5
    a = body.centres(rest_joints(n))
    b = body.centres(rest_joints(n, (0.1, 0.05)))
    c = body.centres(rest_joints(n, (3.0, 0.0)))
    depth, pairs = crowd_overlaps([a, b, c], body)
    np.testing.assert_allclose(depth, body_overlap(a, b, body))
    assert pairs == 1 and depth[0] > 0
    hugging = [np.ones(n, dtype=bool), np.ones(n, dtype=bool), np.zeros(n, dtype=bool)]
    assert crowd_overlaps([a, b, c], body, hugging)[0].max() == 0.0


def test_mouth_reaches_measure_the_wrist_under_the_mouth_of_drinking_and_eating() -> None:
    from storyteller.benchmark.motion_metrics.interactions import brings_to_mouth, mouth_points, mouth_reaches
    from storyteller.sim.world.contacts import HOLD_BELOW_MOUTH_M

    assert brings_to_mouth("drink@seated") and brings_to_mouth("eat") and not brings_to_mouth("walk")
    assert not brings_to_mouth("no_such_action")
    rot = np.broadcast_to(np.eye(3), (4, NUM_JOINTS, 3, 3)).copy()
    rot[:, 0] = heading_to_root(0.7)
    joints = forward_kinematics(rot, np.tile([[1.0, 2.0, REST_OFFSETS[0, 1]]], (4, 1)))[0]
    mouth = mouth_points(joints)
    ahead = mouth[0, :2] - joints[0, JOINT_INDEX["head"], :2]
    assert np.allclose(ahead / np.linalg.norm(ahead), [math.cos(0.7), math.sin(0.7)])  # in front of the face
    joints[2, JOINT_INDEX["right_wrist"]] = mouth[2] - [0.0, 0.0, HOLD_BELOW_MOUTH_M + 0.05]
    got = mouth_reaches(joints, ["walk", "drink", "drink", "drink"], 30.0)
    assert [(r.action, r.frame) for r in got] == [("drink", 2)] and got[0].distance == pytest.approx(0.05)
    far = mouth_reaches(joints, ["eat", "eat", "walk", "walk"], 30.0)  # the T pose's hands: far away
    assert len(far) == 1 and far[0].distance > 0.3

"""Arm IK (storyteller.sim.body.arm_ik) and the contacts the world puts on poses (storyteller.sim.world.contacts): hands
on the object, a handshake's hands meeting, the pelvis on the seat's height."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from storyteller.sim.body.arm_ik import (
    ARM_LENGTH,
    ELBOW_JOINTS,
    SHOULDER_JOINTS,
    WRIST_JOINTS,
    ArmIKError,
    solve_arms,
)
from storyteller.sim.body.leg_ik import leg_chain
from storyteller.sim.body.skeleton import NUM_JOINTS, forward_kinematics, heading_to_root
from storyteller.sim.motion.matching import MotionQuery, Pose
from storyteller.sim.motion.sources.procedural_actions import SEAT_PELVIS_ABOVE_SEAT
from storyteller.sim.motion.sources.procedural_rig import ANKLE_HEIGHT
from storyteller.sim.paths.nav_grid import build_nav_grid
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import SceneObject
from storyteller.sim.world.contacts import (
    FEET_CLEAR_M,
    HOLD_BELOW_MOUTH_M,
    box_contact_point,
    hand_targets,
    mouth_point,
    mouth_weight,
    reach_weight,
    seat_pelvis,
)
from storyteller.sim.world.events import AssignEvent, Assignment
from storyteller.sim.world.phases import CharacterState
from storyteller.sim.world.step import World, WorldConfig, step
from tests.support.reference import OFFICE, reference_or_skip


def _poses(m: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    rots = np.tile(np.eye(3), (m, NUM_JOINTS, 1, 1))
    rots[:, 1:] = Rotation.from_rotvec(rng.normal(0.0, 0.3, (m * (NUM_JOINTS - 1), 3))).as_matrix().reshape(
        m, NUM_JOINTS - 1, 3, 3)
    rots[:, 0] = heading_to_root(rng.uniform(-3.0, 3.0, m))
    pelvis = np.column_stack([rng.uniform(-1.0, 1.0, (m, 2)), np.full(m, 0.93)])
    return pelvis, rots


def test_the_wrist_reaches_a_target_in_reach_and_only_that_arm_moves() -> None:
    m = 8
    pelvis, rots = _poses(m)
    side = np.arange(m) % 2
    pos, _ = forward_kinematics(rots, pelvis)
    shoulder = pos[np.arange(m), np.array(SHOULDER_JOINTS)[side]]
    rng = np.random.default_rng(1)
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    target = shoulder + d * rng.uniform(0.15, 0.45, (m, 1))  # within reach (arm 0.51 m)
    out = solve_arms(pelvis, rots, side, target, np.ones(m))
    new, _ = forward_kinematics(out, pelvis)
    wrist = new[np.arange(m), np.array(WRIST_JOINTS)[side]]
    assert np.abs(wrist - target).max() < 1e-9
    for k in range(m):
        arm = [SHOULDER_JOINTS[side[k]], ELBOW_JOINTS[side[k]], WRIST_JOINTS[side[k]]]
        rest = [j for j in range(NUM_JOINTS) if j not in arm]
        assert np.allclose(new[k, rest], pos[k, rest], atol=1e-12)
        # bones keep their lengths
        for a, b in ((arm[0], arm[1]), (arm[1], arm[2])):
            assert np.linalg.norm(new[k, a] - new[k, b]) == pytest.approx(np.linalg.norm(pos[k, a] - pos[k, b]), abs=1e-9)


def test_weight_zero_is_the_pose_exactly_and_half_goes_half_way_and_far_targets_stretch_the_arm() -> None:
    pelvis, rots = _poses(3, seed=2)
    side = np.array([1, 0, 1])
    pos, _ = forward_kinematics(rots, pelvis)
    wrist = pos[np.arange(3), np.array(WRIST_JOINTS)[side]]
    shoulder = pos[np.arange(3), np.array(SHOULDER_JOINTS)[side]]
    assert np.array_equal(solve_arms(pelvis, rots, side, wrist + 0.3, np.zeros(3)), rots)
    near = wrist + 0.2 * (shoulder - wrist) + np.array([0.0, 0.02, -0.01])  # within reach
    half, _ = forward_kinematics(solve_arms(pelvis, rots, side, near, np.full(3, 0.5)), pelvis)
    assert np.allclose(half[np.arange(3), np.array(WRIST_JOINTS)[side]], (wrist + near) / 2.0, atol=1e-9)
    far = shoulder + np.array([2.0, 0.0, 0.0])
    out, _ = forward_kinematics(solve_arms(pelvis, rots, side, far, np.ones(3)), pelvis)
    reach = out[np.arange(3), np.array(WRIST_JOINTS)[side]] - shoulder
    assert np.allclose(np.linalg.norm(reach, axis=1), ARM_LENGTH[side], atol=1e-3)
    assert np.allclose(reach / np.linalg.norm(reach, axis=1, keepdims=True), [1.0, 0.0, 0.0], atol=1e-6)
    with pytest.raises(ArmIKError):
        solve_arms(pelvis, rots, np.array([1, 2, 0]), far, np.ones(3))
    with pytest.raises(ArmIKError):
        solve_arms(pelvis, rots, side, far[:2], np.ones(3))


def _box(name: str = "coffee_maker_1", z: tuple[float, float] = (0.9, 1.28)) -> SceneObject:
    return SceneObject(name=name, label=name.rsplit("_", 1)[0], idx=1, center=(1.0, 0.0, (z[0] + z[1]) / 2.0),
                       size=(0.3, 0.4, z[1] - z[0]), facing=(-1.0, 0.0), has_facing=True)


def test_box_contact_point_is_on_the_nearest_face_a_little_off_it() -> None:
    box = _box()  # x 0.8..1.2 (depth along the facing), y -0.15..0.15, z 0.9..1.28
    p = box_contact_point(box, np.array([0.4, 0.05, 1.0]), standoff=0.02)
    assert np.allclose(p, [0.78, 0.05, 1.0])
    inside = box_contact_point(box, np.array([1.0, 0.13, 1.1]), standoff=0.0)
    assert np.allclose(inside, [1.0, 0.15, 1.1])
    above = box_contact_point(box, np.array([1.0, 0.0, 1.5]), standoff=0.02)
    assert np.allclose(above, [1.0, 0.0, 1.30])


def test_reach_weight_follows_the_gesture_and_a_loop_holds() -> None:
    w = [reach_weight("reach", False, f, 100, 30.0) for f in range(100)]
    assert w[0] < 0.05 and w[29] == pytest.approx(1.0) and w[50] == 1.0 and w[99] == pytest.approx(0.0, abs=1e-9)
    assert all(0.0 <= x <= 1.0 for x in w)
    assert reach_weight("type", True, 200, -1, 30.0) == 1.0


def _acting(name: str, action: str, frame: int, length: int, **kw: object) -> CharacterState:
    a = Assignment(character=name, action=action, target_xy=(0.0, 0.0), facing_xy=(1.0, 0.0), **kw)
    c = CharacterState(name=name, xy=np.zeros(2), heading=0.0, assignment=a)
    c.enter("interacting", length)
    c.phase_frame = frame
    return c


def _standing(xy: tuple[float, float], heading: float) -> tuple[np.ndarray, np.ndarray]:
    rots = np.tile(np.eye(3), (NUM_JOINTS, 1, 1))
    rots[0] = heading_to_root(heading)
    # arms down along the body, elbows a little bent (not the T pose)
    for side, s in ((0, 1.0), (1, -1.0)):
        rots[SHOULDER_JOINTS[side]] = Rotation.from_euler("z", -s * 1.3).as_matrix()
        rots[ELBOW_JOINTS[side]] = Rotation.from_euler("y", s * 0.4).as_matrix()
    return np.array([*xy, 0.93]), rots


def test_a_hand_goes_onto_the_object_at_the_reach_and_a_handshake_meets() -> None:
    p0, r0 = _standing((0.5, 0.0), 0.0)
    hand = forward_kinematics(r0, p0)[0][WRIST_JOINTS[1]]
    # a box whose front face is 0.12 m ahead of the animated right hand (within reach), facing the character
    box = SceneObject(name="coffee_maker_1", label="coffee_maker", idx=1, center=(hand[0] + 0.32, hand[1], hand[2] + 0.1),
                      size=(0.3, 0.4, 0.38), facing=(-1.0, 0.0), has_facing=True)
    objects = {box.name: box}

    p1, r1 = _standing((3.0, 0.0), 0.0)
    p2, r2 = _standing((3.6, 0.05), np.pi)  # 0.6 m away, facing back
    chars = [_acting("ann", "use_coffee_maker", 90, 180, focus=box.name),
             _acting("bob", "handshake", 45, 90, partners=("cy",)),
             _acting("cy", "handshake", 45, 90, partners=("bob",))]
    pelvis, rots = np.stack([p0, p1, p2]), np.stack([r0, r1, r2])
    out = hand_targets(objects, chars, pelvis, rots, 30.0)
    pos, _ = forward_kinematics(out, pelvis)
    right = WRIST_JOINTS[1]
    d = box_contact_point(box, pos[0, right], standoff=0.0)
    assert np.linalg.norm(pos[0, right] - d) == pytest.approx(0.02, abs=1e-6)
    assert np.linalg.norm(pos[1, right] - pos[2, right]) < 1e-6
    before, _ = forward_kinematics(rots, pelvis)
    assert np.linalg.norm(before[1, right] - before[2, right]) > 0.3
    # at the very start and end the hands are as animated
    chars[0].phase_frame = 179
    chars[1].phase_frame = chars[2].phase_frame = 89
    assert np.allclose(hand_targets(objects, chars, pelvis, rots, 30.0), rots, atol=1e-9)


def test_drinking_and_eating_bring_a_hand_under_the_mouth_on_the_clips_schedule() -> None:
    """drink: the right hand under the mouth while the sip is held, as animated before and after;
    eat (looping): the hands take turns, standing or seated (a seat does not stop it)."""
    assert mouth_weight("to_mouth", 0, 30.0, 4.0)[1] < 0.05
    assert mouth_weight("to_mouth", 40, 30.0, 4.0) == (1, 1.0)  # 1.37 s of 4: held
    assert mouth_weight("to_mouth", 100, 30.0, 4.0)[1] == 0.0  # put down
    assert mouth_weight("to_mouth_both", 20, 30.0, 4.0) == (1, 1.0)
    assert mouth_weight("to_mouth_both", 80, 30.0, 4.0) == (0, 1.0)  # the left hand's turn
    assert mouth_weight("to_mouth_both", 140, 30.0, 4.0) == (1, 1.0)  # and round again
    p0, r0 = _standing((0.0, 0.0), 0.3)
    p1, r1 = _standing((2.0, 0.0), -1.0)
    chars = [_acting("ann", "drink", 40, 120), _acting("bob", "eat", 80, 120, seat="chair_1")]
    chars[0].heading, chars[1].heading = 0.3, -1.0
    pelvis, rots = np.stack([p0, p1]), np.stack([r0, r1])
    out = hand_targets({}, chars, pelvis, rots, 30.0)
    pos, _ = forward_kinematics(out, pelvis)
    before, _ = forward_kinematics(rots, pelvis)
    for k, hand in ((0, 1), (1, 0)):
        goal = mouth_point(pos[k], chars[k].heading) - np.array([0.0, 0.0, HOLD_BELOW_MOUTH_M])
        assert np.linalg.norm(pos[k, WRIST_JOINTS[hand]] - goal) < 1e-6
        assert np.linalg.norm(before[k, WRIST_JOINTS[hand]] - goal) > 0.3
        assert np.allclose(pos[k, WRIST_JOINTS[1 - hand]], before[k, WRIST_JOINTS[1 - hand]])
    chars[0].phase_frame = 100  # the cup is down again
    assert np.allclose(hand_targets({}, chars[:1], pelvis[:1], rots[:1], 30.0), rots[:1], atol=1e-9)


def test_a_seated_pelvis_goes_to_the_seat_height_with_the_feet_kept_on_the_floor() -> None:
    pelvis, rots = _poses(2, seed=3)
    rots[:, 1:] = np.eye(3)
    rots[:, 0] = heading_to_root(np.array([0.3, -1.0]))
    # seated legs: thighs forward, shins down
    for hip, knee in ((1, 4), (2, 5)):
        rots[:, hip] = Rotation.from_euler("x", -np.pi / 2).as_matrix()
        rots[:, knee] = Rotation.from_euler("x", np.pi / 2).as_matrix()
    pelvis[:, 2] = 0.40 + 0.065 + 0.015  # a clip made for another seat height
    a = Assignment(character="ann", action="idle", target_xy=(0.0, 0.0), facing_xy=(1.0, 0.0), seat="chair_1")
    sit = CharacterState(name="ann", xy=np.zeros(2), heading=0.0, assignment=a, phase="interacting")
    walk = CharacterState(name="bob", xy=np.zeros(2), heading=0.0)
    new_p, new_r = seat_pelvis([sit, walk], ["sit_idle", "walk"], [True, False], [0.45, None], pelvis, rots, 0.0)
    assert new_p[0, 2] == pytest.approx(0.45 + SEAT_PELVIS_ABOVE_SEAT)
    assert np.array_equal(new_p[1], pelvis[1]) and np.array_equal(new_r[1], rots[1])
    before, after = leg_chain(pelvis[:1], rots[:1]).ankle, leg_chain(new_p[:1], new_r[:1]).ankle
    assert np.allclose(after[..., :2], before[..., :2], atol=1e-6)
    assert np.allclose(after[..., 2], ANKLE_HEIGHT, atol=1e-6)


def test_an_object_out_of_the_arms_reach_bends_the_trunk_forward_just_enough() -> None:
    p0, r0 = _standing((0.0, 0.0), 0.0)
    # a low box (a record player on a side table): top at 0.72 m, front face 0.3 m ahead of the pelvis
    box = SceneObject(name="record_player_1", label="record_player", idx=1, center=(0.5, 0.0, 0.66),
                      size=(0.42, 0.4, 0.12), facing=(-1.0, 0.0), has_facing=True)
    objects = {box.name: box}

    c = _acting("ann", "turn_on_record_player", 45, 90, focus=box.name)
    out = hand_targets(objects, [c], p0[None], r0[None], 30.0)
    pos, _ = forward_kinematics(out, p0[None])
    wrist = pos[0, WRIST_JOINTS[1]]
    assert np.linalg.norm(wrist - box_contact_point(box, wrist, standoff=0.0)) < 0.03
    before, _ = forward_kinematics(r0[None], p0[None])
    head = 15  # the head went forward and down: the trunk bent
    assert pos[0, head, 0] > before[0, head, 0] + 0.1 and pos[0, head, 2] < before[0, head, 2]


def test_seated_feet_stay_in_front_of_the_seats_base() -> None:
    pelvis, rots = _poses(1, seed=4)
    rots[:, 1:] = np.eye(3)
    rots[:, 0] = heading_to_root(np.array([np.pi / 2]))  # facing +y
    for hip, knee in ((1, 4), (2, 5)):
        rots[:, hip] = Rotation.from_euler("x", -np.pi / 2).as_matrix()
        rots[:, knee] = Rotation.from_euler("x", np.pi / 2).as_matrix()
    pelvis[0] = (0.0, 0.0, 0.54)
    ankle_y = float(leg_chain(pelvis, rots).ankle[0, 0, 1])  # the animated ankles, about 0.39 m ahead
    # a deep couch facing +y whose front face is 0.45 m ahead of the seated pelvis
    couch = SceneObject(name="couch_1", label="couch", idx=1, center=(0.0, 0.0, 0.425), size=(2.0, 0.9, 0.85),
                        facing=(0.0, 1.0), has_facing=True, sit_offset_vertical=0.45)
    assert ankle_y < 0.45
    a = Assignment(character="ann", action="idle", target_xy=(0.0, 0.0), facing_xy=(0.0, 1.0), seat="couch_1")
    sit = CharacterState(name="ann", xy=np.zeros(2), heading=np.pi / 2, assignment=a, phase="interacting")
    new_p, new_r = seat_pelvis([sit], ["sit_idle"], [True], [0.45], pelvis, rots, 0.0, [couch])
    after = leg_chain(new_p, new_r).ankle[0]
    assert np.allclose(after[:, 1], 0.45 + FEET_CLEAR_M, atol=1e-6)
    assert np.allclose(after[:, 2], ANKLE_HEIGHT, atol=1e-6)


class _RestMotion:
    """Rest pose on the world's root (pelvis lowered when seated)."""

    def initial_state(self, label: str, root_xy: object, heading: float, seated: bool = False) -> int:
        return 0

    def step(self, state: int, query: MotionQuery, dt: float) -> tuple[int, Pose]:
        rot = np.tile(np.eye(3), (NUM_JOINTS, 1, 1))
        rot[0] = heading_to_root(float(query.heading or 0.0))
        sitting = query.seated or query.label in ("sit_down", "stand_up")
        root = np.asarray(query.root_xy, dtype=float)
        return state + 1, Pose(np.array([*root, 0.55 if sitting else 0.93]), rot, root, float(query.heading or 0.0),
                               np.ones(2, dtype=bool))


@pytest.mark.parametrize(("action", "apart", "lo", "hi"), [("chat", 2.4, 0.9, 1.5), ("handshake", 1.5, 0.65, 0.65),
                                                           ("chat", 1.2, 1.2, 1.2)])
def test_partners_stand_at_the_actions_distance_face_each_other_and_shake_hands(
        action: str, apart: float, lo: float, hi: float) -> None:
    reference_or_skip()
    scene = load_scene(OFFICE)
    grid = build_nav_grid(scene)
    cells = np.argwhere(grid.component == grid.main_component)
    free = {(int(i), int(j)) for i, j in cells}
    k = round(apart / grid.cell_size)
    i, j = next((int(i), int(j)) for i, j in cells
                if all((i + d, j + m) in free for d in range(-1, k + 2) for m in (-1, 0, 1)))
    pa, pb = grid.center_of(i, j), grid.center_of(i + k, j)
    w = World(scene, {"ann": ((float(pa[0]), float(pa[1])), 0.0), "bob": ((float(pb[0]), float(pb[1])), 0.0)},
              _RestMotion(), grid=grid, config=WorldConfig(foot_ik=False))
    cmd = AssignEvent(event_id="meet", assignments=(
        Assignment(character="ann", action=action, target_xy=(float(pa[0]), float(pa[1])), facing_xy=(0.0, 1.0),
                   partners=("bob",)),
        Assignment(character="bob", action=action, target_xy=(float(pb[0]), float(pb[1])), facing_xy=(0.0, 1.0),
                   partners=("ann",))))
    first: list[AssignEvent] = [cmd]
    for _ in range(1500):
        _, out = step(w, first, w.dt)
        first = []
        if out.failures:
            raise AssertionError(out.failures)
        if all(w.characters[n].phase == "interacting" for n in ("ann", "bob")):
            break
    else:
        raise AssertionError("the pair never started")
    ann, bob = w.characters["ann"], w.characters["bob"]
    gap = float(np.linalg.norm(ann.xy - bob.xy))
    assert lo - 1e-6 <= gap <= hi + 1e-6
    to_bob = math.atan2(*(bob.xy - ann.xy)[::-1])
    assert abs(math.remainder(ann.heading - to_bob, 2 * math.pi)) < 1e-6
    assert abs(math.remainder(bob.heading - to_bob - math.pi, 2 * math.pi)) < 1e-6
    if action == "handshake":
        for _ in range(round(0.5 * 3.0 * 30) - 1):  # to the middle of the shake
            step(w, [], w.dt)
        tracks = w.tracks()
        right = WRIST_JOINTS[1]
        ha = forward_kinematics(tracks["ann"].local_rotations[-1], tracks["ann"].root_positions[-1])[0][right]
        hb = forward_kinematics(tracks["bob"].local_rotations[-1], tracks["bob"].root_positions[-1])[0][right]
        assert np.linalg.norm(ha - hb) < 0.01

"""Arms swing out of the furniture at the shoulder (issue 25: body-furniture penetration).

Before: the arms moved as in the clips, through whatever stood beside the body (an arm brushing
a plant while walking, a hand in the couch while standing beside it: the scripted home story's
frames deeper than 2 cm, 31 of 112).
"""

from __future__ import annotations

import math

import numpy as np

from storyteller.sim.body.arm_ik import ELBOW_JOINTS, SHOULDER_JOINTS, WRIST_JOINTS
from storyteller.sim.body.skeleton import NUM_JOINTS, forward_kinematics, heading_to_root
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.world.arm_room import ARM_CLEAR_M, ARM_FLESH_M, ArmBoxes, arms_clear

PELVIS = np.array([[0.0, 0.0, 0.93]])


def _box(name: str, label: str, center: tuple[float, float, float], size: tuple[float, float, float]) -> SceneObject:
    return SceneObject(name=name, label=label, idx=1, center=center, size=size)


def _t_pose(heading: float = math.pi / 2) -> np.ndarray:
    """One body (1, 22, 3, 3) in the rest pose (arms out sideways) facing ``heading``."""
    rots = np.broadcast_to(np.eye(3), (1, NUM_JOINTS, 3, 3)).copy()
    rots[0, 0] = heading_to_root(heading)
    return rots


def _depth(obj: SceneObject, p: np.ndarray) -> float:
    """How far (m) point ``p`` (3,) lies inside ``obj``'s box (negative: its distance outside)."""
    local = np.array([*obj.to_local(p[None, :2])[0], p[2] - obj.center[2]])
    q = np.abs(local) - np.array(obj.size) / 2.0
    outside = float(np.linalg.norm(np.maximum(q, 0.0)))
    return -outside if outside > 0 else float(-q.max())


def _arm(rots: np.ndarray, side: int) -> np.ndarray:
    pos, _ = forward_kinematics(rots, PELVIS)
    e, w = pos[0, ELBOW_JOINTS[side]], pos[0, WRIST_JOINTS[side]]
    return np.stack([e, (e + w) / 2.0, w])


def test_an_arm_in_a_tall_box_beside_the_body_swings_out_and_the_other_arm_stays() -> None:
    rots = _t_pose()
    left = _arm(rots, 0)
    side = 1.0 if left[2, 0] > 0 else -1.0  # the left hand's side of the body (x)
    cabinet = _box("cabinet_1", "cabinet", (side * 0.75, 0.0, 0.8), (0.3, 0.6, 1.6))  # face 0.6 m out
    assert _depth(cabinet, left[2]) > 0.05  # the hand is in it
    scene = Scene(name="room", bounds_min=(-3.0, -3.0), bounds_max=(3.0, 3.0), objects=(cabinet,))
    out = arms_clear(ArmBoxes.from_scene(scene), PELVIS, rots, [False], [None])
    after = _arm(out, 0)
    for p, flesh in zip(after, ARM_FLESH_M, strict=True):
        assert _depth(cabinet, p) <= -(flesh + ARM_CLEAR_M) + 1e-6
    np.testing.assert_allclose(_arm(out, 1), _arm(rots, 1))  # the right arm is clear: untouched
    changed = [j for j in range(NUM_JOINTS) if not np.allclose(out[0, j], rots[0, j])]
    assert changed == [SHOULDER_JOINTS[0]]  # turned at the shoulder only, the elbow keeps its bend
    lengths = np.linalg.norm(after - forward_kinematics(out, PELVIS)[0][0, SHOULDER_JOINTS[0]], axis=1)
    np.testing.assert_allclose(lengths, np.linalg.norm(left - forward_kinematics(rots, PELVIS)[0][0, SHOULDER_JOINTS[0]], axis=1))


def test_working_hands_the_own_seat_and_a_table_s_legroom_are_left_alone() -> None:
    rots = _t_pose()
    left = _arm(rots, 0)
    side = 1.0 if left[2, 0] > 0 else -1.0
    couch = _box("couch_1", "couch", (side * 0.75, 0.0, 0.8), (0.3, 0.6, 1.6))
    scene = Scene(name="room", bounds_min=(-3.0, -3.0), bounds_max=(3.0, 3.0), objects=(couch,))
    boxes = ArmBoxes.from_scene(scene)
    assert arms_clear(boxes, PELVIS, rots, [True], [None]) is rots  # hands on an object: touching is the point
    assert arms_clear(boxes, PELVIS, rots, [False], ["couch_1"]) is rots  # its seat: arms rest on it
    # under a table's top (5 cm thick, top at 1.1 m) the box is legroom: the arm at 0.93 m is free
    table = _box("table_1", "table", (side * 0.75, 0.0, 0.55), (0.3, 0.6, 1.1))
    scene = Scene(name="room", bounds_min=(-3.0, -3.0), bounds_max=(3.0, 3.0), objects=(table,))
    assert arms_clear(ArmBoxes.from_scene(scene), PELVIS, rots, [False], [None]) is rots


def test_the_turn_grows_from_zero_at_the_surface() -> None:
    """No jump when a hand first touches a box: the correction is continuous in the box's place
    (for an arm pointing straight at the box's face, as here, it grows as the square root of the
    depth: the hand swings down along the face)."""
    rots = _t_pose()
    left = _arm(rots, 0)
    side = 1.0 if left[2, 0] > 0 else -1.0
    reach = abs(float(left[2, 0]))
    moves = []
    for gap in (0.002, 0.0, -0.002, -0.02):  # the box's face this far beyond the hand's flesh
        face = reach + ARM_FLESH_M[2] + ARM_CLEAR_M + gap
        obj = _box("plant_1", "plant", (side * (face + 0.15), 0.0, 0.8), (0.3, 0.6, 1.6))
        scene = Scene(name="room", bounds_min=(-3.0, -3.0), bounds_max=(3.0, 3.0), objects=(obj,))
        out = arms_clear(ArmBoxes.from_scene(scene), PELVIS, rots, [False], [None])
        moves.append(float(np.linalg.norm(_arm(out, 0)[2] - left[2])))
    assert moves[0] == 0.0 and moves[1] < 1e-6
    assert 0.0 < moves[2] < 0.04 < moves[3] < 0.15


def test_a_body_standing_beside_a_cabinet_keeps_its_hanging_hand_out_of_it() -> None:
    """The world runs the rule on every frame: waving beside a tall cabinet (its face 0.22 m to
    the left of the pelvis), the left hand hangs beside it, not in it. The walk is planned on the
    grid of the room without the cabinet, so the body stands exactly there."""
    from storyteller.orchestrator.cache_paths import motion_cache_dir
    from storyteller.sim.motion.database import load_databases
    from storyteller.sim.motion.matching import MotionMatcher
    from storyteller.sim.paths.nav_grid import build_nav_grid
    from storyteller.sim.world.events import AssignEvent, Assignment
    from storyteller.sim.world.step import World, WorldConfig, step

    spot = (2.0, 1.5)
    cabinet = SceneObject(name="cabinet_1", label="cabinet", idx=1, center=(2.0, spot[1] + 0.22 + 0.2, 0.9),
                          size=(1.2, 0.4, 1.8))
    scene = Scene(name="room", bounds_min=(0.0, 0.0), bounds_max=(4.0, 3.0), objects=(cabinet,))
    empty = Scene(name="room", bounds_min=(0.0, 0.0), bounds_max=(4.0, 3.0), objects=())
    world = World(scene, {"Ada": ((0.5, 0.5), 0.0)}, MotionMatcher(load_databases(cache_dir=motion_cache_dir())),
                  grid=build_nav_grid(empty), config=WorldConfig())
    wave = AssignEvent(event_id="wave", assignments=(Assignment(character="Ada", action="wave", target_xy=spot,
                                                                facing_xy=(1.0, 0.0)),))
    acting = []
    for frame in range(300):
        _, out = step(world, [wave] if frame == 0 else (), world.dt)
        assert out.failures == ()
        c = world.characters["Ada"]
        acting.append(c.phase == "interacting" and float(np.linalg.norm(c.xy - np.array(spot))) < 0.02)
    frames = [i for i, a in enumerate(acting) if a]
    assert len(frames) > 30
    joints = world.track("Ada").joint_positions()
    deepest = max(_depth(cabinet, joints[i, j]) + flesh for i in frames
                  for j, flesh in ((ELBOW_JOINTS[0], ARM_FLESH_M[0]), (WRIST_JOINTS[0], ARM_FLESH_M[2])))
    assert deepest <= 0.0, f"the left arm's flesh {100 * deepest:.1f} cm into the cabinet"

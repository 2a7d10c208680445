"""Body contacts the world puts on the poses after the motion layer: the pelvis on the seat, the
hands on the object.

The motion layer animates from clips made for a few seat heights and an object at a nominal
distance and height; the world knows the real seat and object. Two corrections, both smooth
in time and both exact at the contact:

- **seat height** (``seat_pelvis``): while a character sits on a seat its pelvis is
  ``SEAT_PELVIS_ABOVE_SEAT`` above the seat's surface (the scene's seat height); sitting down,
  the pelvis goes from standing height (``STAND_Z``) to it as the root goes onto the seat (the
  ``smoothstep`` of the sit-down's progress, ``storyteller.sim.world.frame_assembly.stationary_root``),
  standing up back (the clips' own heights would end the sit-down 0.3 s early). The legs are
  re-solved (``storyteller.sim.body.leg_ik``) so the feet stay where they were animated, flat
  on the floor (ankle at ``ANKLE_HEIGHT``) where they were near it, and in front of the seat's
  base (``FEET_CLEAR_M``), so the knees take up the difference;
- **hands on the object** (``hand_targets``): a standing character whose action's hands work
  on an object (gestures ``HAND_GESTURES``; the object is the assignment's ``focus``) moves
  its working hand (both for typing and carrying) towards the point of the object's box
  nearest the animated hand, ``HAND_STANDOFF_M`` off its surface, with the weight of the
  gesture's reach (``reach_weight``: up over the first ``REACH_IN`` of the action, held, down
  over the last part, as the procedural clips move the hand), by the arm IK
  (``storyteller.sim.body.arm_ik``); an object out of the arm's reach (a record player on a low side table)
  bends the trunk forward first, as little as will do (``LEAN_STEPS``). A wipe's circles and a
  pen's strokes stay: the point follows the animated hand across the surface;
- **the cup or the food to the mouth** (``hand_targets``): a character drinking or eating
  (gestures ``MOUTH_GESTURES``, standing or seated) moves the hand holding it to just under its
  mouth (``mouth_point``: in front of and below the head joint; the wrist ``HOLD_BELOW_MOUTH_M``
  under it) on the procedural clip's schedule (``mouth_weight``: up over the first quarter of
  each sip or bite, held, down by 65%; eating alternates the hands), by the arm IK;
- **a handshake's hands meet** (``hand_targets``): two partners shaking hands move their right
  hands to the midpoint of their animated right hands (raised to about elbow height), with the
  weight of the handshake's reach. They meet when the partners stand close enough for two
  arms (about 0.6 m between pelvises or less on this skeleton, whose arm is 0.51 m); further
  apart both hands stretch towards the same point and stop short of it.

Pure functions of the frame's poses and the characters' states; deterministic.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.body.arm_ik import ARM_LENGTH, SHOULDER_JOINTS, WRIST_JOINTS, solve_arms
from storyteller.sim.body.leg_ik import leg_chain, solve_chain
from storyteller.sim.body.skeleton import JOINT_INDEX, forward_kinematics
from storyteller.sim.motion.action_labels import action_spec
from storyteller.sim.motion.sources.procedural_actions import SEAT_PELVIS_ABOVE_SEAT, STAND_Z
from storyteller.sim.motion.sources.procedural_rig import ANKLE_HEIGHT
from storyteller.sim.scene.model import SceneObject
from storyteller.sim.world.legroom import feet_clear_of
from storyteller.sim.world.phases import CharacterState, smoothstep

HAND_GESTURES = frozenset({"reach", "reach_low", "wipe", "write", "carry", "type"})
"""Gestures whose hands work on the object used (``storyteller.sim.world.facing.REACH_GESTURES``)."""
BOTH_HANDS = frozenset({"carry", "type"})
REACH_IN = {"carry": (0.35, 0.6), "handshake": (0.3, 0.75)}
"""Fractions of the action's duration at which the hand arrives and leaves (default 0.3, 0.7:
the procedural clips' keyframes, ``storyteller.sim.motion.sources.procedural_actions._gesture``)."""
MOUTH_GESTURES = frozenset({"to_mouth", "to_mouth_both"})
"""Gestures that bring a hand (a cup, food) to the mouth: drink, eat."""
MOUTH_FORWARD_M = 0.10  # the mouth in front of the head joint (horizontally, along the body's forward)
MOUTH_BELOW_HEAD_M = 0.06  # and under it
HOLD_BELOW_MOUTH_M = 0.07  # the wrist under the lips: the cup or the food is in the hand above it
LOOP_REACH_S = 0.5  # seconds a looping action's hands take to settle on the object
HAND_STANDOFF_M = 0.02  # wrist joint off the object's surface (the palm and fingers beyond it)
SHAKE_BELOW_SHOULDER_M = 0.35  # shaking hands meet at least this high: about elbow height, forearms forward
FOOT_NEAR_FLOOR_M = 0.25
FEET_CLEAR_M = 0.07  # a seated ankle joint's distance in front of its seat's front face (the ankle's capsule and 2 cm)
LEAN_STEPS = tuple(float(a) for a in np.linspace(0.0, 0.9, 19))
"""Forward bends (radians at ``spine1``) tried, least first, when a hand cannot reach its object."""
LEAN_MARGIN_M = 0.03  # the hand's target this much inside the straight arm's reach
SPINE1 = JOINT_INDEX["spine1"]  # an animated ankle lower than this above the floor is put on it


def reach_weight(gesture: str, loops: bool, frame: int, length: int, fps: float) -> float:
    """How far (0..1) the hand is on the object ``frame`` frames into an action of ``length``
    frames (looping: ramps up over ``LOOP_REACH_S`` and stays)."""
    if loops or length <= 0:
        return smoothstep((frame + 1) / max(1.0, LOOP_REACH_S * fps))
    a, b = REACH_IN.get(gesture, (0.3, 0.7))
    t = (frame + 1) / length
    if t <= b:
        return smoothstep(t / a)
    return 1.0 - smoothstep((t - b) / (1.0 - b))


def mouth_weight(gesture: str, frame: int, fps: float, duration: float) -> tuple[int, float]:
    """(hand, weight 0..1) of a ``to_mouth`` / ``to_mouth_both`` gesture ``frame`` frames into
    the action, on the procedural clip's keys (``procedural_actions``: each hand's span of a
    ``duration``-second cycle, up by 25%, held to 45%, down by 65%); right hand first, eating
    alternates. Looping actions repeat the cycle."""
    sides = (1,) if gesture == "to_mouth" else (1, 0)
    span = max(duration, 1e-6) / len(sides)
    t = ((frame + 1) / fps) % (span * len(sides))
    k = min(int(t // span), len(sides) - 1)
    u = (t - k * span) / span
    w = smoothstep(u / 0.25) if u <= 0.45 else 1.0 - smoothstep((u - 0.45) / 0.2)
    return sides[k], float(w)


def mouth_point(joints: NDArray[np.float64], heading: float) -> NDArray[np.float64]:
    """The mouth (3,) of a body's joint positions (22, 3) facing ``heading`` (radians)."""
    head = joints[JOINT_INDEX["head"]]
    return np.asarray(head + np.array([MOUTH_FORWARD_M * np.cos(heading), MOUTH_FORWARD_M * np.sin(heading),
                                       -MOUTH_BELOW_HEAD_M]))


def sit_progress(c: CharacterState) -> float:
    """How far (0..1) the sit-down part of ``c``'s transition in is (after its turn)."""
    return (c.phase_frame - c.turn_frames + 1) / max(1, c.phase_length - c.turn_frames)


def stand_progress(c: CharacterState) -> float:
    """How far (0..1) ``c``'s stand-up (its transition out from a seat) is."""
    return (c.phase_frame + 1) / max(1, c.phase_length)


def box_contact_point(obj: SceneObject, p: NDArray[np.float64], standoff: float = HAND_STANDOFF_M) -> NDArray[np.float64]:
    """The point of ``obj``'s box surface nearest to ``p`` (3,), moved ``standoff`` out along the
    surface's outward direction (a point inside the box goes to its nearest face)."""
    centre = np.array([obj.center[0], obj.center[1], (obj.z_min + obj.z_max) / 2.0])
    axes = np.array([[*obj.right, 0.0], [*obj.facing, 0.0], [0.0, 0.0, 1.0]], dtype=np.float64)
    half = np.array([obj.size[0] / 2.0, obj.size[1] / 2.0, (obj.z_max - obj.z_min) / 2.0])
    local = axes @ (np.asarray(p, dtype=np.float64) - centre)
    q = np.clip(local, -half, half)
    out = local - q
    if float(np.linalg.norm(out)) > 1e-9:
        normal = out / float(np.linalg.norm(out))
    else:  # inside: the face with the least margin
        k = int(np.argmin(half - np.abs(local)))
        sign = 1.0 if local[k] >= 0.0 else -1.0
        q[k] = sign * half[k]
        normal = np.zeros(3)
        normal[k] = sign
    return np.asarray(centre + axes.T @ (q + standoff * normal))


def seat_pelvis(chars: Sequence[CharacterState], labels: Sequence[str], seated: Sequence[bool],
                seat_heights: Sequence[float | None], pelvis: NDArray[np.float64], rots: NDArray[np.float64],
                floor_z: float, seats: Sequence[SceneObject | None] | None = None,
                objects: Sequence[SceneObject] = (),
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(pelvis (N, 3), local rotations (N, 22, 3, 3)) with the pelvis of every character sitting,
    sitting down or standing up put on its seat's height (``seat_heights``: the seat's height
    above the floor per character, None when it has no seat); see the module docstring.
    ``seats``: the seat objects (per character, or None): feet on the floor are kept
    ``FEET_CLEAR_M`` in front of the seat's front face (a couch whose seat point is near its
    front would otherwise have the ankles inside its base; a body sitting turned on a seat with
    no back, ``storyteller.sim.world.legroom.sitting_yaw``: the face it sits towards), and out of the other
    ``objects``' footprints (``storyteller.sim.world.legroom.feet_clear_of``)."""
    rows, goals = [], []
    for i, c in enumerate(chars):
        h = seat_heights[i]
        if h is None:
            continue
        want = floor_z + h + SEAT_PELVIS_ABOVE_SEAT
        if seated[i]:
            k = 1.0
        elif labels[i] == "sit_down" and c.phase == "transition_in":
            k = smoothstep(sit_progress(c))
        elif labels[i] == "stand_up" and c.phase == "transition_out":
            k = 1.0 - smoothstep(stand_progress(c))
        else:
            continue
        top = floor_z + STAND_Z
        rows.append(i)
        goals.append(top + k * (want - top))
    if not rows:
        return pelvis, rots
    idx = np.array(rows)
    old = leg_chain(pelvis[idx], rots[idx])
    ankles = old.ankle.copy()
    toes = old.toe - old.ankle
    low = ankles[..., 2] - floor_z < FOOT_NEAR_FLOOR_M
    ankles[..., 2] = np.where(low, floor_z + ANKLE_HEIGHT, ankles[..., 2])
    for n, i in enumerate(rows):
        seat = None if seats is None else seats[i]
        if seat is None:
            continue
        c = chars[i]
        if c.act_yaw is None:
            facing = np.array([*seat.facing, 0.0])
            front = float(np.dot(seat.center_xy, seat.facing)) + seat.size[1] / 2.0 + FEET_CLEAR_M
        else:  # sitting turned: the seat's extent along the way it sits
            facing = np.array([np.cos(c.act_yaw), np.sin(c.act_yaw), 0.0])
            half = abs(seat.size[0] / 2.0 * float(np.dot(seat.right, facing[:2]))) + abs(
                seat.size[1] / 2.0 * float(np.dot(seat.facing, facing[:2])))
            front = float(np.dot(seat.center_xy, facing[:2])) + half + FEET_CLEAR_M
        for leg in (0, 1):
            short = front - float(ankles[n, leg] @ facing)
            if low[n, leg] and short > 0.0:
                ankles[n, leg] += short * facing
        if objects:
            ankles[n] = feet_clear_of(ankles[n], low[n], seat, objects, toes[n])
    new_pelvis = pelvis.copy()
    new_pelvis[idx, 2] = goals
    sub = solve_chain(leg_chain(new_pelvis[idx], rots[idx]), rots[idx], ankles, np.ones((len(idx), 2), dtype=bool))
    new_rots = rots.copy()
    new_rots[idx] = sub
    return new_pelvis, new_rots


def _shake_point(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Where two right hands (joint positions (22, 3) of each body) meet: the midpoint of the
    animated hands, no lower than ``SHAKE_BELOW_SHOULDER_M`` under the shoulders' mean height."""
    right, shoulder = WRIST_JOINTS[1], SHOULDER_JOINTS[1]
    p = (a[right] + b[right]) / 2.0
    p[2] = max(float(p[2]), (float(a[shoulder, 2]) + float(b[shoulder, 2])) / 2.0 - SHAKE_BELOW_SHOULDER_M)
    return np.asarray(p)


def _target(aim: SceneObject | int | str, wrist: NDArray[np.float64], body: NDArray[np.float64],
            partner: NDArray[np.float64] | None, heading: float) -> NDArray[np.float64]:
    """A working hand's target: on the object, at the handshake's point, or under the mouth."""
    if isinstance(aim, SceneObject):
        return box_contact_point(aim, wrist)
    if partner is not None:
        return _shake_point(body, partner)
    return np.asarray(mouth_point(body, heading) - np.array([0.0, 0.0, HOLD_BELOW_MOUTH_M]))


def _lean(rots: NDArray[np.float64], pelvis: NDArray[np.float64], idx: NDArray[np.int64], side: NDArray[np.int64],
          targets: NDArray[np.float64], weights: NDArray[np.float64], lean: Sequence[bool],
          headings: Sequence[float]) -> NDArray[np.float64]:
    """``rots`` with the trunk of each character whose hand rows (``idx``, ``side``, ``targets``;
    rows with ``lean`` False are left out) cannot reach their target bent forward at ``spine1``
    (about the body's left-right axis) by the least of ``LEAN_STEPS`` that brings every such
    shoulder within ``ARM_LENGTH - LEAN_MARGIN_M`` of its target, times the row's weight."""
    out = rots.copy()
    rows = [k for k in range(len(idx)) if lean[k]]
    if not rows:
        return out
    chars = sorted({int(idx[k]) for k in rows})
    pos, glob = forward_kinematics(rots[chars], pelvis[chars])
    at = {c: n for n, c in enumerate(chars)}
    up = np.array([0.0, 0.0, 1.0])
    for c in chars:
        mine = [k for k in rows if int(idx[k]) == c]
        h = headings[mine[0]]
        axis = np.cross(up, [np.cos(h), np.sin(h), 0.0])
        pivot = pos[at[c], SPINE1]
        best = LEAN_STEPS[-1]
        for theta in LEAN_STEPS:
            bend = _axis_rotation(axis, theta)
            if all(np.linalg.norm(targets[k] - (pivot + bend @ (pos[at[c], SHOULDER_JOINTS[side[k]]] - pivot)))
                   <= ARM_LENGTH[side[k]] - LEAN_MARGIN_M for k in mine):
                best = theta
                break
        angle = best * max(float(weights[k]) for k in mine)
        if angle <= 0.0:
            continue
        bent = _axis_rotation(axis, angle) @ glob[at[c], SPINE1]
        out[c, SPINE1] = glob[at[c], 0].T @ bent
    return out


def _axis_rotation(axis: NDArray[np.float64], angle: float) -> NDArray[np.float64]:
    """The rotation (3, 3) by ``angle`` about the unit ``axis`` (Rodrigues)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.asarray(np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k))


def hand_targets(objects: Mapping[str, SceneObject], chars: Sequence[CharacterState], pelvis: NDArray[np.float64], rots: NDArray[np.float64],
                 fps: float) -> NDArray[np.float64]:
    """Local rotations (N, 22, 3, 3) with the working hands of characters acting on an object
    moved onto it (``objects``: the scene's objects by name), and shaking hands meeting (see the
    module docstring); the input where no character is."""
    rows: list[int] = []
    sides: list[int] = []
    weights: list[float] = []
    aims: list[SceneObject | int | str] = []  # the object, the row of the partner shaking hands, or "mouth"
    index = {c.name: i for i, c in enumerate(chars)}
    for i, c in enumerate(chars):
        if c.phase != "interacting":
            continue
        a = c.assignment
        if a is None:
            continue
        spec = action_spec(a.action)
        if spec.gesture in MOUTH_GESTURES:  # standing or seated
            hand, w = mouth_weight(spec.gesture, c.phase_frame, fps, spec.duration_s)
            if w > 0.0:
                rows.append(i)
                sides.append(hand)
                weights.append(w)
                aims.append("mouth")
            continue
        if a.seat is not None:
            continue
        aim: SceneObject | int | None = None
        if spec.gesture == "handshake":
            other = next((index[p] for p in a.partners if p in index), None)
            oa = None if other is None else chars[other].assignment
            if other is not None and oa is not None and chars[other].phase == "interacting" \
                    and action_spec(oa.action).gesture == "handshake":
                aim = other
        elif spec.gesture in HAND_GESTURES and a.focus is not None:
            aim = objects.get(a.focus)
        if aim is None:
            continue
        w = reach_weight(spec.gesture, spec.loops, c.phase_frame, c.phase_length, fps)
        if w <= 0.0:
            continue
        for hand in ((0, 1) if spec.gesture in BOTH_HANDS else (1,)):
            rows.append(i)
            sides.append(hand)
            weights.append(w)
            aims.append(aim)
    if not rows:
        return rots
    idx = np.array(rows)
    side = np.array(sides)
    need = sorted({*rows, *(a for a in aims if isinstance(a, int))})  # the acting and their handshake partners
    at = {r: k for k, r in enumerate(need)}
    pos, _ = forward_kinematics(rots[need], pelvis[need])
    wrists = pos[[at[r] for r in rows], np.array(WRIST_JOINTS)[side]]
    targets = np.array([_target(aim, p, pos[at[r]], None if not isinstance(aim, int) else pos[at[aim]], chars[r].heading)
                        for r, aim, p in zip(rows, aims, wrists, strict=True)])
    out = _lean(rots, pelvis, idx, side, targets, np.array(weights), [isinstance(a, SceneObject) for a in aims],
                [chars[r].heading for r in rows])
    # one row per hand: a character with both hands goes through twice, the second on the first's result
    first = np.ones(len(idx), dtype=bool)
    first[1:] = idx[1:] != idx[:-1]
    for pick in (first, ~first):
        if not pick.any():
            continue
        k = idx[pick]
        out[k] = solve_arms(pelvis[k], out[k], side[pick], targets[pick], np.array(weights)[pick])
    return out

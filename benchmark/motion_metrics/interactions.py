"""Interactions that read: hands at the object, seated at the seat's height, transition times.

Read from a track's per-frame action labels (database keys: ``use_coffee_maker``, ``sit_idle``,
``drink@seated``...) and the scene, so any run folder measures without its plans:

- **hand to object** at the reach frame of a ``use_*`` action, and of every action whose hands
  work on an object (``hands_on_object``: ``open_fridge``, ``turn_on_tv``, ...): for the first ``REACH_WINDOW_S``
  seconds of each run of the label, the frame where the nearer wrist is closest to the box of
  the object the action names (``storyteller.sim.world.facing.object_named_by`` at the run's first root
  position); that distance (metres, 0 inside the box). Target: within ``HAND_TARGET_M`` for
  90% of reaches;
- **hand to mouth** of ``drink`` and ``eat`` (gestures ``MOUTH_GESTURES``, standing or
  seated): for the first ``REACH_WINDOW_S`` seconds of each run of the label, the least distance
  from the nearer wrist to the mouth (``mouth_points``: ``MOUTH_FORWARD_M`` in front of and
  ``MOUTH_BELOW_HEAD_M`` under the head joint, forward taken from the shoulders); the cup or
  the food is in the hand, so the wrist stands ``HOLD_BELOW_MOUTH_M`` under the lips at best.
  Target: within ``HAND_TARGET_M``, as for objects;
- **seat height** while seated (``sit_idle`` and ``...@seated`` frames): the pelvis height
  against the seat surface of the seat under it plus ``PELVIS_ABOVE_SEAT_M``; the median
  absolute error of each sitting (metres; target 3 cm);
- **transition time** of ``sit_down`` and ``stand_up``: the length of each run of the label
  (seconds).

Facing at the start of an interaction and while it lasts is
:mod:`storyteller.benchmark.motion_facing`'s (it needs the run's plans).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from storyteller.benchmark.motion_metrics.bodies import Box, signed_distance
from storyteller.benchmark.motion_metrics.gait import label_runs
from storyteller.sim.body.skeleton import JOINT_INDEX
from storyteller.sim.motion.action_labels import SEATED_SUFFIX, action_spec
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.world.contacts import (
    HOLD_BELOW_MOUTH_M,
    MOUTH_BELOW_HEAD_M,
    MOUTH_FORWARD_M,
    MOUTH_GESTURES,
)
from storyteller.sim.world.facing import needs_reach, object_named_by
from storyteller.sim.world.legroom import seat_surface

REACH_WINDOW_S = 4.0
HAND_TARGET_M = 0.15
SEAT_TARGET_M = 0.03
PELVIS_ABOVE_SEAT_M = 0.09
"""Height of the pelvis joint above the seat surface of an adult sitting upright (the flesh of
the buttocks and thighs under the hip joints); our own round figure."""
SEAT_SEARCH_M = 0.8  # a seat whose footprint lies within this of the pelvis is the one sat on
WRISTS = (JOINT_INDEX["left_wrist"], JOINT_INDEX["right_wrist"])
TRANSITIONS = ("sit_down", "stand_up")


def is_seated_label(label: str) -> bool:
    return label == "sit_idle" or label.endswith(SEATED_SUFFIX)


def hands_on_object(label: str) -> bool:
    """Whether ``label`` (a database key) is an action whose hands work on an object
    (``storyteller.sim.world.facing.needs_reach``: reach, wipe, write, type, carry); False for unknown labels."""
    try:
        return needs_reach(label.split("@", 1)[0])
    except ValueError:
        return False


def is_use_action(action: str) -> bool:
    return action.startswith("use_")


def hand_distance(wrists: NDArray[np.float64], obj: SceneObject) -> tuple[int, float]:
    """(frame, metres) where the nearer of ``wrists`` (F, 2, 3) is closest to ``obj``'s box."""
    d = np.maximum(signed_distance(np.asarray(wrists, dtype=np.float64), Box.of(obj)), 0.0).min(axis=1)
    k = int(np.argmin(d))
    return k, float(d[k])


@dataclass(frozen=True)
class Reach:
    action: str
    obj: str
    frame: int
    distance: float


def reaches(joints: NDArray[np.float64], labels: Sequence[str], scene: Scene, fps: float) -> list[Reach]:
    """Hand-to-object distance at the reach frame of every run of a ``use_*`` label or of a
    label whose hands work on an object (runs whose label names no object nearby are left out)."""
    j = np.asarray(joints, dtype=np.float64)
    out = []
    for label in sorted({lab for lab in labels if lab.startswith("use_") or hands_on_object(lab)}):
        for a, b in label_runs(labels, label):
            obj = object_named_by(scene, label, (float(j[a, 0, 0]), float(j[a, 0, 1])))
            if obj is None:
                continue
            end = min(b, a + round(REACH_WINDOW_S * fps))
            k, dist = hand_distance(j[a:end][:, list(WRISTS)], obj)
            out.append(Reach(label, obj.name, a + k, dist))
    return out


def brings_to_mouth(label: str) -> bool:
    """Whether ``label`` (a database key) is an action that brings a hand to the mouth (drink, eat)."""
    try:
        return action_spec(label.split("@", 1)[0]).gesture in MOUTH_GESTURES
    except ValueError:
        return False


def mouth_points(joints: NDArray[np.float64]) -> NDArray[np.float64]:
    """The mouth (F, 3) of joint positions (F, 22, 3): in front of and under the head joint,
    forward being square to the shoulders, horizontal."""
    j = np.asarray(joints, dtype=np.float64)
    across = j[:, JOINT_INDEX["left_shoulder"]] - j[:, JOINT_INDEX["right_shoulder"]]
    fwd = np.stack([across[:, 1], -across[:, 0], np.zeros(len(j))], axis=1)  # (left - right) x up
    fwd /= np.maximum(np.linalg.norm(fwd, axis=1, keepdims=True), 1e-9)
    return np.asarray(j[:, JOINT_INDEX["head"]] + MOUTH_FORWARD_M * fwd - np.array([0.0, 0.0, MOUTH_BELOW_HEAD_M]))


def mouth_reaches(joints: NDArray[np.float64], labels: Sequence[str], fps: float) -> list[Reach]:
    """Wrist-to-mouth distance (metres, less ``HOLD_BELOW_MOUTH_M``, not below 0) at the frame it
    is least, in the first ``REACH_WINDOW_S`` of every run of a drink / eat label."""
    j = np.asarray(joints, dtype=np.float64)
    out = []
    for label in sorted({lab for lab in labels if brings_to_mouth(lab)}):
        for a, b in label_runs(labels, label):
            end = min(b, a + round(REACH_WINDOW_S * fps))
            mouth = mouth_points(j[a:end])
            d = np.linalg.norm(j[a:end][:, list(WRISTS)] - mouth[:, None], axis=-1).min(axis=1)
            k = int(np.argmin(d))
            out.append(Reach(label, "mouth", a + k, max(float(d[k]) - HOLD_BELOW_MOUTH_M, 0.0)))
    return out


def seat_under(scene: Scene, xy: NDArray[np.float64]) -> SceneObject | None:
    """The seat whose footprint is nearest to ``xy`` (within ``SEAT_SEARCH_M``), or None."""
    best: tuple[float, SceneObject] | None = None
    for o in scene.objects:
        if not o.is_seat:
            continue
        local = np.abs(o.to_local(np.asarray(xy, dtype=np.float64))) - np.array(o.size[:2]) / 2.0
        d = float(np.linalg.norm(np.maximum(local, 0.0)))
        if d <= SEAT_SEARCH_M and (best is None or d < best[0]):
            best = (d, o)
    return None if best is None else best[1]


def seat_errors(joints: NDArray[np.float64], labels: Sequence[str], scene: Scene) -> list[float]:
    """Per sitting (a run of seated labels): median |pelvis height - seat height| in metres."""
    j = np.asarray(joints, dtype=np.float64)
    flags = ["s" if is_seated_label(lab) else "" for lab in labels]
    out = []
    for a, b in label_runs(flags, "s"):
        seat = seat_under(scene, j[(a + b) // 2, 0, :2])
        if seat is None:
            continue
        want = seat_surface(seat) + PELVIS_ABOVE_SEAT_M
        out.append(float(np.median(np.abs(j[a:b, 0, 2] - want))))
    return out


def transition_times(labels: Sequence[str], fps: float) -> dict[str, list[float]]:
    """Seconds of each run of ``sit_down`` and of ``stand_up``."""
    return {t: [(b - a) / fps for a, b in label_runs(labels, t)] for t in TRANSITIONS}

"""What a character faces when it acts, and how near it must stand to an object it uses.

The planner sends a facing with every assignment (``Assignment.facing_xy``), computed from the
point it sampled. A character does not always act on that point: it may stop short of it, on a
neighbouring cell, or beside a body that stands on it (the stall rules of ``storyteller.sim.world.step``),
and a small planning model may point the facing anywhere. So the world turns a standing
character, right before it acts, from where it actually stands:

- to its partners (``Assignment.partners``) for a partner action (chat, handshake...): to the
  mean of their standing points, so two partners face each other;
- else to the nearest point of the footprint of the object it uses (``Assignment.focus``), so a
  character beside a wide counter faces the counter squarely and one past the end of a small
  appliance turns towards it;
- else to the planner's facing. A seated character always faces its seat's front.

``focus_object`` names the object an assignment uses, for ``AssignEvent.from_plans``: the
nearest object (within ``FOCUS_RANGE_M`` of the target) whose label the action names
(``use_coffee_maker`` -> a ``coffee_maker``; ``clean_white_board`` -> a ``whiteboard``), else,
for an action whose hands work on an object (``take_out_book``: the book is a prop, the shelf
is worked on), the first object the plan's area names ("adjacent to bookshelf_1"), else none:
the planner's facing stands (a wave towards someone, a drink by the window). Where the planner looks (``set_orientation``) never picks the
object: a small model points it at bystanders.

Actions whose hands work on the object (``needs_reach``: reach, wipe, write, type, carry) are
done within ``REACH_M`` of the object's footprint (root to nearest footprint point), or as near
as the furniture around the object allows (``StandTargets.within_reach``). Pure geometry: no
state, no randomness. Angles are radians (world yaw from +x toward +y), distances metres.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.motion.action_labels import action_spec
from storyteller.sim.scene.model import Scene, SceneObject

REACH_M = 0.6
"""Metres from a standing root to the nearest point of an object's footprint within which its
hands work on the object (shoulder ahead of the pelvis plus an arm, leaning a little); the
planner's "interact with" area uses the same distance."""
REACH_SLACK_M = 0.2
"""Metres beyond the nearest standing point that still count as within reach of an object that
furniture keeps further away than ``REACH_M`` (a laptop deep on a desk: the body stands at the
desk's edge and reaches 0.2 m past a body radius, as the planner's area allows)."""
FOCUS_RANGE_M = 1.5
"""Metres from an assignment's target within which an object whose label the action names is
taken as the object used."""
OBJECT_NAME = re.compile(r"(?<![a-z0-9_])[a-z][a-z0-9_]*_\d+")
"""An object name in a plan's area text ("interact with coffee_maker_1"), starting a word (so a
search tries each word once: linear in the text)."""
REACH_GESTURES = frozenset({"reach", "reach_low", "wipe", "write", "type", "carry"})
"""Gestures (``ActionSpec.gesture``) of actions whose hands work on the object used."""


def needs_reach(action: str) -> bool:
    """Whether ``action``'s hands work on the object it uses (so it is done within reach)."""
    return action_spec(action).gesture in REACH_GESTURES


def surface_point(obj: SceneObject, xy: Sequence[float] | NDArray[np.float64]) -> NDArray[np.float64]:
    """The point of ``obj``'s footprint nearest to ``xy`` (``xy`` itself when inside it)."""
    local = obj.to_local(np.asarray(xy, dtype=np.float64))
    hw, hd = obj.size[0] / 2.0, obj.size[1] / 2.0
    u, v = float(np.clip(local[0], -hw, hw)), float(np.clip(local[1], -hd, hd))
    return np.asarray(obj.center_xy + u * obj.right + v * np.asarray(obj.facing, dtype=np.float64))


def surface_distance(obj: SceneObject, xy: Sequence[float] | NDArray[np.float64]) -> float:
    """Metres from ``xy`` to ``obj``'s footprint (0 inside it)."""
    return float(np.linalg.norm(surface_point(obj, xy) - np.asarray(xy, dtype=np.float64)))


def heading_to_object(obj: SceneObject, xy: Sequence[float] | NDArray[np.float64]) -> float | None:
    """Yaw from ``xy`` to the nearest point of ``obj``'s footprint (to its centre from inside
    the footprint); None when ``xy`` is the centre itself."""
    p = np.asarray(xy, dtype=np.float64)
    for q in (surface_point(obj, p), obj.center_xy):
        d = q - p
        if float(np.hypot(d[0], d[1])) > 1e-6:
            return math.atan2(float(d[1]), float(d[0]))
    return None


def heading_to_points(xy: Sequence[float] | NDArray[np.float64], points: NDArray[np.float64]) -> float | None:
    """Yaw from ``xy`` to the mean of ``points`` (K, 2); None when there are none or it is ``xy``."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(pts) == 0:
        return None
    d = pts.mean(axis=0) - np.asarray(xy, dtype=np.float64)
    if float(np.hypot(d[0], d[1])) <= 1e-6:
        return None
    return math.atan2(float(d[1]), float(d[0]))


def names_label(action: str, label: str) -> bool:
    """Whether a run of ``action``'s words spells ``label`` (underscores aside): ``tv`` in
    ``turn_on_tv``, ``whiteboard`` and ``white_board`` in ``clean_white_board``."""
    words = action.split("_")
    want = label.replace("_", "")
    return any("".join(words[i:j]) == want for i in range(len(words)) for j in range(i + 1, len(words) + 1))


def object_named_by(scene: Scene, action: str, xy: Sequence[float]) -> SceneObject | None:
    """The object nearest to ``xy`` (footprint distance, within ``FOCUS_RANGE_M``; ties in
    scene order) whose label ``action`` names, or None."""
    p = np.asarray(xy, dtype=np.float64)
    named = [(surface_distance(o, p), k) for k, o in enumerate(scene.objects) if names_label(action, o.label)]
    named = [n for n in named if n[0] <= FOCUS_RANGE_M]
    return scene.objects[min(named)[1]] if named else None


def focus_object(scene: Scene, action: str, target_xy: Sequence[float], area: str = "") -> str | None:
    """The object a standing assignment uses (see the module docstring), or None."""
    named = object_named_by(scene, action, target_xy)
    if named is not None:
        return named.name
    if needs_reach(action):
        for name in OBJECT_NAME.findall(area):
            if name in scene.by_name:
                return str(name)
    return None

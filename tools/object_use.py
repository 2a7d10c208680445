"""One object, one user: which actions use an object alone, and who is using what.

The data (one place): :data:`SINGLE_USER_ACTIONS` maps an action label to the object labels it
uses alone (making coffee at a coffee maker, writing on a whiteboard, opening a fridge); any
other ``use_<label>`` action uses ``<label>`` alone too (``use_sink``), unless it is listed in
:data:`SHARED_ACTIONS`. Actions done together or needing no object (watch TV, chat, dance,
drink, read) are shared: any number of characters may do them at one object. An object with
:data:`SPOT_WIDTH_M` (a whiteboard) has one place per that many metres of its width; others
have one.

A character *uses* an object when its action is single-user, it is still doing it (busy with
an ongoing event, or the action loops, as an interruptible event does) and it stands at or is
heading to the object: the nearest object of a used label within :data:`REACH_M` of its target
(or, without one, its position).

Guarantee: :func:`use_conflicts` names every plan that would put more users at an object than
it has places, counting the users of the world (characters the plans do not move) and the
plans before it; the spatial API refuses such plans (``ObjectInUseError``) before anything is
applied. Pure: no clock, no I/O.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from storyteller.sim.motion.action_labels import ACTION_SPECS
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.world.events import PlanLike
from storyteller.tools.scene_graph import point_footprint_distance

Point = tuple[float, float]

SINGLE_USER_ACTIONS: dict[str, tuple[str, ...]] = {
    "use_coffee_maker": ("coffee_maker", "coffee_machine", "espresso_machine"),
    "use_toaster": ("toaster",),
    "use_microwave": ("microwave",),
    "use_dishwasher": ("dishwasher",),
    "use_water_dispenser": ("water_dispenser", "water_cooler"),
    "use_laptop": ("laptop",),
    "work_on_computer": ("monitor", "computer"),
    "open_fridge": ("fridge", "refrigerator"),
    "close_fridge": ("fridge", "refrigerator"),
    "take_out_drink": ("fridge", "refrigerator"),
    "open_cabinet": ("cabinet",),
    "close_cabinet": ("cabinet",),
    "take_out_document": ("cabinet", "filing_cabinet"),
    "take_out_book": ("bookshelf", "bookcase"),
    "turn_on_tv": ("tv",),
    "turn_off_tv": ("tv",),
    "turn_on_record_player": ("record_player",),
    "turn_off_record_player": ("record_player",),
    "write_on_white_board": ("white_board", "whiteboard"),
    "clean_white_board": ("white_board", "whiteboard"),
    "pay_bill": ("cash_register",),
}
"""Action label -> the object labels one character at a time uses it at (the TV's remote:
turning the TV on or off is one person's act; watching it is shared)."""
SHARED_ACTIONS: frozenset[str] = frozenset({
    "idle", "walk", "sit_down", "sit_idle", "stand_up", "chat", "discuss", "attend_meeting", "handshake", "hug",
    "dance", "wave", "drink", "eat", "use_smartphone", "read_book", "watch_tv", "listen_to_music", "clean_table",
    "deliver_menu", "serve_food", "serve_drink", "take_order", "order_food", "order_drink",
})
"""Actions any number of characters may do at one object (or that need none)."""
SPOT_WIDTH_M: dict[str, float] = {"white_board": 1.2, "whiteboard": 1.2}
"""Labels with one place per this many metres of width (a wide whiteboard holds two writers)."""
REACH_M = 1.5
"""Metres from an object's footprint within which a character is at it."""


class CharacterLike(Protocol):
    """What is read of a character (``tools.character_states.CharacterState``)."""

    @property
    def name(self) -> str: ...
    @property
    def action(self) -> str: ...
    @property
    def busy(self) -> bool: ...
    @property
    def position(self) -> Point | None: ...
    @property
    def target_position(self) -> Point | None: ...


def used_labels(action: str) -> tuple[str, ...]:
    """The object labels ``action`` uses alone (empty: a shared action or none)."""
    if action in SHARED_ACTIONS:
        return ()
    if action in SINGLE_USER_ACTIONS:
        return SINGLE_USER_ACTIONS[action]
    return (action.removeprefix("use_"),) if action.startswith("use_") else ()


def places(obj: SceneObject) -> int:
    """Characters that may use ``obj`` at once."""
    width = SPOT_WIDTH_M.get(obj.label)
    return 1 if width is None else max(1, int(max(obj.size[0], obj.size[1]) // width))


def used_object(action: str, at: Point, scene: Scene) -> SceneObject | None:
    """The object a character doing ``action`` at ``at`` uses alone (the nearest of its labels
    within REACH_M), or None."""
    labels = used_labels(action)
    if not labels:
        return None
    candidates = [o for o in scene.objects if o.label in labels]
    if not candidates:
        return None
    xy = np.array([at], dtype=float)
    dist, best = min((float(point_footprint_distance(o, xy)[0]), o.name) for o in candidates)
    return scene.by_name[best] if dist <= REACH_M else None


def still_doing(c: CharacterLike) -> bool:
    """Whether ``c`` is still doing its action: busy, or the action loops (an interruptible event)."""
    spec = ACTION_SPECS.get(c.action)
    return c.busy or (spec is not None and spec.loops)


def users_of_objects(characters: Iterable[CharacterLike], scene: Scene, skip: Iterable[str] = ()) -> dict[str, list[str]]:
    """Object name -> the characters (not in ``skip``) using it, in the given order."""
    skipped = set(skip)
    out: dict[str, list[str]] = {}
    for c in characters:
        at = c.target_position or c.position
        if c.name in skipped or at is None or not still_doing(c):
            continue
        obj = used_object(c.action, at, scene)
        if obj is not None:
            out.setdefault(obj.name, []).append(c.name)
    return out


@dataclass(frozen=True)
class UseConflict:
    """``character`` was planned to use ``obj``, which ``users`` already fill."""

    character: str
    obj: str
    users: tuple[str, ...]

    @property
    def message(self) -> str:
        who = " and ".join(self.users)
        return f"{self.obj} is being used by {who}; choose another object or wait"


def use_conflicts(plans: Sequence[PlanLike], characters: Iterable[CharacterLike], scene: Scene) -> list[UseConflict]:
    """Plans that would put more users at an object than it has places (see the module docstring)."""
    users = users_of_objects(characters, scene, skip={p.character for p in plans})
    out = []
    for plan in plans:
        obj = used_object(plan.action, plan.position, scene)
        if obj is None:
            continue
        taken = users.setdefault(obj.name, [])
        if len(taken) >= places(obj):
            out.append(UseConflict(plan.character, obj.name, tuple(taken)))
        else:
            taken.append(plan.character)
    return out


def shared_use_frames(
    labels: Mapping[str, Sequence[str]], positions: Mapping[str, np.ndarray], scene: Scene
) -> list[tuple[int, str, tuple[str, ...]]]:
    """Frames where more characters act on one object alone than it has places: (frame, object,
    characters). ``labels``: per character the action label of every frame; ``positions``: per
    character (frames, >= 2) root positions (x, y first)."""
    n = min((len(v) for v in labels.values()), default=0)
    out = []
    for f in range(n):
        at: dict[str, list[str]] = {}
        for name, seq in labels.items():
            p = positions[name][f]
            obj = used_object(seq[f].split("@")[0], (float(p[0]), float(p[1])), scene)
            if obj is not None:
                at.setdefault(obj.name, []).append(name)
        out += [(f, o, tuple(who)) for o, who in at.items() if len(who) > places(scene.by_name[o])]
    return out


def single_user_labels() -> frozenset[str]:
    """Every object label some action uses alone (:data:`SINGLE_USER_ACTIONS`)."""
    return frozenset(label for labels in SINGLE_USER_ACTIONS.values() for label in labels)


def busy_named_objects(
    named_labels: Iterable[str], characters: Iterable[CharacterLike], scene: Scene, skip: Iterable[str] = (),
) -> dict[str, list[str]]:
    """The objects of each single-user label in ``named_labels`` (the labels an event's words
    name) when *every* object of that label is in use by characters outside ``skip``: object
    name -> its users. Empty when a free one of the label is left (the event can use that one)."""
    users = users_of_objects(characters, scene, skip)
    out: dict[str, list[str]] = {}
    for label in dict.fromkeys(named_labels):
        if label not in single_user_labels():
            continue
        objects = [o for o in scene.objects if o.label == label]
        if objects and all(len(users.get(o.name, [])) >= places(o) for o in objects):
            out.update({o.name: users[o.name] for o in objects})
    return out

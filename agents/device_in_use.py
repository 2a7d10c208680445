"""An event about a device someone else is using alone: its characters wait for it.

"Luca also has to fetch a carton of juice from the fridge" while Dalia stands at the open fridge:
the fridge is used by one person at a time (``tools.object_use``), so Luca cannot do it now and
waits. The spatial API refuses a plan that *uses* a device in use (``ObjectInUseError``: told
once, then the character waits by it), but a small model often writes one that avoids the device
instead: Luca drinking on a chair. Here the event's own words decide: when they name a
single-user device (its relations' landmarks taken out: "waits by the fridge" is about where,
not what) and every device of that kind is in use by characters outside the event, and no plan
uses one, each plan becomes waiting where it was placed (idle, facing the device unless seated):
:func:`waiting_for_busy_device`. No model call is made for it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from agents.messages import PlannedCharacter
from agents.relation_words import labels_about
from sim.scene.model import Scene
from tools.character_states import WorldView
from tools.object_use import busy_named_objects, used_object


def busy_device(
    text: str, plans: Sequence[PlannedCharacter], world: WorldView, scene: Scene, event_characters: Sequence[str],
) -> str | None:
    """The device an event with words ``text`` is about that nobody outside the event leaves
    free, when no plan of ``plans`` uses one (see the module docstring); else None."""
    named = labels_about(text, scene.labels, [c.name for c in world.characters])
    busy = busy_named_objects(named, world.characters, scene, skip=event_characters)
    if not busy:
        return None
    for plan in plans:
        used = used_object(plan.action, plan.position, scene)
        if used is not None and used.name in busy:
            return None  # the plan uses it: the spatial API's own check decides
    return next(iter(busy))


def waiting_for_busy_device(
    text: str, plans: Sequence[PlannedCharacter], world: WorldView, scene: Scene, event_characters: Sequence[str],
) -> tuple[PlannedCharacter, ...]:
    """``plans``, each turned into waiting for the busy device the words are about (idle where it
    was placed, facing the device unless seated); ``plans`` unchanged when there is none."""
    device = busy_device(text, plans, world, scene, event_characters)
    if device is None:
        return tuple(plans)
    cx, cy = scene.by_name[device].center[:2]
    out = []
    for plan in plans:
        dx, dy = cx - plan.position[0], cy - plan.position[1]
        norm = math.hypot(dx, dy)
        facing = plan.facing if plan.seat is not None or norm < 1e-6 else (dx / norm, dy / norm)
        out.append(plan.model_copy(update={"action": "idle", "facing": facing,
                                           "area": f"{plan.area}, waiting for {device}"}))
    return tuple(out)

"""An event about a device someone else is using alone, or about sitting at a place whose seats
are all taken: its characters wait for it.

"Luca also has to fetch a carton of juice from the fridge" while Dalia stands at the open fridge:
the fridge is used by one person at a time (``storyteller.tools.object_use``), so Luca cannot do it now and
waits. The spatial API refuses a plan that *uses* a device in use (``ObjectInUseError``: told
once, then the character waits by it), but a small model often writes one that avoids the device
instead: Luca drinking on a chair. Here the event's own words decide: when they name a
single-user device (its relations' landmarks taken out: "waits by the fridge" is about where,
not what) and every device of that kind is in use by characters outside the event, and no plan
uses one, each plan becomes waiting where it was placed (idle, facing the device unless seated):
:func:`waiting_for_busy_device`. No model call is made for it.

The same holds for a place people sit at (a table, desk or counter: :func:`full_place`): "Noor
orders a tea at the counter" while someone sits on every stool at the counter, and a program that
seats her at another table instead, makes her wait (where she was placed). Words that name a
place with a free seat left, a plan that sits at the named place, or one that does not sit at all
("wipes the counter") leave the plans as they are.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence

from storyteller.agents.messages import PlannedCharacter
from storyteller.agents.relation_words import labels_about
from storyteller.sim.scene.model import Scene
from storyteller.tools.character_states import WorldView
from storyteller.tools.object_use import busy_named_objects, used_object
from storyteller.tools.place_relations import sits_at, table_of


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


def full_place(text: str, plans: Sequence[PlannedCharacter], scene: Scene, free_seats: Collection[str]) -> str | None:
    """The place to sit at (a table, desk or counter) the words ``text`` are about when every seat
    at each such place they name is taken (not in ``free_seats``) and every plan sits somewhere
    else (see the module docstring); else None."""
    if not plans or any(p.seat is None for p in plans):
        return None
    places = [label for label in labels_about(text, scene.labels)
              if any(o.label == label and sits_at(o) for o in scene.objects)]
    if not places:
        return None
    at: dict[str, str] = {}  # seat -> the label of the place it is at
    for seat in scene.objects:
        if seat.is_seat and (thing := table_of(scene, seat)) is not None and thing.label in places:
            at[seat.name] = thing.label
    if not at or any(s in free_seats for s in at) or any(p.seat in at for p in plans):
        return None
    label = next(label for label in places if label in at.values())
    return next(o.name for o in scene.objects if o.label == label and sits_at(o))


def waiting_for_busy_device(
    text: str, plans: Sequence[PlannedCharacter], world: WorldView, scene: Scene, event_characters: Sequence[str],
    free_seats: Collection[str] | None = None,
) -> tuple[PlannedCharacter, ...]:
    """``plans``, each turned into waiting for the busy device the words are about, or for a seat
    at the full place they name when ``free_seats`` is given (idle where it was placed, facing
    the device unless seated); ``plans`` unchanged when there is none."""
    device = busy_device(text, plans, world, scene, event_characters)
    if device is None and free_seats is not None:
        device = full_place(text, plans, scene, free_seats)
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

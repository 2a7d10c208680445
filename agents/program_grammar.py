"""A GBNF grammar that only admits well-formed ``parse_event()`` programs for one event.

Small local models write programs that call functions that do not exist, name objects that are
not in the scene (``refrigerator_1``, ``phone``) or run on until the token budget cuts a string
in half. Decoding under this grammar (llama.cpp) makes those mistakes impossible: the program
has exactly one block per event character, in event order::

    def parse_event():
        c1 = get_character("Ava")
        c1.set_position(get_area_close_to("table_3"))
        c1.set_orientation("tv_1")
        c1.set_target_action("watch_tv")

where the area is one of the spatial API's listed area functions (``SpatialAPI.functions()``) over the scene's object names (a
seat function only over seats not in use), the orientation target an object or another
character, and the action one of the offered labels. For an event, :func:`event_program_grammar`
narrows the objects and seats further to the shortlist its words single out
(:mod:`agents.shortlist`: "sits on the couch" offers the free couches, "the chair by the
window" the chairs close to a window), or keeps them all when the words name nothing. The program still runs in the sandbox and
through the spatial API like any other; only what the model can write is narrowed. Providers
that cannot decode under a grammar ignore it and get the same prompt.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import numpy as np

from agents.shortlist import event_shortlist
from sim.motion.action_labels import playable_seated
from sim.scene.model import Scene, SceneObject
from tools.areas import seat_slots
from tools.position_sampling import MIN_SEPARATION
from tools.spatial_api import SpatialAPI


def area_functions() -> tuple[tuple[str, ...], tuple[str, ...], str]:
    """The listed area functions of ``tools.spatial_api.SpatialAPI``: those on one object, those
    on two objects, and the seat function (the grammar offers exactly what the prompt lists)."""
    listed = [f for f in SpatialAPI.functions() if f.listed]
    one = tuple(f.name for f in listed if f.kind == "area" and len(f.parameters) == 1)
    two = tuple(f.name for f in listed if f.kind == "area" and len(f.parameters) == 2)
    seat = [f.name for f in listed if f.kind == "seat_area"]
    if len(seat) != 1 or not one:
        raise ValueError(f"the spatial API lists {len(seat)} seat functions and {len(one)} one-object areas")
    return one, two, seat[0]


def _literal(text: str) -> str:
    """A GBNF string literal for ``text`` (JSON escaping is valid GBNF escaping)."""
    return json.dumps(text, ensure_ascii=True)


def _quoted(name: str) -> str:
    """The GBNF literal of a Python string literal: ``"chair_1"`` in the program."""
    return _literal(json.dumps(name, ensure_ascii=True))


def _choice(rule: str, names: Sequence[str]) -> str:
    if not names:
        raise ValueError(f"grammar rule {rule!r} has no alternatives")
    return f"{rule} ::= " + " | ".join(_quoted(n) for n in dict.fromkeys(names))


def program_grammar(
    event_characters: Sequence[str],
    objects: Sequence[str],
    seats: Sequence[str],
    action_labels: Sequence[str],
    other_characters: Sequence[str] = (),
    seated_labels: Sequence[str] | None = None,
) -> str:
    """The grammar of one event's program (see the module docstring).

    ``objects``: every object an area may be built on; ``seats``: the free seats (the sit
    function is offered only when there is one); ``other_characters``: characters that may be
    looked at besides the objects and the event's own characters; ``seated_labels``: the
    labels that can be played sitting (None: all), the only ones offered after a sit area."""
    if not event_characters:
        raise ValueError("an event without characters has no program")
    if not action_labels:
        raise ValueError("no action labels to choose from")
    sit_labels = list(action_labels if seated_labels is None else [a for a in action_labels if a in set(seated_labels)])
    can_sit = bool(seats) and bool(sit_labels)
    lines = ["root ::= " + _literal("```python\ndef parse_event():\n") + " "
             + " ".join(f"block{i}" for i in range(1, len(event_characters) + 1)) + " " + _literal("```")]
    for i, name in enumerate(event_characters, start=1):
        var = f"c{i}"
        head = _literal(f"    {var} = get_character({json.dumps(name)})\n    {var}.set_position(")
        look = _literal(f")\n    {var}.set_orientation(") + " look " + _literal(f")\n    {var}.set_target_action(")
        end = _literal(")\n")
        stand = f"area {look} label {end}"
        body = f"( sitarea {look} sitlabel {end} | {stand} )" if can_sit else stand
        lines.append(f"block{i} ::= {head} {body}")
    one_object, two_objects, seat_area = area_functions()
    areas = [f"{_literal(fn + '(')} object {_literal(')')}" for fn in one_object]
    areas += [f"{_literal(fn + '(')} object {_literal(', ')} object {_literal(')')}" for fn in two_objects]
    if can_sit:
        lines.append(f"sitarea ::= {_literal(seat_area + '(')} seat {_literal(')')}")
        lines.append(_choice("seat", seats))
        lines.append(_choice("sitlabel", sit_labels))
    lines.append("area ::= " + " | ".join(areas))
    lines.append(_choice("object", objects))
    lookable = [*objects, *(c for c in (*event_characters, *other_characters) if c not in objects)]
    lines.append(_choice("look", lookable))
    lines.append(_choice("label", action_labels))
    return "\n".join(lines) + "\n"


def event_program_grammar(
    scene: Scene, event_characters: Sequence[str], characters: Sequence[Any],
    seats_in_use: Sequence[str], action_labels: Sequence[str], activity: str = "",
) -> str:
    """:func:`program_grammar` for an event in ``scene``: the objects and the seats nobody else
    holds or stands on, narrowed to the event's shortlist (:func:`agents.shortlist.event_shortlist`
    of ``activity``; all of them when it has none), the offered labels; ``characters`` are the
    roster (objects with ``name``, ``seat``, ``position``)."""
    others = [c for c in characters if c.name not in event_characters]
    taken = set(seats_in_use) | {c.seat for c in others if getattr(c, "seat", None)}
    placed = np.array([c.position for c in others if c.position is not None], dtype=float).reshape(-1, 2)

    def free(obj: SceneObject) -> bool:
        """The sampler's own rule: a one-place seat nobody holds, or a slot of it (a couch has
        several) clear of everyone else by the minimum separation."""
        slots = seat_slots(obj)
        if obj.name in taken and len(slots) <= 1:
            return False
        if len(placed) == 0 or not slots:
            return True
        return any(float(np.min(np.linalg.norm(placed - np.asarray(s.position), axis=1))) >= MIN_SEPARATION for s in slots)

    free_seats = [o.name for o in scene.objects if o.is_seat and free(o)]
    shortlist = event_shortlist(scene, activity, free_seats, action_labels)
    return program_grammar(
        event_characters,
        list(shortlist.objects) or [o.name for o in scene.objects],
        list(shortlist.seats) or free_seats,
        action_labels,
        [c.name for c in characters if c.name not in event_characters],
        seated_labels=[a for a in action_labels if playable_seated(a)],
    )


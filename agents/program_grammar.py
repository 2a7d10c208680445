"""A GBNF grammar that only admits well-formed ``parse_event()`` programs for one event.

Small local models write programs that call functions that do not exist, name objects that are
not in the scene (``refrigerator_1``, ``phone``) or run on until the token budget cuts a string
in half. Decoding under this grammar (llama.cpp) makes those mistakes impossible: the program
has exactly one block per event character, in event order::

    def parse_event():
        c1 = get_character("Ava")
        c1.set_target_action("watch_tv")
        c1.set_position(get_area_close_to("table_3"))
        c1.set_orientation("tv_1")

where the action comes first (a label without a seated motion admits standing areas only), the area is one of the spatial API's listed area functions (``SpatialAPI.functions()``) over the scene's object names (a
seat function only over seats not in use), the orientation target an object or another
character, and the action one of the offered labels (those the event's words point to,
:mod:`storyteller.agents.action_shortlist`). For an event, :func:`event_program_grammar`
narrows the objects and seats further to the shortlist its words single out
(:mod:`storyteller.agents.shortlist`: "sits on the couch" offers the free couches, "the chair by the
window" the chairs close to a window), or keeps them all when the words name nothing. The program still runs in the sandbox and
through the spatial API like any other; only what the model can write is narrowed. Providers
that cannot decode under a grammar ignore it and get the same prompt.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from storyteller.agents.action_shortlist import action_shortlist, label_objects, posture
from storyteller.agents.area_words import DescribedArea, keep_in_areas, named_areas
from storyteller.agents.messages import CharacterStatus
from storyteller.agents.related_objects import RelatedObjects, related_objects
from storyteller.agents.relation_words import labels_about, stated_relations, without_relations
from storyteller.agents.shortlist import RELATIONS, event_shortlist, mentioned_labels, relation_areas
from storyteller.sim.motion.action_labels import playable_seated
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.areas import seat_slots
from storyteller.tools.position_sampling import MIN_SEPARATION
from storyteller.tools.spatial_api import SpatialAPI

DIRECTIONAL = frozenset(fn for fn, _ in RELATIONS)
"""Area functions of a place beside a thing (behind it, left of it...): places to stand."""

SEATED_ACTIVITIES = frozenset({"eat", "order_food", "order_drink", "use_laptop", "work_on_computer", "attend_meeting"})
"""Labels people do sitting unless the words say otherwise (a meal at a table, work at a desk):
when the best label for the words is one of them and there is a free seat, the grammar offers
seats only."""


def area_functions() -> tuple[tuple[str, ...], tuple[str, ...], str]:
    """The listed area functions of ``storyteller.tools.spatial_api.SpatialAPI``: those on one object, those
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


PAIR_RULE_MAX_OBJECTS = 24
"""Up to this many objects, the two-object areas (``get_area_between``) take two different
objects by grammar (one rule per first object, listing the others: quadratic in the objects);
with more, any two, and the sandbox refuses the same object twice."""


def _pair_rules(objects: Sequence[str]) -> list[str]:
    """The rules ``objectpair ::= ...``, ``other1 ::= ...``...: two different objects, written
    ``"a", "b"``; none (any two objects, rule ``object``) past :data:`PAIR_RULE_MAX_OBJECTS`."""
    if len(objects) > PAIR_RULE_MAX_OBJECTS:
        return []
    firsts = [f"{_quoted(name)} {_literal(', ')} other{i}" for i, name in enumerate(objects, start=1)]
    rules = ["objectpair ::= " + " | ".join(firsts)]
    rules += [_choice(f"other{i}", [o for o in objects if o != name]) for i, name in enumerate(objects, start=1)]
    return rules


def program_grammar(
    event_characters: Sequence[str],
    objects: Sequence[str],
    seats: Sequence[str],
    action_labels: Sequence[str],
    other_characters: Sequence[str] = (),
    seated_labels: Sequence[str] | None = None,
    interact_objects: Sequence[str] | None = None,
    posture: str | None = None,
    area_names: Sequence[str] = (),
    choose_characters: bool = False,
    max_blocks: int | None = None,
) -> str:
    """The grammar of one event's program (see the module docstring).

    ``objects``: every object an area may be built on; ``seats``: the free seats (the sit
    function is offered only when there is one); ``other_characters``: characters that may be
    looked at besides the objects and the event's own characters; ``seated_labels``: the
    labels that can be played sitting (None: all); ``interact_objects``: the objects
    ``get_area_to_interact_with`` may take (None: ``objects``; interacting with a seat means
    sitting on it, which the seat function offers, and only on a free seat). Each block sets the action first, then the position: a label that has
    no seated motion is followed by standing areas only, and the action, the decision the
    event's words say most about, is made before the place that must suit it. ``posture``
    (``"sit"`` / ``"stand"``, from the event's words): with "sit" and a free seat, only seated
    labels and seat areas are offered; with "stand", no seat area. ``area_names``: the area
    functions the event's where-words name (``get_area_behind``); when given, the only standing
    areas offered. ``choose_characters`` (the "w/o Event" ablation, which has no event to say
    who acts): the program is ``pass`` or one to ``len(event_characters)`` blocks, each on a
    character the model picks from ``event_characters`` (variable ``c`` in every block), at
    most ``max_blocks`` of them (None: one per character)."""
    if not event_characters:
        raise ValueError("an event without characters has no program")
    if not action_labels:
        raise ValueError("no action labels to choose from")
    seated = set(action_labels if seated_labels is None else seated_labels)
    sit_labels = [a for a in action_labels if a in seated]
    stand_labels = [a for a in action_labels if a not in seated]
    can_sit = bool(seats) and bool(sit_labels) and posture != "stand"
    must_sit = can_sit and posture == "sit"
    start, end = _literal("```python\ndef parse_event():\n"), _literal("```")
    if choose_characters:
        blocks = "block"
        for _ in range(min(len(event_characters), max_blocks or len(event_characters)) - 1):  # block ( block )?
            blocks = f"block ( {blocks} )?"
        wait = _literal("    pass\n")
        lines = [f"root ::= {start} ( {wait} | {blocks} ) {end}"]
        heads = [("block", "c", _literal("    c = get_character(") + " who " + _literal(")\n    c.set_target_action("))]
    else:
        lines = [f"root ::= {start} " + " ".join(f"block{i}" for i in range(1, len(event_characters) + 1)) + f" {end}"]
        heads = [(f"block{i}", f"c{i}", _literal(f"    c{i} = get_character({json.dumps(name)})\n    c{i}.set_target_action("))
                 for i, name in enumerate(event_characters, start=1)]
    for rule, var, head in heads:
        place = _literal(f")\n    {var}.set_position(")
        look = _literal(f")\n    {var}.set_orientation(") + " look " + _literal(")\n")
        branches = []
        if must_sit:
            branches.append(f"sitlabel {place} sitarea")
        elif can_sit:
            branches.append(f"sitlabel {place} ( sitarea | area )")
            if stand_labels:
                branches.append(f"standlabel {place} area")
        else:
            branches.append(f"label {place} area")
        lines.append(f"{rule} ::= {head} ( {' | '.join(branches)} ) {look}")
    one_object, two_objects, seat_area = area_functions()
    interact = "get_area_to_interact_with"
    use_interact_rule = interact_objects is not None and interact in one_object and list(interact_objects) != list(objects)
    distinct = list(dict.fromkeys(objects))
    named = set(area_names) & {*one_object, *(two_objects if len(distinct) >= 2 else ())}
    areas = [
        f"{_literal(fn + '(')} {'interactobject' if use_interact_rule and fn == interact else 'object'} {_literal(')')}"
        for fn in one_object
        if not (use_interact_rule and fn == interact and not interact_objects) and (not named or fn in named)
    ]
    pairs = _pair_rules(distinct) if len(distinct) >= 2 else []
    pair = "objectpair" if pairs else f"object {_literal(', ')} object"
    areas += [f"{_literal(fn + '(')} {pair} {_literal(')')}" for fn in two_objects
              if len(distinct) >= 2 and (not named or fn in named)]
    if can_sit:
        lines.append(f"sitarea ::= {_literal(seat_area + '(')} seat {_literal(')')}")
        lines.append(_choice("seat", seats))
        lines.append(_choice("sitlabel", sit_labels))
        if stand_labels and not must_sit:
            lines.append(_choice("standlabel", stand_labels))
    else:
        lines.append(_choice("label", action_labels))
    lines.append("area ::= " + " | ".join(areas))
    lines.append(_choice("object", objects))
    lines.extend(pairs)
    if use_interact_rule and interact_objects:
        lines.append(_choice("interactobject", interact_objects))
    if choose_characters:
        lines.append(_choice("who", event_characters))
    lookable = [*objects, *(c for c in (*event_characters, *other_characters) if c not in objects)]
    lines.append(_choice("look", lookable))
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class EventOptions:
    """What the grammar of one event offers (see :func:`event_options`)."""

    labels: tuple[str, ...]
    objects: tuple[str, ...]
    seats: tuple[str, ...]
    free_seats: tuple[str, ...]
    posture: str | None
    relations: tuple[str, ...]
    others: dict[str, tuple[float, float]]
    """Where the characters outside the event are (name -> xy)."""
    landmarks: tuple[str, ...] = ()
    """Objects the words place the used thing by ("the table nearest the window": the window):
    offered to look at, not to use (:mod:`storyteller.agents.related_objects`)."""

    @property
    def must_sit(self) -> bool:
        """Whether the grammar offers seats only (the event's words, or its best label, sit)."""
        return bool(self.seats) and any(playable_seated(a) for a in self.labels) and self.posture == "sit"


def free_seats(
    scene: Scene, event_characters: Sequence[str], characters: Sequence[CharacterStatus], seats_in_use: Sequence[str],
) -> list[str]:
    """The seats nobody outside the event holds or stands on: the sampler's own rule, a one-place
    seat nobody holds, or a slot of it (a couch has several) clear of everyone else by the
    minimum separation."""
    others = [c for c in characters if c.name not in event_characters]
    taken = set(seats_in_use) | {c.seat for c in others if c.seat}
    placed = np.array([c.position for c in others if c.position is not None], dtype=float).reshape(-1, 2)

    def free(obj: SceneObject) -> bool:
        slots = seat_slots(obj)
        if obj.name in taken and len(slots) <= 1:
            return False
        if len(placed) == 0 or not slots:
            return True
        return any(float(np.min(np.linalg.norm(placed - np.asarray(s.position), axis=1))) >= MIN_SEPARATION for s in slots)

    return [o.name for o in scene.objects if o.is_seat and free(o)]


def event_options(
    scene: Scene, event_characters: Sequence[str], characters: Sequence[CharacterStatus],
    seats_in_use: Sequence[str], action_labels: Sequence[str], activity: str = "", widen: bool = False,
    context: str = "", action: str | None = None, areas: Sequence[DescribedArea] = (),
    served: Sequence[str] = (), heading: Mapping[str, tuple[float, float]] | None = None,
) -> EventOptions:
    """The labels, objects, seats, posture and area functions an event's grammar offers (the
    arguments are :func:`event_program_grammar`'s). ``areas``: the scene description's areas; of
    a kind of thing with instances in an area the words name ("the cabinet in the lounge"), only
    those are offered (:func:`storyteller.agents.area_words.keep_in_areas`); ``served``: the characters the
    event acts for (:func:`storyteller.agents.instruction_parts.served_characters`): a serving action's table
    is theirs (:func:`storyteller.agents.related_objects.related_objects`); ``heading``: where busy characters'
    events take them (name -> xy)."""
    others = [c for c in characters if c.name not in event_characters]
    free = free_seats(scene, event_characters, characters, seats_in_use)
    ranked = list(action_shortlist(activity, action_labels, scene.labels, context))
    labels = ranked or list(action_labels)
    if action is not None and action in labels:  # the action chosen before the program comes first
        labels = [action, *(a for a in labels if a != action)]
    relations = () if widen else relation_areas(activity)
    where = {c.name: (float(c.position[0]), float(c.position[1])) for c in others if c.position is not None}
    shortlist = event_shortlist(scene, activity, free, labels, others=where)
    # words that name no thing use the thing their action works ("starts a vinyl spinning": the
    # record player), else anything
    operated = _operated_things(scene, labels[0]) if ranked or action is not None else []
    objects = list(shortlist.objects) or operated or [o.name for o in scene.objects]
    seats = list(shortlist.seats) or list(free)
    if not widen and (in_area := {n for a in named_areas(activity, areas, labels=scene.labels) for n in a.objects}):
        label_of = {o.name: o.label for o in scene.objects}
        objects, seats = keep_in_areas(objects, label_of, in_area), keep_in_areas(seats, label_of, in_area)
    related = RelatedObjects(tuple(objects), ()) if widen else related_objects(
        scene, activity, objects, where, action=labels[0],
        served_at=served_places(scene, characters, served, heading or {}),
    )
    return EventOptions(
        labels=tuple(labels),
        objects=related.objects,
        seats=tuple(seats),
        free_seats=tuple(free),
        posture=posture(activity) or ("stand" if set(relations) & DIRECTIONAL else None)
        or ("sit" if labels[0] in SEATED_ACTIVITIES or about_a_seat(scene, activity, labels[0]) else None)
        or ("stand" if idle_beside_a_thing(scene, activity, labels[0]) else None),
        relations=relations,
        others=where,
        landmarks=related.landmarks,
    )


def _operated_things(scene: Scene, label: str) -> list[str]:
    """The scene's objects of the kind ``label`` works (``turn_on_record_player``: every
    ``record_player``); [] when it names no kind the scene has."""
    kinds = set(label_objects([label]))
    return [o.name for o in scene.objects if o.label in kinds]


def served_places(
    scene: Scene, characters: Sequence[CharacterStatus], served: Sequence[str],
    heading: Mapping[str, tuple[float, float]],
) -> list[tuple[float, float]]:
    """Where the ``served`` characters are: the seat each holds, else where their event takes
    them (``heading``: a guest still walking to a table is served there), else their position."""
    seat_at = {o.name: (float(o.center[0]), float(o.center[1])) for o in scene.objects if o.is_seat}
    out = []
    for c in characters:
        if c.name not in served:
            continue
        if c.seat in seat_at:
            out.append(seat_at[c.seat])
        elif c.name in heading:
            out.append(heading[c.name])
        elif c.position is not None:
            out.append((float(c.position[0]), float(c.position[1])))
    return out


def about_a_seat(scene: Scene, activity: str, label: str) -> bool:
    """Whether the event's words are about a seat, with the places they relate it to taken out
    ("of all the chairs, Ava takes the one farthest from the lamp, to read": the chairs), and its
    best label can be played seated: the character then sits on it, though no word says "sit"."""
    if not activity or not playable_seated(label):
        return False
    named = labels_about(activity, sorted(scene.labels))
    seat_labels = {o.label for o in scene.objects if o.is_seat}
    return bool(named) and all(n in seat_labels for n in named)


def idle_beside_a_thing(scene: Scene, activity: str, label: str) -> bool:
    """Whether the event's words put a character doing nothing in particular (best label
    ``idle``: "waits right next to the refrigerator") near a thing that is not a seat, and name no
    seat: the character stands beside it (a 0.5B model otherwise sat them on the nearest couch)."""
    if label != "idle" or not activity:
        return False
    labels = sorted(scene.labels)
    seat_labels = {o.label for o in scene.objects if o.is_seat}
    mentions = stated_relations(activity, labels)
    near_things = [r for m in mentions if m.kind in ("near", "nearest") for r in m.references
                   if r and not r[0].startswith("@")]
    if not near_things or any(set(r) & seat_labels for r in near_things):
        return False
    return not set(mentioned_labels(without_relations(activity, mentions, labels), labels)) & seat_labels


def event_program_grammar(
    scene: Scene, event_characters: Sequence[str], characters: Sequence[CharacterStatus],
    seats_in_use: Sequence[str], action_labels: Sequence[str], activity: str = "", widen: bool = False,
    context: str = "", seat: str | None = None, action: str | None = None, areas: Sequence[DescribedArea] = (),
    served: Sequence[str] = (), heading: Mapping[str, tuple[float, float]] | None = None,
) -> str:
    """:func:`program_grammar` for an event in ``scene``: the labels its words point to
    (:func:`storyteller.agents.action_shortlist.action_shortlist` of ``activity``; every offered label
    when they point to none), the objects and the seats nobody else holds or stands on,
    narrowed to the event's shortlist (:func:`storyteller.agents.shortlist.event_shortlist`; all of them
    when it has none), and no seat to interact with (sitting goes through the seat function). ``activity`` is the event's text
    (the narrator's activity and the instruction part it comes from); ``characters`` are the
    roster (objects with ``name``, ``seat``, ``position``). ``widen`` (a retry after the named
    place had no room): every area function over the shortlist, not only those the where-words
    name, so the model can pick another place by the same things. ``context``: other words
    about the event (the narrator's activity), which break ties between labels. ``seat``: the
    seat already chosen for the event (:mod:`storyteller.agents.place_choice`): the only seat offered. ``action``:
    the action chosen for it when its words name none (:mod:`storyteller.agents.action_choice`): offered first.
    ``areas``, ``served``: see :func:`event_options`."""
    options = event_options(
        scene, event_characters, characters, seats_in_use, action_labels, activity, widen, context, action, areas,
        served, heading,
    )
    objects = list(options.objects)
    seat_names = {o.name for o in scene.objects if o.is_seat}  # sitting is get_area_to_sit_on's
    if seat is not None and seat not in objects:
        objects.append(seat)
    return program_grammar(
        event_characters,
        objects,
        [seat] if seat is not None else list(options.seats),
        list(options.labels),
        [c.name for c in characters if c.name not in event_characters],
        seated_labels=[a for a in options.labels if playable_seated(a)],
        interact_objects=[o for o in objects if o not in seat_names and o not in options.landmarks],
        posture="sit" if seat is not None else options.posture,
        area_names=options.relations,
    )



def open_program_grammar(
    scene: Scene, characters: Sequence[CharacterStatus], seats_in_use: Sequence[str], action_labels: Sequence[str],
) -> str:
    """The grammar of the "w/o Event" planner's program: the same well-formed programs as an
    event's (:func:`program_grammar`) but with nothing an event would narrow: the model picks
    which free characters act (or ``pass``), any offered label, any object of the scene and any
    seat nobody holds, for one to three characters (an event's size in the narrator's rules).
    The ablation then measures what the event adds, not what the grammar does.
    ``characters``: the roster."""
    free = [c.name for c in characters if not c.busy]
    if not free:
        raise ValueError("nobody is free: there is no program to write")
    taken = set(seats_in_use) | {c.seat for c in characters if c.seat}
    seat_names = {o.name for o in scene.objects if o.is_seat}
    objects = [o.name for o in scene.objects]
    return program_grammar(
        free,
        objects,
        [o.name for o in scene.objects if o.is_seat and o.name not in taken],
        list(action_labels),
        [c.name for c in characters if c.name not in free],
        seated_labels=[a for a in action_labels if playable_seated(a)],
        interact_objects=[o for o in objects if o not in seat_names],
        choose_characters=True,
        max_blocks=3,
    )

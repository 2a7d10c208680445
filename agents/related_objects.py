"""The object an event acts on, narrowed by the relations its words state about it.

"Ben wipes down the table nearest the window": of the tables, the one nearest the window; the
window is where the table is, not what Ben wipes. A 0.5B model writing
``get_area_to_interact_with(...)`` picks one of the offered objects, and with every table and the
window offered it often picks the landmark or the first table by name. Seats already go through
a choice checked by geometry (:mod:`storyteller.agents.place_choice`); this is the same check for the things
a character stands at and uses.

For each relation the words state about a kind of thing (:func:`storyteller.agents.relation_words.stated_relations`
with a ``subject``: the words right before the relation word, or an attributive one's described
words), the offered instances of that kind that do not meet it (computed from the scene by
:func:`storyteller.tools.place_relations.keep_satisfying`) are no longer offered, and what the relation is
measured against (its landmarks) is offered to look at but not to use. A relation that no
offered instance meets, or whose subject is a seat (seats have their own choice), changes
nothing. No word list here: the relation words and their subjects come from
:mod:`storyteller.agents.relation_words`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from storyteller.agents.place_choice import references_of
from storyteller.agents.relation_words import stated_relations
from storyteller.sim.scene.model import Scene
from storyteller.tools.place_relations import (
    TIE_M,
    Reference,
    StatedRelation,
    group_gap,
    keep_satisfying,
    sits_at,
)

SERVING_LABELS = ("serve_", "deliver_", "take_order")
"""Labels (prefixes) of actions done for other people at their place: a waiter serves a table."""


@dataclass(frozen=True)
class RelatedObjects:
    """What the relations leave: the objects still offered (in the order given) and the
    landmarks (offered to look at, not to use)."""

    objects: tuple[str, ...]
    landmarks: tuple[str, ...]


def related_objects(
    scene: Scene, text: str, objects: Sequence[str], others: Mapping[str, tuple[float, float]],
    *, action: str = "", served_at: Sequence[tuple[float, float]] = (),
) -> RelatedObjects:
    """``objects`` (an event's offered object names) narrowed by the relations ``text`` states
    about one of their kinds (see the module docstring); ``others``: where the characters outside
    the event are (a relation may be measured against one of them). ``action``: the event's best
    label; when it serves people (:data:`SERVING_LABELS`) and ``served_at`` gives where they are
    (their seats), the nearest thing one sits at (a table, a counter) is the only object offered:
    "Cleo brings them menus" is at the guests' table, not the bar."""
    by_name = {o.name: o for o in scene.objects}
    kept = [n for n in objects if n in by_name]
    if served_at and action.startswith(SERVING_LABELS):
        guests = tuple(Reference(f"guest {i}", point=xy) for i, xy in enumerate(served_at))
        gaps = {o.name: group_gap(o, guests) for o in scene.objects if sits_at(o) and not o.is_seat}
        if gaps:  # the guests' table, even when the words did not name it ("takes their order"), and
            # nothing else: a serving action is done where the guests are (a small model otherwise
            # picks the coffee maker or a bottle from a long list)
            least = min(gaps.values())
            return RelatedObjects(objects=tuple(n for n, g in gaps.items() if g <= least + TIE_M), landmarks=())
    landmarks: list[str] = []
    for mention in stated_relations(text, scene.labels, list(others)):
        if not mention.subject:
            continue
        things = [by_name[n] for n in kept if by_name[n].label in mention.subject and not by_name[n].is_seat]
        refs = references_of(scene, mention, others)
        if not things or not all(refs):
            continue
        meeting = {o.name for o in keep_satisfying([StatedRelation(mention.kind, refs)], things)}
        marks = {r.name for group in refs for r in group if r.obj is not None and r.obj.label not in mention.subject}
        thing_names = {o.name for o in things}
        kept = [n for n in kept if n in meeting or n not in thing_names]
        landmarks.extend(m for m in sorted(marks) if m not in landmarks and m not in meeting)
    return RelatedObjects(objects=tuple(kept), landmarks=tuple(landmarks))

"""Switches and doors the story has already set: nobody turns on a TV that is on.

A pair of action labels ``turn_on_X`` / ``turn_off_X`` or ``open_X`` / ``close_X`` sets a state
of the scene's things of label ``X`` (on or off, open or closed). The story so far says which
state holds: the latest event of the history (completed, ongoing or looping; a failed one
changed nothing) whose words the label ranker reads as one of the pair. An event's offered
labels then leave out the member of a pair that would set the state already held, when its
opposite is offered too: "Reza wants silence and takes care of the TV" after "Bea switches on
the TV" can only mean turning it off.

Only labels whose thing the scene has exactly one of are settled this way (with two fridges, an
opened fridge says nothing about the other); with no such event in the history, nothing is
left out.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence

from storyteller.agents.action_shortlist import rank_action_labels
from storyteller.agents.messages import HistoryEntry

TOGGLES = (("turn_on_", "turn_off_"), ("open_", "close_"))
"""(sets the state, undoes it): the prefixes of the label pairs this module settles."""


def _pairs(labels: Sequence[str]) -> dict[str, str]:
    """Each label of a toggle pair offered in full, mapped to its opposite."""
    offered = set(labels)
    out: dict[str, str] = {}
    for on, off in TOGGLES:
        for label in labels:
            if label.startswith(on) and (opposite := off + label[len(on):]) in offered:
                out[label], out[opposite] = opposite, label
    return out


def held_states(history: Sequence[HistoryEntry], labels: Sequence[str], object_labels: Sequence[str]) -> dict[str, str]:
    """Per toggled thing (the label's suffix: ``tv``, ``fridge``), the label of the latest history
    event that set it (see the module docstring); things no event touched are absent."""
    pairs = _pairs(labels)
    if not pairs:
        return {}
    toggles = sorted(pairs)
    held: dict[str, str] = {}
    for entry in sorted(history, key=lambda h: h.index):
        if entry.state == "failed":
            continue
        ranked = rank_action_labels(entry.activity, toggles, object_labels)
        if ranked:
            label = ranked[0].label
            held[_thing(label)] = label
    return held


def _thing(label: str) -> str:
    for on, off in TOGGLES:
        for prefix in (on, off):
            if label.startswith(prefix):
                return label[len(prefix):]
    return label


def unsettled_labels(
    labels: Sequence[str], history: Sequence[HistoryEntry], object_labels: Sequence[str],
) -> tuple[str, ...]:
    """``labels`` without those that would set a state the story already holds (see the module
    docstring); ``object_labels`` is the scene's object label of every object (repeats count)."""
    counts = Counter(object_labels)
    held = held_states(history, labels, sorted(counts))
    drop = {label for thing, label in held.items() if counts.get(thing, 0) == 1}
    return tuple(a for a in labels if a not in drop)

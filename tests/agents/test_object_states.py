"""A switch or door the story already set: its label that would set it again is not offered."""

from __future__ import annotations

from storyteller.agents.messages import EventState, HistoryEntry
from storyteller.agents.object_states import held_states, unsettled_labels

LABELS = ("idle", "turn_on_tv", "turn_off_tv", "open_fridge", "close_fridge", "open_cabinet", "close_cabinet", "eat")
THINGS = ("tv", "fridge", "cabinet", "cabinet", "chair")  # one TV, one fridge, two cabinets


def _entry(index: int, activity: str, state: EventState = "completed") -> HistoryEntry:
    return HistoryEntry(index=index, characters=("Bea",), activity=activity, state=state)


def test_a_tv_someone_switched_on_can_only_be_turned_off() -> None:
    history = [_entry(0, "switch on the TV"), _entry(1, "phone a cousin abroad", "ongoing")]
    assert held_states(history, LABELS, sorted(set(THINGS))) == {"tv": "turn_on_tv"}
    assert unsettled_labels(LABELS, history, THINGS) == tuple(a for a in LABELS if a != "turn_on_tv")


def test_the_latest_event_decides_and_a_failed_one_changes_nothing() -> None:
    history = [_entry(0, "open the fridge to look for milk"), _entry(1, "close the fridge door"),
               _entry(2, "open the fridge", "failed")]
    assert held_states(history, LABELS, sorted(set(THINGS)))["fridge"] == "close_fridge"
    assert "close_fridge" not in unsettled_labels(LABELS, history, THINGS)
    assert "open_fridge" in unsettled_labels(LABELS, history, THINGS)


def test_nothing_is_settled_for_a_thing_the_scene_has_two_of_or_when_no_event_touched_it() -> None:
    history = [_entry(0, "open the cabinet to take a plate")]
    assert unsettled_labels(LABELS, history, THINGS) == LABELS  # which cabinet is open? either may be opened
    assert unsettled_labels(LABELS, [_entry(0, "eat a bowl of salad")], THINGS) == LABELS
    assert unsettled_labels(LABELS, [], THINGS) == LABELS


def test_a_label_without_its_opposite_is_never_dropped() -> None:
    labels = ("idle", "turn_on_tv", "eat")
    assert unsettled_labels(labels, [_entry(0, "switch on the TV")], THINGS) == labels

"""The story so far as a planning step sees it: how many events it carries, how many it lists.

Two windows with two purposes, both in force in the narrator's prompt:

- :data:`HISTORY_WINDOW` (12) is how many of the latest events a planning step carries as its
  ``history`` (``PlanningState.recent`` in ``storyteller plan``, the session's
  ``history_window`` in ``storyteller run``); the events before are folded into one
  :class:`~storyteller.agents.messages.EarlierEvents` summary. The instruction's progress and the
  ongoing events the prompt shows are read from this history.
- :data:`LISTED_FINISHED` (8) is how many of the completed or failed events of that history
  the narrator's prompt lists one per line (``storyteller.agents.narrator.history_text``); ongoing events
  are always listed. The finished events before them are counted in one line, or folded with
  ``earlier`` into its summary line.

So the narrator sees at most 8 finished events line by line while the step still knows the
last 12 (a part done 10 events ago is still done). Changing either number changes the prompts
and so the recorded traces.
"""

from __future__ import annotations

from collections.abc import Sequence

from storyteller.agents.messages import EarlierEvents, HistoryEntry

HISTORY_WINDOW = 12
"""Latest events (by step) a planning step carries as its history; older ones are summarised."""

LISTED_FINISHED = 8
"""Completed or failed events of the history that the narrator's prompt lists one per line."""


def keep_window(
    history: Sequence[HistoryEntry], earlier: EarlierEvents | None
) -> tuple[tuple[HistoryEntry, ...], EarlierEvents | None]:
    """The last :data:`HISTORY_WINDOW` entries of ``history`` (oldest first), and ``earlier``
    with the entries before them folded in."""
    cut = max(0, len(history) - HISTORY_WINDOW)
    folded = EarlierEvents.fold(earlier, ((h.characters, h.activity) for h in history[:cut]))
    return tuple(history[cut:]), folded

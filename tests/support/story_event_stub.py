"""A stand-in for the runtime's ``StoryEvent``: the attributes ``StoryStream.event`` reads."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Event:
    """What ``StoryStream.event`` reads (the runtime's ``StoryEvent`` has these attributes)."""

    index: int
    event_id: str
    characters: tuple[str, ...]
    activity: str
    requested_frame: int
    applied_frame: int
    state: str = "ongoing"
    finished_frame: int | None = None
    failure: str | None = None
    text: str = ""
    narration: str | None = None

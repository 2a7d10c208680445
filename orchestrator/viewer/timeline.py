"""What is happening at a frame: the story's events and each character's action (pure).

An event is *on* from the frame its plan was applied (``applied_frame``) to the frame it
finished (``finished_frame``), or to the end of the run when it never finished (ongoing,
looping). Frames are indices into the exported tracks, at the run's fps.
"""

from __future__ import annotations

from collections.abc import Sequence

from storyteller.orchestrator.safe_text import plain
from storyteller.orchestrator.session.story_stream import StoryEventRecord
from storyteller.sim.world.character_track import CharacterTrack


def event_span(event: StoryEventRecord, last_frame: int) -> tuple[int, int]:
    """First and last frame (inclusive) the event is on, clamped to ``[0, last_frame]``."""
    start = min(max(event.applied_frame, 0), last_frame)
    end = last_frame if event.finished_frame is None else event.finished_frame
    return start, min(max(end, start), last_frame)


def active_events(events: Sequence[StoryEventRecord], frame: int, last_frame: int) -> list[int]:
    """Indices (into ``events``) of the events on at ``frame``."""
    out = []
    for i, event in enumerate(events):
        start, end = event_span(event, last_frame)
        if start <= frame <= end:
            out.append(i)
    return out


def action_at(track: CharacterTrack, frame: int) -> str:
    """The character's action label at ``frame`` (the last one past the track's end; '' if none)."""
    if not track.action_labels:
        return ""
    return track.action_labels[min(max(frame, 0), track.num_frames - 1)]


def clock(frame: int, fps: float) -> str:
    """``frame`` as seconds, e.g. ``'12.3 s'``."""
    return f"{frame / fps:.1f} s"


MAX_EVENT_TEXT_CHARS = 1_000
"""Characters of an event's text shown (a caption line, a line of the event lists), the rest cut
to an ellipsis: a run's plan sentences are far shorter (167 at most in 200 story runs), while a
story file may hold 40 MB in one, which the export captioned at every frame it drew (2.5 GB,
40 s: a hostile-inputs attack, issue 22)."""


def event_text(event: StoryEventRecord) -> str:
    """What the event is, as a person reads it: its plan sentence (``StoryEventRecord.text``;
    never the narrator's unchecked words), else only who takes part (control characters shown
    as escapes), cut to :data:`MAX_EVENT_TEXT_CHARS`."""
    text = event.text or ", ".join(event.characters)
    if len(text) > MAX_EVENT_TEXT_CHARS:
        text = text[: MAX_EVENT_TEXT_CHARS - 1] + "\u2026"
    return plain(text)


def event_line(event: StoryEventRecord, fps: float) -> str:
    """One line of the event list: start time, what happens and, when it ended, how."""
    end = {"completed": " (done)", "failed": " (failed)", "looping": " (loops)"}.get(event.state, "")
    return f"{event.applied_frame / fps:5.1f} s  {event_text(event)}{end}"

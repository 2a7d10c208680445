"""``story.jsonl``: the story as it happens, one JSON line per change, for a live viewer.

``story.json`` is written when a run ends; ``story.jsonl`` grows while it runs, so
``storyteller view`` can show the events of a run still in progress. The file is append-only
and every line is one JSON object (``json.dumps`` with ASCII escapes: text from the model or
the user is data, and a newline in it cannot split a line):

- ``{"kind": "start", ...}`` (:class:`StreamStart`): the scene, the characters in order, the
  instruction at the start, the fps and the frame the session starts from (0, or the frame a
  ``resume`` goes on from). Every later line belongs to this start;
- ``{"kind": "event", "event": {...}}`` (:class:`StreamEvent`): an event as it is now, with the
  fields of a ``story.json`` event (:class:`StoryEventRecord`); an event appears again each
  time it starts, completes or fails.

A resume appends a new start line, then every event of the checkpoint it goes on from, so a
reader keeps only what follows the last start line (:func:`read_story_stream`): the events
of the killed process after its checkpoint are dropped, as their frames are. Each line is
written with one ``write`` on a file opened for appending; a reader ignores a last line with
no newline (a write in progress).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, model_validator

from storyteller.orchestrator.session.run_manifest import MAX_CHARACTERS, MAX_DURATION_S
from storyteller.sim.bounded_files import (
    MAX_OBJECT_KEYS,
    BoundedFileError,
    json_keys_exceed,
    read_bounded_tail,
)
from storyteller.sim.no_follow_writes import open_append
from storyteller.sim.run_folder_names import STORY_STREAM
from storyteller.sim.validation_text import user_error
from storyteller.sim.world.character_track import MAX_FPS, MIN_FPS

STREAM_FILE = STORY_STREAM
MAX_FRAME = int(MAX_DURATION_S * MAX_FPS)
"""The latest frame a story names (the longest run at the highest frame rate): a file naming a
later one was not written by a run, and a viewer would size its timeline after it."""
Frame = Annotated[int, Field(ge=0, le=MAX_FRAME)]
"""A frame of a story file."""
Fps = Annotated[float, Field(ge=MIN_FPS, le=MAX_FPS)]
"""The frame rate of a story file."""
Characters = Annotated[tuple[str, ...], Field(max_length=MAX_CHARACTERS)]
"""The characters of a story file, or of one of its events."""


class StoryEventRecord(BaseModel):
    """One event of ``story.json``'s ``events`` (as :func:`~.run_outputs.story_json` writes it)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    event_id: str
    index: int
    characters: Characters
    activity: str
    requested_frame: Frame
    applied_frame: Frame
    state: Literal["ongoing", "looping", "completed", "failed"]
    finished_frame: Frame | None
    failure: str | None
    part: str = ""
    text: str = Field(default="", description="The applied plan in plain English (what a person reads).")
    narration: str | None = Field(
        default=None, description="The narrator's activity in human names, when it agrees with the plan.",
    )

    @model_validator(mode="after")
    def _finished_after_applied(self) -> StoryEventRecord:
        if self.finished_frame is not None and self.finished_frame < self.applied_frame:
            raise ValueError(f"finished at frame {self.finished_frame}, before it was applied at {self.applied_frame}")
        return self


class StreamStart(BaseModel):
    """The first line of a session in ``story.jsonl``."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: Literal["start"] = "start"
    scene: str = Field(description="The scene's name (the scene itself is in scene.json).")
    characters: Characters
    instruction: str
    fps: Fps
    frame: Frame = Field(description="The frame the session starts from (a resume: its checkpoint's).")


class StreamEvent(BaseModel):
    """An event as it is at one of its changes."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: Literal["event"] = "event"
    event: StoryEventRecord


StreamLine = Annotated[StreamStart | StreamEvent, Field(discriminator="kind")]
_LINE: TypeAdapter[StreamStart | StreamEvent] = TypeAdapter(StreamLine)


MAX_STREAM_BYTES = 64 << 20
"""Bytes of the largest ``story.jsonl`` read (an event's line is written again at each change)."""


class StoryStreamError(ValueError):
    """A ``story.jsonl`` line that is not a stream record (the message names the file and line)."""


class StoryStream:
    """Appends to ``<out>/story.jsonl``; :meth:`close` when the run ends. A symbolic link (or a
    FIFO, a hard-linked file) at that name is refused with an ``OSError`` naming it
    (``sim.no_follow_writes``), never appended through."""

    def __init__(self, out: Path) -> None:
        self.path = out / STREAM_FILE
        self._fd: int | None = open_append(self.path)

    def start(self, start: StreamStart, events: Iterable[object] = ()) -> None:
        """A new session from ``start.frame``, with the events it starts with (a resume's)."""
        self._write(start)
        for event in events:
            self.event(event)

    def event(self, event: object) -> None:
        """``event`` (a ``StoryEvent`` of the runtime, read by attribute) as it is now."""
        record = StoryEventRecord.model_validate(event, from_attributes=True)
        self._write(StreamEvent(event=record))

    def _write(self, line: StreamStart | StreamEvent) -> None:
        if self._fd is None:
            raise ValueError(f"{self.path}: the story stream is closed")
        data = (json.dumps(line.model_dump(mode="json"), ensure_ascii=True) + "\n").encode("ascii")
        view = memoryview(data)
        while view:
            view = view[os.write(self._fd, view) :]

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def read_story_stream(path: Path) -> tuple[StreamStart | None, tuple[StoryEventRecord, ...]]:
    """The last session's start line and its events (each as last written, in story order);
    ``(None, ())`` for a missing or empty file. A malformed whole line raises
    :class:`StoryStreamError`, and so is a file over :data:`MAX_STREAM_BYTES` or not a regular
    file; a last line with no newline is not read yet."""
    return StoryStreamReader(path).read()


class StoryStreamReader:
    """``story.jsonl`` read as it grows: each :meth:`read` parses only the whole lines appended
    since the last one and returns the story so far, as :func:`read_story_stream` of the file
    would. The file is read from its start again when it is another file (another inode) or
    shorter than what was read (:attr:`reread` says why, None after a read of appended lines
    only). A malformed line is refused at each read until the file changes; nothing of a read
    that raised is kept. :attr:`bytes_read` counts the bytes read."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.bytes_read = 0
        self.reread: str | None = None
        self._identity: tuple[int, int] | None = None
        self._offset = 0  # the byte after the last whole line taken
        self._lines = 0  # whole lines taken
        self._start: StreamStart | None = None
        self._events: dict[str, StoryEventRecord] = {}
        self.start_line = 0
        """Line number of the last start line read (0: none): a new one is a new session."""

    def read(self) -> tuple[StreamStart | None, tuple[StoryEventRecord, ...]]:
        try:
            tail = read_bounded_tail(self.path, MAX_STREAM_BYTES, str(self.path), self._offset, self._identity)
        except BoundedFileError as exc:
            if not exc.missing:
                raise StoryStreamError(str(exc)) from None
            self.reread = None if self._identity is None else "the file is gone"
            self._identity, self._offset, self._lines, self._start, self._events = None, 0, 0, None, {}
            self.start_line = 0
            return None, ()
        self.bytes_read += len(tail.data)
        self.reread = tail.reread
        offset, lines, start, events, start_line = self._offset, self._lines, self._start, self._events, self.start_line
        if tail.reread is not None:
            offset, lines, start, events, start_line = 0, 0, None, {}, 0
        whole = tail.data[: tail.data.rfind(b"\n") + 1]
        parsed = [self._line(lines + i, raw) for i, raw in enumerate(whole.splitlines(), start=1)]
        events = dict(events)  # nothing is kept of a read that raised above
        for number, line in enumerate(parsed, start=lines + 1):
            if isinstance(line, StreamStart):
                start, events, start_line = line, {}, number
            elif start is not None:
                events[line.event.event_id] = line.event
        self._identity, self._offset, self._lines = tail.identity, offset + len(whole), lines + len(parsed)
        self._start, self._events, self.start_line = start, events, start_line
        return start, tuple(sorted(events.values(), key=lambda e: (e.index, e.event_id)))

    def _line(self, number: int, raw: bytes) -> StreamStart | StreamEvent:
        if json_keys_exceed(raw, MAX_OBJECT_KEYS):  # before pydantic builds an error per unknown key
            raise StoryStreamError(f"{self.path}: line {number}: more than {MAX_OBJECT_KEYS} keys in one line")
        try:
            return _LINE.validate_json(raw)
        except ValidationError as exc:
            raise StoryStreamError(user_error(f"{self.path}: line {number}", exc)) from None

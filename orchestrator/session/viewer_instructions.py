"""``viewer_instructions.jsonl``: instructions typed in a viewer's box, on their way to the run.

The viewer (``storyteller view RUN_DIR`` or ``run --view``; several at once, in other processes,
each with several browsers) and the run share one append-only file in the run folder. The
viewer appends one JSON line per instruction (:func:`send_instruction`):
``{"id": "<32 hex>", "thread": "<run.json's thread id>", "text": "...", "sent_unix": 1.7e9}``.
The run (not a replay) reads it from its last offset in a thread of its own
(:func:`start_inbox_reader`), and each new line goes to ``Session.instruct_nowait(text,
"viewer")``: the latest instruction from the next frame, exactly as a line typed on stdin (an
``instruction`` record with its frame and source ``viewer`` in ``trace.jsonl``, listed in
``story.json``, applied again by a replay and by a resume).

Guarantees:

- nothing typed is lost when either process restarts: a line is written with one ``write`` on a
  descriptor opened ``O_APPEND`` (``storyteller.sim.no_follow_writes.open_append``: never through a link)
  and fsynced before the viewer says it was sent; the run only reads the file;
- each line is applied once: lines are taken in file order; a line whose ``id`` came before, or
  for another thread (an earlier run in the same folder), is skipped; a resumed run skips the
  first lines as many as the trace holds ``viewer`` instructions (applied already: the resume
  applies them again at their recorded frames), because the run applies lines in file order,
  and holds the new ones until it is past the last recorded instruction's frame (they were sent
  after it, so they come after it in the story);
- bounded: the file is opened ``O_NOFOLLOW`` and read only when it is a regular file, at most
  :data:`READ_BYTES` a poll; a line longer than :data:`MAX_LINE_BYTES` is skipped to its newline
  without being held whole; a malformed line is skipped with a warning; a last line with no
  newline is a write in progress and waits for the next poll.
"""

from __future__ import annotations

import errno
import json
import os
import stat
import string
import threading
import uuid
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Generic, Protocol, TypeVar

import structlog
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from storyteller.orchestrator.session.instruction_script import MAX_INSTRUCTION_CHARS
from storyteller.sim.no_follow_writes import append_durably
from storyteller.sim.run_folder_names import VIEWER_INSTRUCTIONS

if TYPE_CHECKING:  # the viewer imports this module too, without the session
    from storyteller.orchestrator.session.stdin_instructions import TakesInstructions

    class _AtFrame(Protocol):
        @property
        def frame(self) -> int: ...

    class InboxSession(TakesInstructions, Protocol):
        """What the inbox reader needs of the session: its world's frame, ``instruct_nowait``."""

        @property
        def world(self) -> _AtFrame: ...


_log = structlog.get_logger("storyteller.session")

INBOX_FILE = VIEWER_INSTRUCTIONS
MAX_LINE_BYTES = 32 * 1024
"""Bytes of one line at most (an instruction of ``MAX_INSTRUCTION_CHARS`` characters, each escaped
as ``\\uXXXX`` pairs at worst, fits)."""
READ_BYTES = 1 << 20
"""Bytes read from the file in one poll at most."""
assert READ_BYTES > MAX_LINE_BYTES  # a poll that finds no newline in a whole read has found a line too long
POLL_S = 0.1
"""Wall seconds between two looks at the file."""
LineT = TypeVar("LineT")
ViewerLineT = TypeVar("ViewerLineT", bound="ViewerLine")
_READ = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)


class ViewerLine(BaseModel):
    """What every line a viewer appends for a run starts with: its id and the run's thread (the
    instruction and control channels' lines add their own fields)."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    id: str = Field(min_length=32, max_length=32, description="Unique per line: 32 hex digits.")
    thread: str = Field(min_length=1, max_length=200, description="The run's planning thread (run.json).")

    @field_validator("id")
    @classmethod
    def _hex(cls, value: str) -> str:
        if not all(c in string.hexdigits for c in value):
            raise ValueError("expected 32 hex digits")
        return value


class ViewerInstruction(ViewerLine):
    """One line of the file: an instruction typed in a viewer for the run of ``thread``."""

    text: str = Field(min_length=1, max_length=MAX_INSTRUCTION_CHARS)
    sent_unix: float = Field(ge=0, description="When the viewer wrote it (wall clock; shown only).")


def instruction_text(typed: str) -> str:
    """The instruction a typed text gives, as the session keeps it (runs of spaces, tabs and
    newlines made one space)."""
    return " ".join(typed.split())


def instruction_problem(typed: str) -> str | None:
    """Why ``typed`` cannot be sent (None: it can): nothing but spaces, or too long."""
    text = instruction_text(typed)
    if not text:
        return "the instruction is empty"
    if len(text) > MAX_INSTRUCTION_CHARS:
        return f"the instruction has {len(text)} characters, at most {MAX_INSTRUCTION_CHARS} are taken"
    return None


def send_instruction(folder: Path, thread: str, typed: str, *, sent_unix: float) -> ViewerInstruction:
    """Append ``typed`` for the run of ``thread`` to ``folder``'s file, on disk when this returns.
    ``ValueError`` when :func:`instruction_problem` has one; ``OSError`` naming the file when it
    cannot be written (a link or anything but a regular file there, a full disk)."""
    problem = instruction_problem(typed)
    if problem is not None:
        raise ValueError(problem)
    line = ViewerInstruction(id=uuid.uuid4().hex, thread=thread, text=instruction_text(typed), sent_unix=sent_unix)
    append_line(folder / INBOX_FILE, line)
    return line


def append_line(path: Path, line: BaseModel) -> None:
    """``line`` as one JSON line (ASCII escapes) at the end of ``path``, in one ``write`` on a
    descriptor opened ``O_APPEND`` without following a link, fsynced before this returns."""
    data = (json.dumps(line.model_dump(mode="json"), ensure_ascii=True) + "\n").encode("ascii")
    append_durably(path, data)


class AppendedLines(Generic[LineT]):
    """The reading side of an append-only JSON-lines file in the run folder: the whole new lines
    since the last :meth:`poll`, each parsed by :meth:`parse` (None: skipped), bounded as the
    module doc says. ``what`` names the file's lines in warnings (e.g. ``viewer_instruction``)."""

    what = "line"

    def __init__(self, path: Path) -> None:
        self.path = path
        self.offset = 0
        self._skipping = False  # inside a line longer than MAX_LINE_BYTES

    def parse(self, raw: bytes) -> LineT | None:
        raise NotImplementedError

    def poll(self) -> list[LineT]:
        """The lines appended since the last call that :meth:`parse` takes, in file order."""
        data = self._read()
        out: list[LineT] = []
        start = 0
        while (end := data.find(b"\n", start)) >= 0:
            raw, start = data[start:end], end + 1
            if self._skipping:  # the end of a line too long to take
                self._skipping = False
                continue
            if len(raw) > MAX_LINE_BYTES:
                _log.warning(f"{self.what}_too_long", file=str(self.path), limit=MAX_LINE_BYTES)
                continue
            line = self.parse(raw)
            if line is not None:
                out.append(line)
        rest = len(data) - start
        if self._skipping or rest > MAX_LINE_BYTES:  # no newline yet in a line that is too long already
            if not self._skipping:
                _log.warning(f"{self.what}_too_long", file=str(self.path), limit=MAX_LINE_BYTES)
            self._skipping = True
            start = len(data)
        self.offset += start
        return out

    def _read(self) -> bytes:
        try:
            fd = os.open(self.path, _READ)
        except FileNotFoundError:
            return b""
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                _log.warning(f"{self.what}s_refused", file=str(self.path), reason="a symbolic link")
            return b""
        try:
            info = os.fstat(fd)
            if not stat.S_ISREG(info.st_mode):
                _log.warning(f"{self.what}s_refused", file=str(self.path), reason="not a regular file")
                return b""
            if info.st_size < self.offset:  # replaced by a shorter file: read it from its start (ids stay seen)
                self.offset, self._skipping = 0, False
            return os.pread(fd, min(READ_BYTES, info.st_size - self.offset), self.offset)
        finally:
            os.close(fd)


class ThreadLines(AppendedLines[ViewerLineT]):
    """The lines a viewer appends for the run of ``thread``, each once: a line is validated as
    ``model`` (a malformed one is skipped with a ``<what>_malformed`` warning); a line for
    another thread, one whose id came before, or one :meth:`takes` refuses is skipped; the id
    of a line taken is remembered."""

    def __init__(self, path: Path, thread: str, model: type[ViewerLineT]) -> None:
        super().__init__(path)
        self.thread = thread
        self.model = model
        self._seen: set[str] = set()

    def takes(self, line: ViewerLineT) -> bool:
        """Whether a valid line of this thread not seen before is taken (its id is then seen)."""
        return True

    def parse(self, raw: bytes) -> ViewerLineT | None:
        try:
            line = self.model.model_validate_json(raw)
        except ValidationError as exc:
            _log.warning(f"{self.what}_malformed", file=str(self.path), offset=self.offset,
                         error=str(exc.errors()[0]["msg"]))
            return None
        if line.thread != self.thread or line.id in self._seen or not self.takes(line):
            return None
        self._seen.add(line.id)
        return line


class InstructionInbox(ThreadLines[ViewerInstruction]):
    """The run's side: the new lines for ``thread`` since the last :meth:`poll` (a text of
    nothing but spaces is skipped).

    ``applied``: the texts of the ``viewer`` instructions the run applied before (a resume: from
    its trace); that many lines are skipped first (a line that differs is logged: the file was
    changed by hand)."""

    what = "viewer_instruction"

    def __init__(self, path: Path, thread: str, applied: Sequence[str] = ()) -> None:
        super().__init__(path, thread, ViewerInstruction)
        self._applied = list(applied)

    def takes(self, line: ViewerInstruction) -> bool:
        return bool(instruction_text(line.text))

    def parse(self, raw: bytes) -> ViewerInstruction | None:
        line = super().parse(raw)
        if line is None:
            return None
        if self._applied:
            before = self._applied.pop(0)
            if before != instruction_text(line.text):
                _log.warning("viewer_instruction_mismatch", file=str(self.path), trace=before, line=line.text)
            return None
        return line


def start_inbox_reader(
    session: InboxSession,
    path: Path,
    thread: str,
    applied: Sequence[str] = (),
    *,
    stop: threading.Event,
    after_frame: int = -1,
    taken: Callable[[ViewerInstruction], None] | None = None,
) -> threading.Thread:
    """Start the daemon thread that hands every new line of ``path`` for ``thread`` to
    ``session.instruct_nowait(text, "viewer")`` (``taken(line)`` first, in the same order); it
    ends when ``stop`` is set or the session takes no more instructions.

    ``after_frame``: lines are handed on only once the session's world is past that frame. A
    resume passes the frame of the last instruction its trace holds: the killed process applied
    it (at that frame, which the resume reaches again), so what was sent after it must not take
    effect before it and be replaced by it."""
    inbox = InstructionInbox(path, thread, applied)

    def read() -> None:
        waiting: list[ViewerInstruction] = []
        while not stop.wait(POLL_S):
            waiting += inbox.poll()
            if not waiting or session.world.frame <= after_frame:
                continue
            for line in waiting:
                if taken is not None:
                    taken(line)
                if not session.instruct_nowait(line.text, "viewer"):
                    return
            waiting.clear()

    thread_ = threading.Thread(target=read, name="storyteller-viewer-instructions", daemon=True)
    thread_.start()
    return thread_

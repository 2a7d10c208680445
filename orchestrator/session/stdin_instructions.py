"""Lines typed on stdin become the story's instruction while it runs (``--interactive``).

:func:`start_stdin_reader` reads stdin in a daemon thread, so a blocked ``readline`` never
stalls the simulation's event loop nor keeps the process alive once the story has ended.
Each non-empty line (``#`` comments skipped) goes to :meth:`Session.instruct_nowait`, which
is safe from any thread; the simulation picks it up at the next frame it starts.

Bounded: a line is read at most ``MAX_INSTRUCTION_CHARS`` characters at a time
(:func:`bounded_lines`); a longer line is skipped, with a warning, in pieces of that size, so
a 1 GiB line costs no more memory than a short one and never reaches the story or run.json.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Iterator
from typing import Protocol, TextIO

import structlog

from storyteller.orchestrator.session.instruction_script import MAX_INSTRUCTION_CHARS
from storyteller.orchestrator.session.session_types import InstructionSource

_log = structlog.get_logger("storyteller.session")


class TakesInstructions(Protocol):
    """What the reader needs of the session (:meth:`Session.instruct_nowait`)."""

    def instruct_nowait(self, text: str, source: InstructionSource = "stdin") -> bool: ...


def typed_instruction(line: str) -> str | None:
    """The instruction a typed line gives (None: an empty line, a ``#`` comment, or a line
    longer than ``MAX_INSTRUCTION_CHARS``, which is logged as skipped)."""
    text = line.strip()
    if len(text) > MAX_INSTRUCTION_CHARS:
        _log.warning("instruction_too_long", characters=len(text), limit=MAX_INSTRUCTION_CHARS)
        return None
    return None if not text or text.startswith("#") else text


def bounded_lines(stream: TextIO, limit: int = MAX_INSTRUCTION_CHARS) -> Iterator[str | None]:
    """The lines of ``stream``, each read at most ``limit + 1`` characters at a time; a line
    longer than ``limit`` characters (its newline aside) is read to its end in such pieces,
    dropped, and given as None."""
    while True:
        line = stream.readline(limit + 1)
        if not line:
            return
        if len(line) <= limit or line.endswith("\n"):
            yield line
            continue
        skipped = len(line)
        while not line.endswith("\n"):
            line = stream.readline(limit + 1)
            if not line:
                break
            skipped += len(line)
        _log.warning("instruction_too_long", characters=skipped, limit=limit)
        yield None


def start_stdin_reader(session: TakesInstructions, stream: TextIO | None = None) -> threading.Thread:
    """Start the reader thread on ``stream`` (default: ``sys.stdin``); it ends at end of file
    or once the session no longer takes instructions."""
    source = stream if stream is not None else sys.stdin

    def read() -> None:
        for line in bounded_lines(source):
            text = None if line is None else typed_instruction(line)
            if text is not None and not session.instruct_nowait(text, "stdin"):
                return
        _log.debug("stdin_closed")

    thread = threading.Thread(target=read, name="storyteller-stdin", daemon=True)
    thread.start()
    return thread

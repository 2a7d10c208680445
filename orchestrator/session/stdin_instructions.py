"""Lines typed on stdin become the story's instruction while it runs (``--interactive``).

:func:`start_stdin_reader` reads stdin in a daemon thread, so a blocked ``readline`` never
stalls the simulation's event loop nor keeps the process alive once the story has ended.
Each non-empty line (``#`` comments skipped) goes to :meth:`Session.instruct_nowait`, which
is safe from any thread; the simulation picks it up at the next frame it starts.
"""

from __future__ import annotations

import sys
import threading
from typing import TextIO

import structlog

from orchestrator.session.runtime import Session

_log = structlog.get_logger("storyteller.session")


def typed_instruction(line: str) -> str | None:
    """The instruction a typed line gives (None: an empty line or a ``#`` comment)."""
    text = line.strip()
    return None if not text or text.startswith("#") else text


def start_stdin_reader(session: Session, stream: TextIO | None = None) -> threading.Thread:
    """Start the reader thread on ``stream`` (default: ``sys.stdin``); it ends at end of file
    or once the session no longer takes instructions."""
    source = stream if stream is not None else sys.stdin

    def read() -> None:
        for line in source:
            text = typed_instruction(line)
            if text is not None and not session.instruct_nowait(text, "stdin"):
                return
        _log.debug("stdin_closed")

    thread = threading.Thread(target=read, name="storyteller-stdin", daemon=True)
    thread.start()
    return thread

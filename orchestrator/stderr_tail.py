"""What a child process writes to stderr, read as data: drained, bounded, escaped.

A child that runs untrusted input (the event-program worker) must not share the terminal's
stderr: a traceback from a crash quotes the input, and a program could make the child print
escape sequences. :class:`StderrTail` takes the read end of the child's stderr pipe, drains it
on a daemon thread (so the child never blocks on a full pipe, however much it writes) and keeps
only its last :data:`KEPT_BYTES` bytes; :meth:`StderrTail.finish` waits for the end of the
stream (the child has exited) and returns that tail as text through
``storyteller.sim.visible_text.plain`` (bytes that are not UTF-8 shown as ``\\xNN``, every control, format,
separator and surrogate character as its escape; line breaks kept), for a log record.

Guarantee: the memory held is at most ``kept`` bytes plus one read, and nothing the child
writes reaches a terminal except as that escaped text.
"""

from __future__ import annotations

import contextlib
import os
import threading
from dataclasses import dataclass
from typing import IO

from storyteller.sim.visible_text import plain

KEPT_BYTES = 8 * 1024
"""Bytes of a child's stderr kept (its last ones: a traceback ends with the error)."""
_READ_BYTES = 64 * 1024
_FINISH_SECONDS = 2.0
"""Seconds :meth:`StderrTail.finish` waits for the end of the stream after the child exited
(a grandchild may still hold the pipe: the tail so far is returned)."""


@dataclass(frozen=True)
class StderrText:
    """The last bytes a child wrote to stderr, escaped: ``text`` shows the last ``shown`` of the
    ``written`` bytes."""

    text: str
    written: int
    shown: int


class StderrTail:
    """Drains ``stream`` (a child's stderr pipe, read end) and keeps its last ``kept`` bytes."""

    def __init__(self, stream: IO[bytes], kept: int = KEPT_BYTES) -> None:
        self._stream = stream
        self._kept = kept
        self._tail = bytearray()
        self._written = 0
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._drain, name="child-stderr", daemon=True)
        self._thread.start()

    def _drain(self) -> None:
        fd = self._stream.fileno()
        while True:
            try:
                chunk = os.read(fd, _READ_BYTES)
            except OSError:
                return
            if not chunk:
                return
            with self._lock:
                self._written += len(chunk)
                self._tail += chunk
                del self._tail[: -self._kept]

    def finish(self) -> StderrText | None:
        """The escaped tail once the stream ended (call after the child exited), or None when the
        child wrote nothing. Closes the pipe once the drain is done."""
        self._thread.join(_FINISH_SECONDS)
        if not self._thread.is_alive():
            with contextlib.suppress(OSError):
                self._stream.close()
        with self._lock:
            if not self._written:
                return None
            raw = bytes(self._tail)
            written = self._written
        text = plain(raw.decode("utf-8", "backslashreplace"), keep_newlines=True)
        return StderrText(text, written, len(raw))

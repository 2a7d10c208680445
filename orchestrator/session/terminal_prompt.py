"""Instructions typed on a terminal while a live view is drawn on it (``--interactive`` with ``--live``).

A terminal echoes what is typed where its cursor is, and a live view redraws over that place
several times a second. So while the view runs, :class:`TerminalPrompt` takes the echo from the
terminal: it switches the terminal to no echo and no line buffering (signals stay: Ctrl-C still
stops the run), reads the keys in a daemon thread, edits the line itself
(:class:`LineEditor`) and lets the view draw it (``text``; ``on_change`` after every key).
Enter gives the line to :meth:`Session.instruct_nowait` (as the plain stdin reader does: empty
lines and ``#`` comments are skipped). :meth:`TerminalPrompt.close` puts the terminal's mode back
as it found it (also at exit, should the run end another way).

:class:`LineEditor` is the pure part: bytes in (UTF-8, possibly cut mid-character), the line so
far and the lines given out. It keeps printable text only: control characters and escape
sequences (arrow keys, function keys) are dropped, so the line is one line of text.
"""

from __future__ import annotations

import atexit
import codecs
import os
import threading
from collections.abc import Callable
from typing import Any, Protocol

import structlog

from storyteller.orchestrator.session.instruction_script import MAX_INSTRUCTION_CHARS
from storyteller.orchestrator.session.session_types import InstructionSource
from storyteller.orchestrator.session.stdin_instructions import typed_instruction

_log = structlog.get_logger("storyteller.session")

MAX_LINE = MAX_INSTRUCTION_CHARS
"""Characters a typed line keeps at most (the rest of a longer paste is dropped)."""


class InstructionTaker(Protocol):
    """Where typed lines go (a :class:`~orchestrator.session.runtime.Session`)."""

    def instruct_nowait(self, text: str, source: InstructionSource = ...) -> bool: ...


class LineEditor:
    """One line being typed: printable characters append, Backspace / DEL removes the last
    character, Ctrl-U clears the line, Ctrl-W removes the last word, Enter gives the line out;
    Tab is a space; other control characters and escape sequences are dropped."""

    def __init__(self) -> None:
        self.text = ""
        self._decoder = codecs.getincrementaldecoder("utf-8")(errors="replace")
        self._escape = ""  # the escape sequence being skipped: "", "\x1b", "[" (CSI) or "O" (SS3)
        self._after_cr = False  # a "\n" right after a "\r" ends no second line

    def feed(self, data: bytes) -> list[str]:
        """Take the bytes read; returns the lines given out (Enter), in order."""
        done: list[str] = []
        for ch in self._decoder.decode(data):
            after_cr, self._after_cr = self._after_cr, ch == "\r"
            if self._skip(ch) or (ch == "\n" and after_cr):
                continue
            if ch in "\r\n":
                done.append(self.text)
                self.text = ""
            elif ch in "\x7f\x08":
                self.text = self.text[:-1]
            elif ch == "\x15":  # Ctrl-U
                self.text = ""
            elif ch == "\x17":  # Ctrl-W
                kept = self.text.rstrip()
                self.text = kept[: kept.rfind(" ") + 1]
            elif ch == "\t":
                self._append(" ")
            elif ch.isprintable():
                self._append(ch)
        return done

    def _append(self, ch: str) -> None:
        if len(self.text) < MAX_LINE:
            self.text += ch

    def _skip(self, ch: str) -> bool:
        """Whether ``ch`` is part of an escape sequence (ESC [ ... final, ESC O x, ESC x)."""
        if ch == "\x1b":
            self._escape = "\x1b"
            return True
        if self._escape == "\x1b":
            self._escape = ch if ch in "[O" else ""
            return True
        if self._escape == "[":
            if "\x40" <= ch <= "\x7e":
                self._escape = ""
            return True
        if self._escape == "O":
            self._escape = ""
            return True
        return False


class TerminalPrompt:
    """Reads instructions key by key from the terminal ``fd`` (see the module doc).

    ``on_change()`` is called from the reader thread after every read that changed the line (it
    must be safe to call from another thread)."""

    def __init__(self, fd: int, on_change: Callable[[], None] = lambda: None) -> None:
        self.fd = fd
        self.on_change = on_change
        self.editor = LineEditor()
        self._saved: list[Any] | None = None  # termios.tcgetattr's mode
        self._lock = threading.Lock()

    @property
    def text(self) -> str:
        """The line typed so far."""
        return self.editor.text

    def start(self, session: InstructionTaker) -> threading.Thread:
        """Take the echo and the line buffering from the terminal and start the reader thread;
        it ends at end of file or once the session no longer takes instructions."""
        import termios

        saved = termios.tcgetattr(self.fd)
        mode = termios.tcgetattr(self.fd)
        mode[3] &= ~(termios.ICANON | termios.ECHO)  # lflag: keys one by one, not echoed; ISIG kept
        mode[6][termios.VMIN] = 1
        mode[6][termios.VTIME] = 0
        with self._lock:
            self._saved = saved
        atexit.register(self.close)
        termios.tcsetattr(self.fd, termios.TCSANOW, mode)
        thread = threading.Thread(target=self._read, args=(session,), name="storyteller-prompt", daemon=True)
        thread.start()
        return thread

    def _read(self, session: InstructionTaker) -> None:
        while True:
            try:
                data = os.read(self.fd, 1024)
            except OSError:
                data = b""
            if not data:
                _log.debug("stdin_closed")
                return
            before = self.editor.text
            lines = self.editor.feed(data)
            for line in lines:
                text = typed_instruction(line)
                if text is not None and not session.instruct_nowait(text, "stdin"):
                    return
            if lines or self.editor.text != before:
                self.on_change()

    def close(self) -> None:
        """Put the terminal's mode back (safe to call twice)."""
        import termios

        with self._lock:
            saved, self._saved = self._saved, None
        if saved is None:
            return
        atexit.unregister(self.close)
        try:
            termios.tcsetattr(self.fd, termios.TCSADRAIN, saved)
        except (OSError, termios.error) as exc:  # the terminal went away
            _log.warning("terminal_mode_not_restored", error=str(exc))

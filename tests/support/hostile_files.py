"""Hostile versions of a file the product reads back, and the check every command that reads one
must pass.

The strategies take a valid file's bytes and return a damaged or hostile version of it:
:func:`truncated`, :func:`bit_flipped`, :func:`spliced` (a hostile piece put in place of a
slice: deep nesting, 5,000-digit and 400-nine numbers, ``NaN`` / ``Infinity``, long runs, bytes
that are not UTF-8, control and bidi characters) and :func:`value_spliced` (the same, in place of
one of the file's JSON/TOML numbers or strings, so the syntax around it holds and the value
reaches validation); :func:`hostile_bytes` draws one of them.

:func:`clean_outcome` is the check: the command ended with exit code 0, or with exactly one
non-empty line on stderr, an ``error: ...`` line, and exit code 2; never a traceback or
another exception, and no control, format (bidi), separator or surrogate character anywhere in
what it printed (newlines and tabs aside). Structured log records on stderr (JSON lines with an
``event`` and a ``level``: a warning the reader logged on its way) are not counted as lines.
"""

from __future__ import annotations

import json
import re
import unicodedata

from hypothesis import strategies as st
from typer.testing import Result

HOSTILE: tuple[bytes, ...] = (
    b"[" * 3_000 + b"]" * 3_000,
    b"{" * 60 + b"}" * 60,
    b'{"a":' * 40 + b"1" + b"}" * 40,
    b"9" * 5_000,
    b"9" * 400,
    b"-" + b"9" * 70,
    b"1e999",
    b"-1e309",
    b"NaN",
    b"Infinity",
    b"nan",
    b"inf",
    b'"' + b"a" * 20_000 + b'"',
    b"\xff\xfe\x80",
    b"\xed\xa0\x80",  # a lone surrogate, UTF-8 encoded (not valid UTF-8)
    b'"\\ud800"',  # a lone surrogate, JSON-escaped (valid JSON)
    '"\x1b[31m\u202e\u2066\x07\u2028\ufeff"'.encode(),
    b'"\\u001b]0;pwned\\u0007\\u202e"',
    "\x00\x1b[2J\u202e".encode(),
    b"\n" * 3,
    b"\r",
    b"a" * 3_000,
    b"0",
    b"-1",
    b"null",
    b"[]",
    b"{}",
    b'"[/]"',
    b'"$\\\\bar$"',
)

UNSAFE_CATEGORIES = frozenset({"Cc", "Cf", "Zl", "Zp", "Cs"})
_VALUE = re.compile(rb'-?[0-9][0-9.eE+-]*|"[^"\n]{0,200}"|\btrue\b|\bfalse\b|\bnull\b')


@st.composite
def truncated(draw: st.DrawFn, valid: bytes) -> bytes:
    """The first bytes of ``valid`` (a write torn anywhere)."""
    return valid[: draw(st.integers(0, max(0, len(valid) - 1)))]


@st.composite
def bit_flipped(draw: st.DrawFn, valid: bytes, *, start: int = 0) -> bytes:
    """``valid`` with one to four bits flipped at or after byte ``start``."""
    data = bytearray(valid)
    if len(data) <= start:
        return bytes(data)
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(start, len(data) - 1))
        data[at] ^= 1 << draw(st.integers(0, 7))
    return bytes(data)


@st.composite
def spliced(draw: st.DrawFn, valid: bytes) -> bytes:
    """``valid`` with one to three hostile pieces put in place of a slice of it."""
    data = valid
    for _ in range(draw(st.integers(1, 3))):
        start = draw(st.integers(0, len(data)))
        end = draw(st.integers(start, min(len(data), start + 40)))
        data = data[:start] + draw(st.sampled_from(HOSTILE)) + data[end:]
    return data


@st.composite
def value_spliced(draw: st.DrawFn, valid: bytes) -> bytes:
    """``valid`` with one to three of its values (numbers, strings, true/false/null) replaced by
    hostile pieces, the syntax around them kept so they reach validation."""
    data = valid
    for _ in range(draw(st.integers(1, 3))):
        spans = [m.span() for m in _VALUE.finditer(data)]
        if not spans:
            break
        start, end = draw(st.sampled_from(spans))
        data = data[:start] + draw(st.sampled_from(HOSTILE)) + data[end:]
    return data


def hostile_bytes(valid: bytes) -> st.SearchStrategy[bytes]:
    """A damaged or hostile version of ``valid``."""
    return st.one_of(value_spliced(valid), spliced(valid), truncated(valid), bit_flipped(valid))


def unsafe_characters(text: str) -> list[str]:
    """The characters of ``text`` a terminal must never get raw (newline and tab aside)."""
    return [c for c in text if c not in "\n\t" and unicodedata.category(c) in UNSAFE_CATEGORIES]


def clean_outcome(result: Result, *, codes: tuple[int, ...] = (0, 2)) -> None:
    """Exit 0, or one ``error:`` line and exit 2 (``codes`` may admit others); no traceback,
    nothing raised but ``SystemExit``, and no control / bidi character printed."""
    shown = f"exit {result.exit_code}\nstdout: {result.stdout[-1500:]!r}\nstderr: {result.stderr[-1500:]!r}"
    assert result.exit_code in codes, shown
    assert result.exception is None or isinstance(result.exception, SystemExit), (repr(result.exception), shown)
    assert "Traceback" not in result.stdout and "Traceback" not in result.stderr, shown
    for text in (result.stdout, result.stderr):
        assert not unsafe_characters(text), (unsafe_characters(text)[:5], shown)
    if result.exit_code == 2:
        lines = [line for line in result.stderr.splitlines() if line.strip() and not _log_record(line)]
        assert len(lines) == 1 and lines[0].startswith("error: "), shown


def _log_record(line: str) -> bool:
    """A structured log line (JSON with an event and a level), which is not the command's output."""
    try:
        record = json.loads(line)
    except ValueError:
        return False
    return isinstance(record, dict) and "event" in record and "level" in record

"""``--instructions FILE``: a timed script of instructions, in simulated time.

One instruction a line, ``TIME TEXT``: ``00:30 Ben leaves the kitchen and waves at Ava``.
``TIME`` is ``SS``, ``MM:SS`` or ``H:MM:SS`` (seconds may have a fraction: ``1:05.5``),
simulated seconds from the story's start. Blank lines and lines starting with ``#`` are
skipped. Lines may come in any order; instructions at the same time take effect in file
order, the last one winning (a new instruction replaces the one before). A line that does
not fit is an :class:`InstructionScriptError` naming the file, the line and what was
expected; nothing of the file is used then.

Bounded: the file is read within ``MAX_SCRIPT_BYTES`` (a regular file), it holds at most
``MAX_SCRIPT_INSTRUCTIONS`` instructions, an instruction (here, typed on stdin or in the
terminal prompt) has at most ``MAX_INSTRUCTION_CHARS`` characters, and a time is a finite
number of seconds up to ``MAX_SCRIPT_TIME_S`` (a time of 400 nines used to become infinity and a
run.json that resume refused). Lines are matched by a pattern without backtracking blow-up,
and only once their length is known to be within bounds.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

MAX_INSTRUCTION_CHARS = 2_000
"""Characters of one instruction, wherever it comes from (script, stdin, terminal prompt)."""
MAX_SCRIPT_BYTES = 1024 * 1024
"""Bytes of an instruction script file."""
MAX_SCRIPT_INSTRUCTIONS = 10_000
"""Instructions in one script."""
MAX_SCRIPT_TIME_S = 7 * 24 * 3600.0
"""Latest time an instruction may take effect, simulated seconds (a week)."""
_MAX_TIME_CHARS = 32
"""Characters of a TIME field (the longest sensible one, '168:00:00.000', has 13)."""

_LINE = re.compile(r"^(?:(?:(\d+):)?(\d{1,2}):)?(\d+(?:\.\d+)?)\s+(\S.*)$")


class InstructionScriptError(Exception):
    """A script line that is not ``TIME TEXT`` (the message names the file and the line)."""


class ScriptLine(BaseModel):
    """One instruction of a script: at ``time_s`` simulated seconds, ``text``."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    time_s: float = Field(ge=0, le=MAX_SCRIPT_TIME_S, description="Simulated seconds from the story's start.")
    text: str = Field(min_length=1, max_length=MAX_INSTRUCTION_CHARS)


def parse_instruction_script(text: str, source: str = "<script>") -> tuple[ScriptLine, ...]:
    """The script's lines, sorted by time (stable). ``source`` names the file in errors."""
    lines: list[ScriptLine] = []
    for no, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        stamp = line[: _MAX_TIME_CHARS + 1].split(maxsplit=1)[0]
        if len(stamp) > _MAX_TIME_CHARS and stamp[:1].isdigit():  # a number too long to be a time
            raise InstructionScriptError(
                f"{source}: line {no}: time {stamp[:20]!r}... is too large (at most "
                f"{MAX_SCRIPT_TIME_S:.0f} s)"
            )
        if len(line) > MAX_INSTRUCTION_CHARS + _MAX_TIME_CHARS + 1:
            raise InstructionScriptError(
                f"{source}: line {no}: {len(line)} characters, an instruction may have at most "
                f"{MAX_INSTRUCTION_CHARS}"
            )
        m = _LINE.match(line)
        if m is None:
            raise InstructionScriptError(
                f"{source}: line {no}: expected 'TIME TEXT' with TIME as SS, MM:SS or H:MM:SS "
                f"(e.g. '00:30 Ben waves at Ava'), got {line[:60]!r}"
            )
        hours, minutes, seconds, what = m.groups()
        if minutes is not None and float(seconds) >= 60:
            raise InstructionScriptError(f"{source}: line {no}: seconds must be below 60 in {stamp!r}")
        if hours is not None and int(minutes) >= 60:
            raise InstructionScriptError(f"{source}: line {no}: minutes must be below 60 in {stamp!r}")
        t = int(hours or 0) * 3600 + int(minutes or 0) * 60 + float(seconds)
        if not (math.isfinite(t) and t <= MAX_SCRIPT_TIME_S):
            raise InstructionScriptError(
                f"{source}: line {no}: time {stamp!r} is too late (at most {MAX_SCRIPT_TIME_S:.0f} s)"
            )
        what = " ".join(what.split())
        if len(what) > MAX_INSTRUCTION_CHARS:
            raise InstructionScriptError(
                f"{source}: line {no}: the instruction has {len(what)} characters (at most {MAX_INSTRUCTION_CHARS})"
            )
        if len(lines) == MAX_SCRIPT_INSTRUCTIONS:
            raise InstructionScriptError(f"{source}: more than {MAX_SCRIPT_INSTRUCTIONS} instructions")
        lines.append(ScriptLine(time_s=t, text=what))
    return tuple(sorted(lines, key=lambda s: s.time_s))


def read_instruction_script(path: Path) -> tuple[ScriptLine, ...]:
    """:func:`parse_instruction_script` of a file read within :data:`MAX_SCRIPT_BYTES` (an
    unreadable, oversized or non-UTF-8 file is an error too)."""
    from storyteller.sim.bounded_files import BoundedFileError, read_bounded_bytes

    try:
        text = read_bounded_bytes(path, MAX_SCRIPT_BYTES, str(path)).decode("utf-8")
    except BoundedFileError as exc:
        raise InstructionScriptError(f"{path}: cannot read the instruction script ({exc.problem})") from None
    except UnicodeDecodeError as exc:
        raise InstructionScriptError(
            f"{path}: cannot read the instruction script (not UTF-8: bad byte at offset {exc.start})"
        ) from None
    return parse_instruction_script(text, str(path))

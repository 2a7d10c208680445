"""``--instructions FILE``: a timed script of instructions, in simulated time.

One instruction a line, ``TIME TEXT``: ``00:30 Ben leaves the kitchen and waves at Ava``.
``TIME`` is ``SS``, ``MM:SS`` or ``H:MM:SS`` (seconds may have a fraction: ``1:05.5``),
simulated seconds from the story's start. Blank lines and lines starting with ``#`` are
skipped. Lines may come in any order; instructions at the same time take effect in file
order, the last one winning (a new instruction replaces the one before). A line that does
not fit is an :class:`InstructionScriptError` naming the file, the line and what was
expected; nothing of the file is used then.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

_MAX_TIME_CHARS = 32
"""Characters of a line's ``TIME`` at most (``H:MM:SS.fff`` of any real story is far shorter)."""
_LINE = re.compile(r"^(?:(?:(\d+):)?(\d{1,2}):)?(\d+(?:\.\d+)?)\s+(\S.*)$")


class InstructionScriptError(Exception):
    """A script line that is not ``TIME TEXT`` (the message names the file and the line)."""


class ScriptLine(BaseModel):
    """One instruction of a script: at ``time_s`` simulated seconds, ``text``."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    time_s: float = Field(ge=0, description="Simulated seconds from the story's start.")
    text: str = Field(min_length=1)


def parse_instruction_script(text: str, source: str = "<script>") -> tuple[ScriptLine, ...]:
    """The script's lines, sorted by time (stable). ``source`` names the file in errors."""
    lines: list[ScriptLine] = []
    for no, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        m = _LINE.match(line)
        if m is None:
            raise InstructionScriptError(
                f"{source}: line {no}: expected 'TIME TEXT' with TIME as SS, MM:SS or H:MM:SS "
                f"(e.g. '00:30 Ben waves at Ava'), got {line[:60]!r}"
            )
        hours, minutes, seconds, what = m.groups()
        stamp = line.split()[0]
        if len(stamp) > _MAX_TIME_CHARS:  # 5,000 digits: past int()'s limit; 400 nines: an infinite float
            raise InstructionScriptError(
                f"{source}: line {no}: time {stamp[:20]!r}... is too long (at most {_MAX_TIME_CHARS} characters)"
            )
        if minutes is not None and float(seconds) >= 60:
            raise InstructionScriptError(f"{source}: line {no}: seconds must be below 60 in {line.split()[0]!r}")
        if hours is not None and int(minutes) >= 60:
            raise InstructionScriptError(f"{source}: line {no}: minutes must be below 60 in {line.split()[0]!r}")
        t = int(hours or 0) * 3600 + int(minutes or 0) * 60 + float(seconds)
        if not math.isfinite(t):  # unreachable within _MAX_TIME_CHARS; kept so no infinite time is ever stored
            raise InstructionScriptError(f"{source}: line {no}: time {stamp[:20]!r} is not a finite number of seconds")
        lines.append(ScriptLine(time_s=t, text=" ".join(what.split())))
    return tuple(sorted(lines, key=lambda s: s.time_s))


def read_instruction_script(path: Path) -> tuple[ScriptLine, ...]:
    """:func:`parse_instruction_script` of a file (an unreadable file is an error too)."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InstructionScriptError(f"{path}: cannot read the instruction script ({exc})") from None
    return parse_instruction_script(text, str(path))

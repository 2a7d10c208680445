"""Text from an LLM or a program, made safe to show: one helper per kind of printer.

Names, labels, activities and error messages come from a model or from an event program,
so they are data, never formatting: ``plain`` replaces control characters (C0, DEL, C1: the
terminal escape sequences) and bidirectional overrides with visible ``\\xNN`` / ``\\uNNNN``
escapes (terminal lines, log lines, the viewer's 3D labels and buttons, which draw text
literally); ``markup`` additionally escapes rich markup (``[red]``, ``[/]``) for text printed
through rich; ``markdown`` additionally escapes every markdown and HTML special character, for
the viewer's panel (viser renders its markdown with raw HTML and no sanitizing). Guarantee: the
result contains no control character, and through rich, or as markdown, it renders as the
literal text.
"""

from __future__ import annotations

import re

from rich.markup import escape

_UNSAFE = re.compile("[\x00-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")
_UNSAFE_IN_LINES = re.compile("[\x00-\x09\x0b-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")


def _visible(match: re.Match[str]) -> str:
    code = ord(match.group())
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}"


def plain(text: object, *, keep_newlines: bool = False) -> str:
    """``str(text)`` with every control character shown as an escape (newlines too, unless
    ``keep_newlines``: for multi-line messages such as error feedback)."""
    pattern = _UNSAFE_IN_LINES if keep_newlines else _UNSAFE
    return pattern.sub(_visible, str(text))


def markup(text: object) -> str:
    """``plain(text)`` with rich markup escaped, for tables and other rich output."""
    return escape(plain(text))


_MARKDOWN_SPECIAL = re.compile(r"([\\`*_{}\[\]()<>#+\-.!|~&:=\"'$^@])")


def markdown(text: object) -> str:
    """``plain(text)`` with every markdown (and inline HTML) special character backslash-escaped:
    one line of literal text in a markdown document, never a tag, link, entity or emphasis."""
    return _MARKDOWN_SPECIAL.sub(r"\\\1", plain(text))

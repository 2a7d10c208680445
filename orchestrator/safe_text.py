"""Text from outside, made safe to show: one helper per kind of printer.

``plain`` and ``one_line`` live in :mod:`storyteller.sim.visible_text` (the one home of the escaping, low
enough that ``storyteller.sim.export`` draws names with it) and are re-exported here; see that module for
what they escape. Used for terminal lines, log lines, the viewer's 3D labels and buttons, which
draw text literally. This module adds the escaping of two renderers: ``markup`` additionally
escapes rich markup (``[red]``, ``[/]``) for text printed through rich; ``markdown``
additionally escapes every markdown and HTML special character, for the viewer's panel (viser
renders its markdown with raw HTML and no sanitizing).

Guarantee: the result holds no control, format, separator or surrogate character (as
``plain``'s), and through rich, or as markdown, it renders as the literal text.
"""

from __future__ import annotations

import re

from rich.markup import escape

from storyteller.sim.visible_text import one_line, plain

__all__ = ["markdown", "markup", "one_line", "plain"]


def markup(text: object) -> str:
    """``plain(text)`` with rich markup escaped, for tables and other rich output."""
    return escape(plain(text))


_MARKDOWN_SPECIAL = re.compile(r"([\\`*_{}\[\]()<>#+\-.!|~&:=\"'$^@])")


def markdown(text: object) -> str:
    """``plain(text)`` with every markdown (and inline HTML) special character backslash-escaped:
    one line of literal text in a markdown document, never a tag, link, entity or emphasis."""
    return _MARKDOWN_SPECIAL.sub(r"\\\1", plain(text))

"""Text from outside with every character a terminal or a renderer would act on made visible.

Names, labels, activities and error messages come from a model, an event program or a file
someone shared, so they are data, never formatting: :func:`plain` replaces every character of
the Unicode categories Cc (controls: C0, DEL, C1, the terminal escape sequences), Cf (format:
bidirectional overrides and isolates, U+061C, zero-width characters, U+2060, the BOM), Zl and
Zp (U+2028, U+2029) and every lone surrogate (Cs) with a visible escape (``\\xNN``,
``\\uNNNN`` or ``\\UNNNNNNNN``), chosen by ``unicodedata.category``, not a hand list. The one
exception is ``keep_newlines``, for multi-line messages (error feedback): newline and tab stay.
:func:`one_line` first joins a message's lines with spaces, for the ``error:`` line a command
ends with (one line, whatever the message quoted).

This is the one home of the escaping: it lives in ``sim`` (pure, no I/O) so every layer may use
it: ``storyteller.sim.export`` for the names drawn in pictures, ``storyteller.orchestrator.safe_text`` for the terminal,
the logs and the viewer (which adds rich-markup and markdown escaping on top of it).

Guarantee: the result holds no character of those categories (but newline and tab with
``keep_newlines``; ``one_line``'s holds no line break at all), it encodes to UTF-8 (no lone
surrogate is left), and it is idempotent (escaped text escapes to itself).
"""

from __future__ import annotations

import unicodedata

UNSAFE_CATEGORIES = frozenset({"Cc", "Cf", "Zl", "Zp", "Cs"})
"""Unicode categories never shown raw: controls, format characters, line and paragraph
separators, surrogates."""

_LINE_BREAKS = frozenset("\n\t")


def _visible(char: str) -> str:
    code = ord(char)
    if code < 0x100:
        return f"\\x{code:02x}"
    return f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}"


def plain(text: object, *, keep_newlines: bool = False) -> str:
    """``str(text)`` with every control, format, separator and surrogate character shown as an
    escape (newlines and tabs too, unless ``keep_newlines``: for multi-line messages such as
    error feedback)."""
    text = str(text)
    if text.isprintable():  # fast path: no Cc, Cf, Cs, Zl, Zp (nor Co, Cn, Zs but the space)
        return text
    kept = _LINE_BREAKS if keep_newlines else frozenset()
    return "".join(
        _visible(c) if c not in kept and unicodedata.category(c) in UNSAFE_CATEGORIES else c
        for c in text
    )


def one_line(text: object) -> str:
    """``plain(text)`` on one line: its lines (split at every line break Python knows, U+2028 and
    U+2029 included) stripped and joined with single spaces, for an ``error:`` line."""
    return plain(" ".join(part.strip() for part in str(text).splitlines() if part.strip()))

"""Bounded text of values a program made: ``repr`` that stops at a size limit.

``bounded_repr(value, limit)`` renders ``repr(value)`` for str / int / float / bool / None /
list / tuple / dict / set / frozenset / range piece by piece and stops as soon as the text
reaches ``limit`` characters: it never builds the full text, never recurses (a value nested
20,000 deep is fine), and does work proportional to ``limit`` whatever the value's size (a
list of 20,000 references to a list of 20,000 references costs ``limit`` items, not 4·10^8).
Cycles render as Python renders them (``[...]``). Other objects are rendered by their own
``repr`` when their type defines one (clipped), else as ``<TypeName>``: a callable or a plain
object never shows its memory address. ``show`` is the form error messages use.

Guarantee: ``len(text) <= limit`` and, when ``complete`` is True, ``text == repr(value)`` for
the built-in types above. Imports only the standard library.
"""

from __future__ import annotations

import types
from collections.abc import Iterator
from typing import Final

SHOW_LIMIT: Final = 80
"""Characters of a value shown inside an error message."""

_CALLABLE_TYPES: Final = (
    types.FunctionType,
    types.MethodType,
    types.BuiltinFunctionType,
    types.BuiltinMethodType,
    types.MethodWrapperType,
    types.WrapperDescriptorType,
    type,
)


class _Frame:
    """One container being rendered: its remaining items and the text that closes it."""

    __slots__ = ("after_colon", "close", "first", "items", "key")

    def __init__(self, items: Iterator[object], close: str, key: int) -> None:
        self.items = items
        self.close = close
        self.first = True
        self.after_colon = False
        self.key = key


_COLON: Final = object()
"""Marks the place between a dict key and its value in a dict frame's items."""
_END: Final = object()


def _dict_items(d: dict[object, object]) -> Iterator[object]:
    for k, v in d.items():
        yield k
        yield _COLON
        yield v


def _int_text(value: int, room: int) -> tuple[str, bool]:
    digits = int(value.bit_length() * 0.30103) + 2
    if digits > room + 2:
        return f"<int of {value.bit_length()} bits>"[:room], False
    return repr(value), True


def _str_text(value: str, room: int) -> tuple[str, bool]:
    if len(value) <= room:
        return repr(value), True
    return repr(value[:room]), False


def _opaque_text(value: object, room: int) -> tuple[str, bool]:
    t = type(value)
    if isinstance(value, _CALLABLE_TYPES):
        name = getattr(value, "__name__", None)
        return (f"<function {name}>" if isinstance(name, str) else f"<{t.__name__}>"), True
    if t.__repr__ is object.__repr__:
        return f"<{t.__name__}>", True
    try:
        text = repr(value)
    except Exception:
        return f"<{t.__name__}>", True
    return text, len(text) <= room


_Opened = tuple[str, str, str, int, Iterator[object]]


def _open(value: object) -> _Opened | None:
    """(opening text, closing text, text when empty, length, items) of a container; None
    for a leaf."""
    if type(value) is list:
        return "[", "]", "[]", len(value), iter(value)
    if type(value) is tuple:
        return "(", ",)" if len(value) == 1 else ")", "()", len(value), iter(value)
    if type(value) is dict:
        return "{", "}", "{}", len(value), _dict_items(value)
    if type(value) is set:
        return "{", "}", "set()", len(value), iter(value)
    if type(value) is frozenset:
        return "frozenset({", "})", "frozenset()", len(value), iter(value)
    return None


def _leaf(value: object, room: int) -> tuple[str, bool]:
    if type(value) is str:
        return _str_text(value, room)
    if type(value) is int:
        return _int_text(value, room)
    if type(value) is float or type(value) is bool or value is None:
        return repr(value), True
    if type(value) is range:
        step = "" if value.step == 1 else f", {value.step}"
        start, ok1 = _int_text(value.start, room)
        stop, ok2 = _int_text(value.stop, room)
        return f"range({start}, {stop}{step})", ok1 and ok2
    return _opaque_text(value, room)


def bounded_repr(value: object, limit: int) -> tuple[str, bool]:
    """``(text, complete)``: ``repr(value)`` clipped to ``limit`` characters, built lazily.

    Every loop turn emits text or closes a container, so the work is O(``limit``) turns
    (plus one ``repr`` of at most ``limit`` characters per leaf).
    """
    out: list[str] = []
    size = 0
    stack: list[_Frame] = []
    active: set[int] = set()
    current: object = value
    have = True
    while size < limit:
        if not have:
            if not stack:
                return "".join(out), True
            frame = stack[-1]
            item = next(frame.items, _END)
            if item is _END:
                stack.pop()
                active.discard(frame.key)
                out.append(frame.close)
                size += len(frame.close)
            elif item is _COLON:
                out.append(": ")
                size += 2
                frame.after_colon = True
            else:
                if frame.first:
                    frame.first = False
                elif frame.after_colon:
                    frame.after_colon = False
                else:
                    out.append(", ")
                    size += 2
                current, have = item, True
            continue
        have = False
        opened = _open(current)
        if opened is None:
            text, complete = _leaf(current, limit - size)
            out.append(text)
            size += len(text)
            if not complete:
                return "".join(out)[:limit], False
            continue
        start, close, empty, length, items = opened
        key = id(current)
        if key in active:
            text = "[...]" if start == "[" else "(...)" if start == "(" else "{...}"
        elif length == 0:
            text = empty
        else:
            active.add(key)
            stack.append(_Frame(items, close, key))
            text = start
        out.append(text)
        size += len(text)
    text = "".join(out)
    if size <= limit and not have and not stack:
        return text, True
    return text[:limit], False


def show(value: object, limit: int = SHOW_LIMIT) -> str:
    """A value as an error message shows it: its ``repr``, clipped with ``...`` at ``limit``."""
    text, complete = bounded_repr(value, limit)
    return text if complete else text[: max(limit - 3, 0)] + "..."

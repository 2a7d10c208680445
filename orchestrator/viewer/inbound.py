"""What a page may send the viewer over its websocket: viser messages, nothing else.

viser reads every incoming websocket message with ``assert isinstance(raw, bytes)`` and
``Message.deserialize(raw)`` inside the connection's handler, so a text frame, bytes that are not
msgpack, a truncated message, one naming a type viser does not have, one missing its fields or
nested past msgpack's depth each ended the connection with an exception that websockets logged
as a traceback ("connection handler failed"). A client that is not the viewer's page can send
any of these (the handshake's Origin check does not stop a program on this machine). A message
that decodes could still break the viewer: a GUI update whose value viser cannot cast to its
element's type (``"abc"`` for the frame slider) was a traceback, and one of ``1e300`` for the
slider became an integer msgpack cannot encode, so every page that connected afterwards was
closed with an internal error.

:func:`checked_handler` wraps viser's connection handler: viser sees the connection through
:class:`CheckedConnection`, whose ``recv`` returns only binary messages that decode into one of
viser's message types with fields of their annotated types (:func:`fields_problem`), and whose
GUI updates (:func:`update_problem`) set only a value that is a bool, a string or finite numbers
within JavaScript's exact integers (what the page's inputs send) and that viser can cast to the
element's type. Anything else closes that connection with a close code and a one-line reason
(``1003`` for a text frame, ``1007`` for a message that does not decode, ``1008`` for a GUI
update viser cannot apply) and nothing is logged; viser's handler then sees the closed
connection it expects and tears it down as for a page that went away. Other connections and the
server go on. Messages over :data:`MAX_MESSAGE_BYTES` are refused by websockets itself (close
code ``1009``) from the frame header, before their payload is read (:mod:`.guarded_server` sets
``max_size``).

Guarantee: a message viser's handler receives decodes, with fields of their types (viser decodes
it again; the messages a page sends are small); the checks add no state across messages. Imports
``viser``'s message classes (pinned 1.1.1, as :mod:`.guarded_server`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import types
from collections.abc import Awaitable, Callable
from typing import Any, Literal, Union, cast, get_args, get_origin, get_type_hints

import msgspec
from viser._messages import GuiUpdateMessage, Message
from websockets.asyncio.server import ServerConnection
from websockets.frames import CloseCode

MAX_MESSAGE_BYTES = 8 << 20
"""The largest websocket message a page may send, bytes. The largest a page of this viewer sends
is the instruction box's text as typed (a pasted megabyte is then refused under the box with its
reason: an instruction is at most 2,000 characters), which 8 MiB holds in any characters. viser's
own limit, 50 MiB, is for ``get_render`` answers, which this viewer never asks for."""

MAX_EXACT = 2**53  # the page's numbers are JavaScript doubles: larger integers are not exact there
MAX_ITEMS = 64  # the longest vector a page's input sends (colours, multi-sliders: a few numbers)

GuiValue = Callable[[str], object]
"""The current value of the GUI input with this uuid (None: no such input, viser ignores it)."""
Handler = Callable[[ServerConnection], Awaitable[None]]


def _number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value) and abs(value) <= MAX_EXACT


def _cast(current: object, value: object) -> object:
    """``value`` cast the way viser casts a GUI update to the type of the element's ``current``
    value (raises when it cannot)."""
    if isinstance(current, tuple):
        if not isinstance(value, list | tuple):
            raise TypeError("a vector input takes a list")
        if not current:
            return tuple(value)
        item: Callable[[Any], object] = type(current[0])
        return tuple(item(v) for v in value)
    kind: Callable[[Any], object] = type(current)
    return kind(value)


def update_problem(updates: object, current: object) -> str | None:
    """Why a GUI update's ``updates`` cannot be applied to an input whose value is ``current``
    (None: no such input), or None when it can."""
    if not isinstance(updates, dict) or set(updates) != {"value"}:
        return "a GUI update sets its value only"
    value = updates["value"]
    items = value if isinstance(value, list) and len(value) <= MAX_ITEMS else [value]
    if not all(isinstance(v, bool | str) or _number(v) for v in items):
        return "a GUI value is a bool, a string or finite numbers"
    if current is None:
        return None
    try:
        cast_value = _cast(current, value)
    except (TypeError, ValueError, OverflowError):
        return f"the value does not convert to the input's type ({type(current).__name__})"
    cast_items = cast_value if isinstance(cast_value, tuple) else (cast_value,)
    if not all(isinstance(v, bool | str) or _number(v) for v in cast_items):
        return "a GUI value is a bool, a string or finite numbers"
    return None


def fits(value: object, annotation: object) -> bool:
    """Whether ``value`` (as msgpack decoded it) is what a field annotated ``annotation`` holds;
    viser's own types (props classes: the server sends those, not a page) pass."""
    origin = get_origin(annotation)
    if annotation is Any:
        return True
    if annotation in (bool, str, bytes, type(None)):
        return type(value) is annotation
    if annotation is int:  # a JavaScript number: exact integers only
        return _number(value) and float(cast(float, value)).is_integer()
    if annotation is float:
        return isinstance(value, int | float) and not isinstance(value, bool)
    if origin in (Union, types.UnionType):
        return any(fits(value, a) for a in get_args(annotation))
    if origin is Literal:
        return any(type(value) is type(a) and value == a for a in get_args(annotation))
    if origin is tuple:
        args = get_args(annotation)
        if not isinstance(value, list | tuple):
            return False
        if len(args) == 2 and args[1] is Ellipsis:
            return all(fits(v, args[0]) for v in value)
        return len(value) == len(args) and all(fits(v, a) for v, a in zip(value, args, strict=True))
    if origin is dict:
        return isinstance(value, dict)
    return True


def fields_problem(mapping: dict[Any, Any]) -> str | None:
    """Why a decoded message is not one of viser's message types with fields of their types
    (checked before viser builds it: viser casts what it can and warns about the rest)."""
    kind = mapping.get("type")
    known = Message._subclass_from_type_string()
    if not isinstance(kind, str) or kind not in known:
        return "an unknown message type"
    fields = _wire_fields(kind)
    for name, value in mapping.items():
        if name == "type":
            continue
        if name not in fields:
            return f"a field {kind} does not have"
        if not fits(value, fields[name]):
            return f"{kind}.{name} has the wrong type"
    return None


@functools.cache  # one entry per message type viser has (checked before the call)
def _wire_fields(kind: str) -> dict[str, Any]:
    """The annotation of each field of message type ``kind`` that goes on the wire."""
    message_type = Message._subclass_from_type_string()[kind]
    hints = get_type_hints(message_type)
    return {f.name: hints[f.name] for f in dataclasses.fields(message_type) if f.name in hints}


def message_problem(raw: str | bytes, gui_value: GuiValue) -> tuple[CloseCode, str] | None:
    """Why ``raw`` (one websocket message) is not a message of the page (a close code and a
    reason), or None when it decodes into a viser message whose fields have their types and, for
    a GUI update, fits the input ``gui_value`` finds."""
    if isinstance(raw, str):
        return CloseCode.UNSUPPORTED_DATA, "text frames are not viser messages"
    try:
        mapping = msgspec.msgpack.decode(raw)
    except (msgspec.DecodeError, RecursionError):
        return CloseCode.INVALID_DATA, "not msgpack"
    problem = fields_problem(mapping) if isinstance(mapping, dict) else "a viser message is a map"
    if problem is not None:
        return CloseCode.INVALID_DATA, problem
    try:
        message = Message.deserialize(raw)
    except Exception as exc:  # whatever else viser's decoding raises (a missing field: TypeError) is a refusal
        return CloseCode.INVALID_DATA, f"not a viser message ({type(exc).__name__})"
    if isinstance(message, GuiUpdateMessage):
        problem = update_problem(message.updates, gui_value(message.uuid))
        if problem is not None:
            return CloseCode.POLICY_VIOLATION, problem
    return None


class CheckedConnection:
    """A websockets ``ServerConnection`` whose ``recv`` returns only messages that decode; the
    rest of it (``send``, ``close``, ``subprotocol`` ...) is the connection's own."""

    def __init__(self, connection: ServerConnection, gui_value: GuiValue) -> None:
        self._connection = connection
        self._gui_value = gui_value

    def __getattr__(self, name: str) -> Any:
        return getattr(self._connection, name)

    async def recv(self) -> str | bytes:
        """The next message; a message that is not viser's closes the connection, and this
        raises websockets' ``ConnectionClosed`` as for a page that went away."""
        raw = await self._connection.recv()
        problem = message_problem(raw, self._gui_value)
        if problem is None:
            return raw
        await self._connection.close(*problem)
        return await self._connection.recv()  # closed: raises ConnectionClosedError


def checked_handler(handler: Handler, gui_value: GuiValue) -> Handler:
    """viser's connection handler, given each connection as a :class:`CheckedConnection`."""

    async def checked(connection: ServerConnection) -> None:
        await handler(cast(ServerConnection, CheckedConnection(connection, gui_value)))  # its interface, with a checked recv

    return checked

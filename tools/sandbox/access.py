"""Reading and writing parts of program values, and calling tools: ``obj.name``,
``container[key]``, ``container[key] = value`` and ``tool(...)``.

A program reads only allow-listed methods of built-in types, the attributes a type lists in
``sandbox_attributes`` and, with ``[...]``, types listing ``"[]"`` in ``sandbox_operators``;
never a name starting with ``_``. What a tool returns is detached (copied) before the program
sees it; a tool's ``EventProgramError`` keeps its type and gains the program line; any other
exception from a tool becomes ``ProgramRuntimeError`` (``BudgetExceededError`` for stack or
memory exhaustion). ``PROGRAM_LINE`` names the line of the tool call in progress.
"""

from __future__ import annotations

import contextlib
import inspect
from collections.abc import Callable
from typing import Protocol, cast

from storyteller.tools import errors
from storyteller.tools.errors import EventProgramError, did_you_mean
from storyteller.tools.sandbox.boundary import check_key, detach, is_int, materialize, type_name
from storyteller.tools.sandbox.budget import DICT_ITEM_BYTES, Meter, container_bytes, str_bytes
from storyteller.tools.sandbox.errors import (
    BudgetExceededError,
    ForbiddenConstructError,
    Line,
    ProgramRuntimeError,
    add_line,
    describe,
)
from storyteller.tools.sandbox.methods import METHODS, MethodImpl
from storyteller.tools.sandbox.values import INTERNAL_TYPES, BoundMethod
from storyteller.tools.value_text import show


class _Indexable(Protocol):
    """A tool-defined type that lists ``"[]"`` in ``sandbox_operators``."""

    def __getitem__(self, key: object, /) -> object: ...


def short_repr(value: object) -> str:
    """A value as an error message shows it: short literals (bounded), else the type name."""
    return show(value, 60) if type(value) in (str, int, float, bool) else type_name(value)


def get_attribute(obj: object, name: str, line: Line) -> object:
    """``obj.name``: an allow-listed method (bound) or a declared attribute (detached)."""
    t = type(obj)
    if name.startswith("_"):
        raise ForbiddenConstructError(
            f"attributes starting with '_' are not allowed ('.{name}')", line=line
        )
    methods = METHODS.get(t)
    if methods is not None:
        impl = methods.get(name)
        if impl is not None:
            return BoundMethod(obj, name, impl)
        allowed: frozenset[str] | set[str] | dict[str, MethodImpl] = methods
    else:
        declared = getattr(t, "sandbox_attributes", None) if t not in INTERNAL_TYPES else None
        allowed = declared if isinstance(declared, frozenset | set) else frozenset()
        if name in allowed:
            try:
                return detach(getattr(obj, name))
            except EventProgramError as err:
                add_line(err, line)
                raise
            except (AttributeError, TypeError, ValueError) as err:
                raise ProgramRuntimeError(f"reading '.{name}' failed: {err}", line=line) from None
    if hasattr(t, name):
        raise ForbiddenConstructError(
            f"'{t.__name__}.{name}' is not available in event programs"
            + (" (use an f-string)" if name in ("format", "format_map") else ""),
            line=line,
        )
    public = sorted(k for k in allowed if not k.startswith("_"))
    hint = did_you_mean(name, public, n=1) or (
        f" available: {', '.join(public[:12])}" if public else " it has no usable attributes"
    )
    raise ProgramRuntimeError(f"'{t.__name__}' object has no attribute '{name}';{hint}", line=line)


def get_item(container: object, key: object, meter: Meter, line: Line) -> object:
    """``container[key]`` (``key`` may be a slice)."""
    t = type(container)
    if type(container) is dict:
        check_key(key, line)
        try:
            return container[key]
        except KeyError:
            keys = (k for k in container if type(k) is str)
            hint = meter.suggest(key, keys, line) if type(key) is str else ""
            raise ProgramRuntimeError(
                f"key {short_repr(key)} is not in the dict;{hint or ' use d.get(key) to allow missing keys'}",
                line=line,
            ) from None
    if (
        type(container) is list
        or type(container) is tuple
        or type(container) is str
        or type(container) is range
    ):
        if type(key) is slice:
            result = container[key]
            n = len(result)
            meter.charge(str_bytes(n) if type(result) is str else container_bytes(n), line)
            return result
        if not is_int(key):
            raise ProgramRuntimeError(
                f"{t.__name__} indices must be integers, not '{type_name(key)}'", line=line
            )
        try:
            return container[key]
        except IndexError:
            raise ProgramRuntimeError(
                f"{t.__name__} index {key} out of range (length {len(container)})", line=line
            ) from None
    declared = getattr(t, "sandbox_operators", None) if t not in INTERNAL_TYPES else None
    if isinstance(declared, frozenset | set) and "[]" in declared:
        try:
            return detach(cast(_Indexable, container)[key])
        except EventProgramError as err:
            add_line(err, line)
            raise
    raise ProgramRuntimeError(f"a '{t.__name__}' cannot be indexed with [...]", line=line)


def set_item(container: object, key: object, value: object, meter: Meter, line: Line) -> None:
    """``container[key] = value`` for lists (index or slice) and dicts."""
    if type(container) is list:
        if type(key) is slice:
            items = materialize(value, meter, line)
            meter.check_len(len(container) + len(items), line, added=len(items))
            try:
                container[key] = items
            except ValueError as err:
                raise ProgramRuntimeError(f"slice assignment failed: {err}", line=line) from None
            return
        if not is_int(key):
            raise ProgramRuntimeError(
                f"list indices must be integers, not '{type_name(key)}'", line=line
            )
        try:
            container[key] = value
        except IndexError:
            raise ProgramRuntimeError(
                f"list index {key} out of range (length {len(container)})", line=line
            ) from None
    elif type(container) is dict:
        check_key(key, line)
        if key not in container:
            meter.check_len(len(container) + 1, line, added=1, item_bytes=DICT_ITEM_BYTES)
        container[key] = value
    else:
        raise ProgramRuntimeError(
            f"cannot assign items of a '{type_name(container)}' (only lists and dicts)", line=line
        )


def call_external(
    fn: Callable[..., object],
    args: list[object],
    kwargs: dict[str, object],
    meter: Meter,
    line: Line,
    label: str,
) -> object:
    """Call a tool (a namespace function or a declared method of a tool value)."""
    token = errors.PROGRAM_LINE.set(line)
    try:
        result = fn(*args, **kwargs)
    except EventProgramError as err:
        add_line(err, line)
        raise
    except (RecursionError, MemoryError):
        raise BudgetExceededError(f"{label}() ran out of stack or memory", line=line) from None
    except (Exception, SystemExit, KeyboardInterrupt) as err:
        message = f"{label}() failed: {describe(err)}"
        if isinstance(err, TypeError):
            with contextlib.suppress(TypeError, ValueError):
                message += f" (expected {label}{inspect.signature(fn)})"
        raise ProgramRuntimeError(message, line=line) from None
    finally:
        errors.PROGRAM_LINE.reset(token)
    meter.check_time(line)
    return detach(result)

"""Values crossing the sandbox boundary, checked before they are built.

What a tool or the namespace hands a program is copied (``detach``) so the program cannot
alias the caller's containers; what a program loops over, hashes, unpacks or turns into text
is bounded by the run's ``Meter`` *before* Python does the work (``materialize``,
``check_key``, ``to_text``, ``format_value``). The type sets name which built-in types a
program may operate on directly.
"""

from __future__ import annotations

import numbers
import re
from typing import TypeAlias, TypeGuard

from storyteller.tools.sandbox.budget import Meter, int_bytes
from storyteller.tools.sandbox.errors import BudgetExceededError, Line, ProgramRuntimeError
from storyteller.tools.value_text import bounded_repr

ITERABLE_TYPES = frozenset({list, tuple, str, dict, set, frozenset, range})
INT_TYPES = frozenset({int, bool})
NUMBER_TYPES = frozenset({int, bool, float})
SEQ_TYPES = frozenset({str, list, tuple})
OPERAND_TYPES = frozenset({int, bool, float, str, list, tuple, dict, set, frozenset, type(None)})
CONTAINER_TYPES = frozenset({list, tuple, dict, set, frozenset})
HASHED_TYPES = frozenset({dict, set, frozenset})

Hashed: TypeAlias = dict[object, object] | set[object] | frozenset[object]
"""A container whose items (keys) are hashed when it is built or compared."""


def is_int(value: object) -> TypeGuard[int]:
    """Exactly an int or a bool (never a subclass a tool defined)."""
    return type(value) in INT_TYPES


def is_number(value: object) -> TypeGuard[int | float]:
    """Exactly an int, a bool or a float."""
    return type(value) in NUMBER_TYPES


def is_hashed(value: object) -> TypeGuard[Hashed]:
    """Exactly a dict, a set or a frozenset."""
    return type(value) in HASHED_TYPES


def type_name(value: object) -> str:
    return type(value).__name__


def detach(value: object, memo: dict[int, object] | None = None) -> object:
    """Copy containers coming from tools / the namespace so a program cannot alias them.

    Lists, tuples, dicts and sets are copied recursively; subclasses of str/int/float (enums,
    numpy scalars) become plain values; any other object is passed by reference (opaque).
    """
    t = type(value)
    if t is str or t is int or t is float or t is bool or value is None:
        return value
    if memo is None:
        memo = {}
    key = id(value)
    if key in memo:
        return memo[key]
    if type(value) is list:
        out_list: list[object] = []
        memo[key] = out_list
        out_list.extend(detach(v, memo) for v in value)
        return out_list
    if type(value) is dict:
        out_dict: dict[object, object] = {}
        memo[key] = out_dict
        for k, v in value.items():
            out_dict[detach(k, memo)] = detach(v, memo)
        return out_dict
    if type(value) is tuple:
        return tuple(detach(v, memo) for v in value)
    if type(value) is set:
        return {detach(v, memo) for v in value}
    if type(value) is frozenset:
        return frozenset(detach(v, memo) for v in value)
    if isinstance(value, bool):
        return bool(value)
    if isinstance(value, str):
        return str.__str__(value)
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return float(value)
    return value


_FLAT_KEY = frozenset({str, int, float, bool, type(None)})


def check_key(key: object, line: Line) -> None:
    """A dict key / set item must be hashable and small (hashing deep tuples can crash C)."""
    t = type(key)
    if t is str or t is int or t is float or t is bool or key is None:
        return
    if (
        (type(key) is tuple or type(key) is frozenset)
        and len(key) < 100
        and _FLAT_KEY.issuperset(map(type, key))
    ):
        return  # the common case, checked in C
    stack = [key]
    count = 0
    while stack:
        v = stack.pop()
        count += 1
        if count > 100:
            raise BudgetExceededError(
                "a dict key or set item holds more than 100 values", line=line
            )
        if type(v) is tuple or type(v) is frozenset:
            stack.extend(v)
        elif type(v) is list or type(v) is dict or type(v) is set:
            raise ProgramRuntimeError(
                f"a '{type_name(v)}' cannot be a dict key or set item (use a tuple or a string)",
                line=line,
            )


Iterated: TypeAlias = (
    list[object]
    | tuple[object, ...]
    | str
    | dict[object, object]
    | set[object]
    | frozenset[object]
    | range
)
"""What a program may loop over (exact types: ``ITERABLE_TYPES``)."""


def iter_source(value: object, line: Line) -> Iterated:
    """The value itself if a program may loop over it."""
    if (
        type(value) is list
        or type(value) is tuple
        or type(value) is str
        or type(value) is dict
        or type(value) is set
        or type(value) is frozenset
        or type(value) is range
    ):
        return value
    raise ProgramRuntimeError(
        f"cannot loop over a value of type '{type_name(value)}' "
        "(loop over a list, tuple, dict, set, string or range)",
        line=line,
    )


def range_item_bytes(value: object) -> int:
    """Bytes of each int a loop over ``value`` creates (0 unless ``value`` is a range)."""
    if type(value) is not range:
        return 0
    return int_bytes(max(abs(value.start), abs(value.stop)).bit_length())


def materialize(value: object, meter: Meter, line: Line, what: str = "") -> list[object]:
    """All items of an iterable as a new list, after checking how many there are.

    The ints of a range are created here, so they are charged too (a range of 4096-bit
    numbers is not free).
    """
    src = iter_source(value, line)
    try:
        n = len(src)
    except OverflowError:
        n = meter.budget.container_len + 1
    meter.check_len(n, line, what=what, item_bytes=8 + range_item_bytes(src))
    return list(src)


def _ascii(text: str) -> str:
    """``ascii()`` from ``repr()`` text, as CPython derives it."""
    return text.encode("ascii", "backslashreplace").decode("ascii")


def to_text(value: object, meter: Meter, line: Line, conversion: str = "s") -> str:
    """``str`` / ``repr`` / ``ascii`` of a value, through the bounded renderer.

    The text is built piece by piece and refused as soon as it passes ``str_len``: the
    work is bounded by the limit, never by the size of the value. Types a tool defined
    with their own ``__str__`` use it (clipped to the limit after the fact: tools are
    trusted code).
    """
    t = type(value)
    if conversion == "s":
        if type(value) is str:
            return value
        if t is float or t is bool or value is None:
            return str(value)
        if t not in OPERAND_TYPES and t is not range and t.__str__ is not object.__str__:
            text = str(value)
            meter.check_str(len(text), line)
            return text
    limit = meter.budget.str_len
    text, complete = bounded_repr(value, limit + 1)
    meter.work(len(text), line)
    if not complete:
        raise BudgetExceededError(
            f"converting a '{t.__name__}' to text would give more than {limit} characters",
            line=line,
        )
    if conversion == "a":
        text = _ascii(text)
    meter.check_str(len(text), line)
    return text


_SPEC = re.compile(
    r"(?:.?[<>=^])?[-+ ]?z?#?0?(?P<width>\d*)[,_]?(?:\.(?P<precision>\d*))?[bcdeEfFgGnosxX%]?",
    re.DOTALL,
)


def format_value(value: object, spec: str, meter: Meter, line: Line) -> str:
    """One f-string field: width and precision are bounded, only numbers/strings take a spec."""
    if spec == "":
        return to_text(value, meter, line)
    match = _SPEC.fullmatch(spec)
    if match is None:
        raise ProgramRuntimeError(f"invalid format spec '{spec[:40]}' in an f-string", line=line)
    limit = meter.budget.format_width
    for group in ("width", "precision"):
        digits = match.group(group)
        if digits and (len(digits) > 6 or int(digits) > limit):
            raise BudgetExceededError(
                f"f-string {group} {digits[:12]} is too large (limit {limit})", line=line
            )
    if type(value) not in NUMBER_TYPES and type(value) is not str:
        raise ProgramRuntimeError(
            f"a format spec ':{spec[:40]}' only applies to numbers and strings, "
            f"not '{type_name(value)}'",
            line=line,
        )
    try:
        text = format(value, spec)
    except (ValueError, TypeError, OverflowError) as err:
        raise ProgramRuntimeError(f"cannot format with ':{spec[:40]}': {err}", line=line) from None
    meter.check_str(len(text), line)
    return text

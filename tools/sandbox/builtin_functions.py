"""The built-in functions event programs may call (``len``, ``range``, ``sorted``, ``print``...).

Each one checks its arguments and the size of what it would build *before* building it
(``sum(range(10**11))`` never starts) and raises ``ProgramRuntimeError`` /
``BudgetExceededError`` naming the program line. A program never holds a real Python
callable: it looks built-ins up by name in ``BUILTINS``. ``Host`` is the interpreter seen
from here (it calls program functions given as ``key=``).
"""

from __future__ import annotations

from collections.abc import Callable, Sized
from typing import Any, Protocol, TypeAlias, cast

from storyteller.tools.sandbox.boundary import (
    ITERABLE_TYPES,
    check_key,
    is_int,
    is_number,
    materialize,
    to_text,
    type_name,
)
from storyteller.tools.sandbox.budget import (
    DICT_ITEM_BYTES,
    REF_BYTES,
    SET_ITEM_BYTES,
    Meter,
    container_bytes,
    int_bytes,
)
from storyteller.tools.sandbox.errors import BudgetExceededError, Line, ProgramRuntimeError
from storyteller.tools.sandbox.operators import check_hash_spread, check_result, comparison_work


class Host(Protocol):
    """What built-ins need from the interpreter."""

    meter: Meter

    def call_value(
        self, fn: object, args: list[object], kwargs: dict[str, object], line: Line
    ) -> object: ...


BuiltinImpl: TypeAlias = Callable[[Host, list[object], dict[str, object], Line], object]
"""A built-in function: (interpreter, positional args, keyword args, program line) -> value."""


def arity(
    name: str,
    args: list[object],
    kwargs: dict[str, object],
    line: Line,
    low: int,
    high: int,
    keywords: tuple[str, ...] = (),
) -> None:
    if not low <= len(args) <= high:
        expected = str(low) if low == high else f"{low} to {high}"
        raise ProgramRuntimeError(
            f"{name}() takes {expected} positional arguments but {len(args)} were given",
            line=line,
        )
    for key in kwargs:
        if key not in keywords:
            allowed = ", ".join(keywords) if keywords else "none"
            raise ProgramRuntimeError(
                f"{name}() got an unexpected keyword argument '{key}' (allowed: {allowed})",
                line=line,
            )


def _number(name: str, value: object, line: Line) -> int | float:
    if not is_number(value):
        raise ProgramRuntimeError(f"{name}() needs a number, not '{type_name(value)}'", line=line)
    return value


def _keys(host: Host, items: list[object], key: object, line: Line) -> list[object]:
    if key is None:
        return items
    host.meter.charge(container_bytes(len(items)), line)
    return [host.call_value(key, [item], {}, line) for item in items]


def _position_key(keys: list[object]) -> Callable[[int], Any]:
    """Orders item positions by their keys: Python compares the keys and raises ``TypeError``
    for a pair it cannot order (the caller reports it)."""
    return keys.__getitem__


def _b_len(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("len", args, kwargs, line, 1, 1)
    value = args[0]
    if type(value) not in ITERABLE_TYPES and not hasattr(type(value), "__len__"):
        raise ProgramRuntimeError(f"len() of a '{type_name(value)}' is not defined", line=line)
    try:
        return len(cast("Sized", value))  # a sandbox iterable or a type with __len__
    except OverflowError:
        raise ProgramRuntimeError("len() of this range is too large", line=line) from None


def _b_range(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("range", args, kwargs, line, 1, 3)
    bounds: list[int] = []
    for a in args:
        if not is_int(a):
            raise ProgramRuntimeError(f"range() needs integers, not '{type_name(a)}'", line=line)
        bounds.append(a)
    try:
        return range(*bounds)
    except ValueError as err:
        raise ProgramRuntimeError(f"range(): {err}", line=line) from None


def _extreme(which: str) -> BuiltinImpl:
    pick = min if which == "min" else max

    def impl(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
        arity(which, args, kwargs, line, 1, host.meter.budget.container_len, ("key", "default"))
        items = (
            materialize(args[0], host.meter, line, f"{which}()") if len(args) == 1 else list(args)
        )
        if not items:
            if "default" in kwargs:
                return kwargs["default"]
            raise ProgramRuntimeError(f"{which}() of an empty sequence", line=line)
        keys = _keys(host, items, kwargs.get("key"), line)
        comparison_work(host.meter, line, keys)
        try:
            best = pick(range(len(items)), key=_position_key(keys))
        except TypeError as err:
            raise ProgramRuntimeError(
                f"{which}() cannot compare the items: {err}", line=line
            ) from None
        return items[best]

    return impl


def _b_sum(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("sum", args, kwargs, line, 1, 2, ("start",))
    items = materialize(args[0], host.meter, line, "sum()")
    total = _number("sum", args[1] if len(args) > 1 else kwargs.get("start", 0), line)
    for item in items:
        total = check_result(total + _number("sum", item, line), host.meter, line)
    return total


def _b_abs(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("abs", args, kwargs, line, 1, 1)
    return abs(_number("abs", args[0], line))


def _b_round(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("round", args, kwargs, line, 1, 2, ("ndigits",))
    value = _number("round", args[0], line)
    ndigits = args[1] if len(args) > 1 else kwargs.get("ndigits")
    if ndigits is None:
        try:
            return check_result(round(value), host.meter, line)
        except (ValueError, OverflowError) as err:
            raise ProgramRuntimeError(f"round(): {err}", line=line) from None
    if not is_int(ndigits) or not -30 <= ndigits <= 30:
        raise ProgramRuntimeError("round() needs ndigits between -30 and 30", line=line)
    return round(value, ndigits)


def _b_sorted(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("sorted", args, kwargs, line, 1, 1, ("key", "reverse"))
    items = materialize(args[0], host.meter, line, "sorted()")
    return sort_items(host, items, kwargs.get("key"), kwargs.get("reverse", False), line)


def sort_items(
    host: Host, items: list[object], key: object, reverse: object, line: Line
) -> list[object]:
    keys = _keys(host, items, key, line)
    comparison_work(host.meter, line, keys, repeat=max(1, len(keys).bit_length()))
    try:
        order = sorted(range(len(items)), key=_position_key(keys), reverse=bool(reverse))
    except TypeError as err:
        raise ProgramRuntimeError(f"cannot sort these items: {err}", line=line) from None
    return [items[i] for i in order]


def _b_reversed(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("reversed", args, kwargs, line, 1, 1)
    items = materialize(args[0], host.meter, line, "reversed()")
    items.reverse()
    return items


def _b_enumerate(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("enumerate", args, kwargs, line, 1, 2, ("start",))
    items = materialize(args[0], host.meter, line, "enumerate()")
    start = args[1] if len(args) > 1 else kwargs.get("start", 0)
    if not is_int(start):
        raise ProgramRuntimeError("enumerate() needs an integer start", line=line)
    last = int(start) + len(items)
    bits = max(abs(int(start)), abs(last)).bit_length()
    host.meter.check_bits(bits, line)
    pair = container_bytes(2) + int_bytes(bits)  # a 2-tuple and its new int
    host.meter.check_len(len(items), line, item_bytes=REF_BYTES + pair)
    return [(start + i, item) for i, item in enumerate(items)]


def _b_zip(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("zip", args, kwargs, line, 0, 20)
    lists = [materialize(a, host.meter, line, "zip()") for a in args]
    n = min(map(len, lists), default=0)
    host.meter.check_len(n, line, item_bytes=REF_BYTES + container_bytes(len(lists)))
    return list(zip(*lists, strict=False))


def _b_list(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("list", args, kwargs, line, 0, 1)
    return materialize(args[0], host.meter, line) if args else []


def _b_tuple(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("tuple", args, kwargs, line, 0, 1)
    return tuple(materialize(args[0], host.meter, line)) if args else ()


def _b_set(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("set", args, kwargs, line, 0, 1)
    items = materialize(args[0], host.meter, line) if args else []
    for item in items:
        check_key(item, line)
    check_hash_spread(items, host.meter, line)
    host.meter.charge(container_bytes(len(items), SET_ITEM_BYTES), line)
    return set(items)


def dict_from(
    host: Host, args: list[object], kwargs: dict[str, object], line: Line
) -> dict[object, object]:
    arity("dict", args, kwargs, line, 0, 1, tuple(kwargs))
    out: dict[object, object] = {}
    if args:
        source = args[0]
        if type(source) is dict:
            pairs: list[object] = list(source.items())
        else:
            pairs = materialize(source, host.meter, line)
        host.meter.check_len(len(pairs) + len(kwargs), line, item_bytes=DICT_ITEM_BYTES)
        items: list[tuple[object, object]] = []
        for pair in pairs:
            if not (type(pair) is tuple or type(pair) is list) or len(pair) != 2:
                raise ProgramRuntimeError("dict() needs (key, value) pairs", line=line)
            check_key(pair[0], line)
            items.append((pair[0], pair[1]))
        check_hash_spread([key for key, _ in items], host.meter, line)
        out.update(items)
    out.update(kwargs)
    return out


def _b_str(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("str", args, kwargs, line, 0, 1)
    return to_text(args[0], host.meter, line) if args else ""


def _b_int(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("int", args, kwargs, line, 0, 1)
    if not args:
        return 0
    value = args[0]
    if type(value) is str:
        if len(value) > host.meter.budget.int_bits // 3 + 10:
            raise BudgetExceededError("int() of a very long string", line=line)
        source: str | float = value
    elif is_number(value):
        source = value
    else:
        raise ProgramRuntimeError(
            f"int() needs a number or a string, not '{type_name(value)}'", line=line
        )
    try:
        result = int(source)
    except (ValueError, OverflowError) as err:
        raise ProgramRuntimeError(f"int(): {err}", line=line) from None
    return check_result(result, host.meter, line)


def _b_float(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("float", args, kwargs, line, 0, 1)
    if not args:
        return 0.0
    value = args[0]
    if type(value) is str:
        if len(value) > 400:
            raise ProgramRuntimeError("float() of a very long string", line=line)
        source: str | float = value
    elif is_number(value):
        source = value
    else:
        raise ProgramRuntimeError(
            f"float() needs a number or a string, not '{type_name(value)}'", line=line
        )
    try:
        return float(source)
    except (ValueError, OverflowError) as err:
        raise ProgramRuntimeError(f"float(): {err}", line=line) from None


def _b_bool(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("bool", args, kwargs, line, 0, 1)
    return bool(args[0]) if args else False


def _b_any(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("any", args, kwargs, line, 1, 1)
    return any(materialize(args[0], host.meter, line, "any()"))


def _b_all(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("all", args, kwargs, line, 1, 1)
    return all(materialize(args[0], host.meter, line, "all()"))


def _b_print(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    arity("print", args, kwargs, line, 0, 50, ("sep", "end"))
    sep = kwargs.get("sep", " ")
    end = kwargs.get("end", "\n")
    sep = " " if sep is None else sep
    end = "\n" if end is None else end
    if type(sep) is not str or type(end) is not str:
        raise ProgramRuntimeError("print(): sep and end must be strings", line=line)
    parts = [to_text(a, host.meter, line) for a in args]
    host.meter.check_str(sum(map(len, parts)) + len(sep) * len(parts) + len(end), line)
    text = sep.join(parts) + end
    if text.endswith("\n"):
        text = text[:-1]
    for piece in text.split("\n"):
        host.meter.print_line(piece, line)
    return None


BUILTINS: dict[str, BuiltinImpl] = {
    "len": _b_len,
    "range": _b_range,
    "min": _extreme("min"),
    "max": _extreme("max"),
    "abs": _b_abs,
    "sum": _b_sum,
    "sorted": _b_sorted,
    "reversed": _b_reversed,
    "enumerate": _b_enumerate,
    "zip": _b_zip,
    "list": _b_list,
    "dict": dict_from,
    "set": _b_set,
    "tuple": _b_tuple,
    "str": _b_str,
    "int": _b_int,
    "float": _b_float,
    "bool": _b_bool,
    "round": _b_round,
    "any": _b_any,
    "all": _b_all,
    "print": _b_print,
}


# Python built-ins a program may reach for; named in the "not available" message.
def words(text: str) -> list[str]:
    return text.split()


PYTHON_ONLY_BUILTINS = frozenset(
    words(
        """
    getattr setattr delattr hasattr type vars dir globals locals open eval exec compile
    __import__ format isinstance issubclass id hash input exit quit help object super
    classmethod staticmethod property iter next map filter chr ord divmod pow repr ascii
    callable memoryview bytes bytearray breakpoint frozenset slice complex bin hex oct aiter
    anext math random os sys Exception BaseException SystemExit
    """
    )
)

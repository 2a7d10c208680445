"""Values, operators, built-in functions and methods that event programs may use.

Everything here checks sizes *before* computing (``'a' * 10**10``, ``10**10**8``,
``1 << 10**9``, ``sum(range(10**11))`` never start) and never hands a program a real Python
callable: built-ins and methods are looked up by name in fixed tables. ``Host`` is the
interpreter seen from here (it calls program functions for ``key=`` arguments).
"""

from __future__ import annotations

import ast
import math
import numbers
import operator
import re
from collections.abc import Callable, Iterable
from typing import Protocol

from tools.sandbox.budget import (
    BudgetExceededError,
    ForbiddenConstructError,
    Meter,
    ProgramRuntimeError,
    nested_size,
    text_len_bound,
)

Line = int | None

PRIMITIVE = (str, int, float, bool, type(None))
ITERABLE_TYPES = frozenset({list, tuple, str, dict, set, frozenset, range})
INT_TYPES = frozenset({int, bool})
NUMBER_TYPES = frozenset({int, bool, float})
SEQ_TYPES = frozenset({str, list, tuple})
OPERAND_TYPES = frozenset({int, bool, float, str, list, tuple, dict, set, frozenset, type(None)})


class Host(Protocol):
    """What built-ins need from the interpreter."""

    meter: Meter

    def call_value(
        self, fn: object, args: list[object], kwargs: dict[str, object], line: Line
    ) -> object: ...


def type_name(value: object) -> str:
    return type(value).__name__


# ---------------------------------------------------------------- values crossing the boundary


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
    if t is list:
        out_list: list[object] = []
        memo[key] = out_list
        out_list.extend(detach(v, memo) for v in value)  # type: ignore[attr-defined]
        return out_list
    if t is dict:
        out_dict: dict[object, object] = {}
        memo[key] = out_dict
        for k, v in value.items():  # type: ignore[attr-defined]
            out_dict[detach(k, memo)] = detach(v, memo)
        return out_dict
    if t is tuple:
        return tuple(detach(v, memo) for v in value)  # type: ignore[attr-defined]
    if t is set:
        return {detach(v, memo) for v in value}  # type: ignore[attr-defined]
    if t is frozenset:
        return frozenset(detach(v, memo) for v in value)  # type: ignore[attr-defined]
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
    if (t is tuple or t is frozenset) and len(key) < 100 and _FLAT_KEY.issuperset(map(type, key)):  # type: ignore[arg-type]
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
        tv = type(v)
        if tv is tuple or tv is frozenset:
            stack.extend(v)  # type: ignore[arg-type]
        elif tv is list or tv is dict or tv is set:
            raise ProgramRuntimeError(
                f"a '{tv.__name__}' cannot be a dict key or set item (use a tuple or a string)",
                line=line,
            )


def iter_source(value: object, line: Line) -> Iterable[object]:
    """The value itself if a program may loop over it."""
    if type(value) in ITERABLE_TYPES:
        return value  # type: ignore[return-value]
    raise ProgramRuntimeError(
        f"cannot loop over a value of type '{type_name(value)}' "
        "(loop over a list, tuple, dict, set, string or range)",
        line=line,
    )


def materialize(value: object, meter: Meter, line: Line, what: str = "") -> list[object]:
    """All items of an iterable as a new list, after checking how many there are."""
    src = iter_source(value, line)
    try:
        n = len(src)  # type: ignore[arg-type]
    except OverflowError:
        n = meter.budget.container_len + 1
    meter.check_len(n, line, what=what)
    return list(src)


def to_text(value: object, meter: Meter, line: Line, conversion: str = "s") -> str:
    """``str`` / ``repr`` / ``ascii`` of a value, bounded before rendering."""
    t = type(value)
    if conversion == "s":
        if t is str:
            return value  # type: ignore[return-value]
        if t is int or t is float or t is bool or value is None:
            return str(value)
    limit = meter.budget.str_len
    if t in OPERAND_TYPES or t is range:
        bound = text_len_bound(value, limit)
        if bound > limit:
            raise BudgetExceededError(
                f"converting a '{t.__name__}' to text would give about {bound} characters "
                f"(limit {limit})",
                line=line,
            )
    render = {"s": str, "r": repr, "a": ascii}[conversion]
    text = render(value)
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


# ---------------------------------------------------------------- operators

_BINARY: dict[type[ast.operator], tuple[str, Callable[[object, object], object]]] = {
    ast.Add: ("+", operator.add),
    ast.Sub: ("-", operator.sub),
    ast.Mult: ("*", operator.mul),
    ast.Div: ("/", operator.truediv),
    ast.FloorDiv: ("//", operator.floordiv),
    ast.Mod: ("%", operator.mod),
    ast.Pow: ("**", operator.pow),
    ast.LShift: ("<<", operator.lshift),
    ast.RShift: (">>", operator.rshift),
    ast.BitOr: ("|", operator.or_),
    ast.BitXor: ("^", operator.xor),
    ast.BitAnd: ("&", operator.and_),
}


def operator_symbol(op: ast.operator) -> str:
    entry = _BINARY.get(type(op))
    return entry[0] if entry else type(op).__name__


def _operand_ok(value: object, symbol: str) -> bool:
    if type(value) in OPERAND_TYPES:
        return True
    declared = getattr(type(value), "sandbox_operators", None)
    return isinstance(declared, frozenset | set) and symbol in declared


def binary(op: ast.operator, a: object, b: object, meter: Meter, line: Line) -> object:
    """``a <op> b`` with sizes checked first; Python errors become ``ProgramRuntimeError``."""
    entry = _BINARY.get(type(op))
    if entry is None:
        raise ForbiddenConstructError(
            f"the operator {type(op).__name__} is not supported", line=line
        )
    symbol, fn = entry
    ta, tb = type(a), type(b)
    if not (_operand_ok(a, symbol) and _operand_ok(b, symbol)):
        raise ProgramRuntimeError(
            f"unsupported operand types for {symbol}: '{ta.__name__}' and '{tb.__name__}'",
            line=line,
        )
    if symbol == "+":
        if ta is str and tb is str:
            meter.check_str(len(a) + len(b), line)  # type: ignore[arg-type]
        elif ta is tb and (ta is list or ta is tuple):
            meter.check_len(len(a) + len(b), line)  # type: ignore[arg-type]
    elif symbol == "*":
        if ta in SEQ_TYPES and tb in INT_TYPES:
            _check_repeat(a, b, meter, line)
        elif tb in SEQ_TYPES and ta in INT_TYPES:
            _check_repeat(b, a, meter, line)
        elif ta in INT_TYPES and tb in INT_TYPES:
            meter.check_bits(a.bit_length() + b.bit_length(), line)  # type: ignore[attr-defined]
    elif symbol == "**":
        if ta in INT_TYPES and tb in INT_TYPES and b > 1 and abs(a) > 1:  # type: ignore[operator]
            meter.check_bits(a.bit_length() * b, line)  # type: ignore[attr-defined,operator]
    elif symbol == "<<":
        if ta in INT_TYPES and tb in INT_TYPES and b > 0 and a != 0:  # type: ignore[operator]
            meter.check_bits(a.bit_length() + b, line)  # type: ignore[attr-defined,operator]
    elif symbol == "%":
        if ta is str:
            raise ForbiddenConstructError(
                "'%' string formatting is not allowed; use an f-string", line=line
            )
    elif (
        symbol in ("|", "&", "^", "-")
        and ta in (set, frozenset, dict)
        and tb in (set, frozenset, dict)
    ):
        meter.check_len(len(a) + len(b), line)  # type: ignore[arg-type]
        check_hash_spread([*a, *b], meter, line)  # type: ignore[misc]
    try:
        result = fn(a, b)
    except ZeroDivisionError:
        raise ProgramRuntimeError(f"division by zero in '{symbol}'", line=line) from None
    except (TypeError, ValueError, ArithmeticError) as err:
        raise ProgramRuntimeError(f"'{symbol}' failed: {err}", line=line) from None
    return check_result(result, meter, line)


def _check_repeat(seq: object, n: object, meter: Meter, line: Line) -> None:
    size = len(seq) * max(int(n), 0)  # type: ignore[arg-type,call-overload]
    if type(seq) is str:
        meter.check_str(size, line)
    else:
        meter.check_len(size, line)


def check_result(value: object, meter: Meter, line: Line) -> object:
    """Post-check of arithmetic results: integer size, no complex numbers."""
    t = type(value)
    if t is int:
        meter.check_bits(value.bit_length(), line)  # type: ignore[attr-defined]
    elif t is complex:
        raise ProgramRuntimeError(
            "the result is a complex number (e.g. a negative number to a fractional power)",
            line=line,
        )
    return value


def unary(op: ast.unaryop, v: object, meter: Meter, line: Line) -> object:
    if isinstance(op, ast.Not):
        return not v
    t = type(v)
    if isinstance(op, ast.Invert):
        if t in INT_TYPES:
            return check_result(~v, meter, line)  # type: ignore[operator]
    elif t in NUMBER_TYPES:
        return check_result(-v if isinstance(op, ast.USub) else +v, meter, line)  # type: ignore[operator]
    symbol = {ast.Invert: "~", ast.USub: "-", ast.UAdd: "+"}.get(type(op), "?")
    raise ProgramRuntimeError(f"bad operand type for unary {symbol}: '{t.__name__}'", line=line)


_COMPARE: dict[type[ast.cmpop], tuple[str, Callable[[object, object], object]]] = {
    ast.Eq: ("==", operator.eq),
    ast.NotEq: ("!=", operator.ne),
    ast.Lt: ("<", operator.lt),
    ast.LtE: ("<=", operator.le),
    ast.Gt: (">", operator.gt),
    ast.GtE: (">=", operator.ge),
    ast.Is: ("is", operator.is_),
    ast.IsNot: ("is not", operator.is_not),
}


CONTAINER_TYPES = frozenset({list, tuple, dict, set, frozenset})
_HASHED = frozenset({dict, set, frozenset})


def comparison_work(meter: Meter, line: Line, items: list[object], repeat: int = 1) -> None:
    """Comparing nested containers runs in C without checks: bound and charge it first.

    ``items`` are the values whose nested sizes add up to the work; ``repeat`` multiplies it
    (e.g. the length of the list searched by ``in``).
    """
    cap = meter.budget.container_len * 10
    total = 0
    for item in items:
        if type(item) in CONTAINER_TYPES:
            total += nested_size(item, cap)
            if total * repeat > cap:
                break
    work = total * repeat
    if work > cap:
        raise BudgetExceededError(
            f"comparing these values means visiting about {work} nested items (limit {cap})",
            line=line,
        )
    meter.work(work, line)


def compare(op: ast.cmpop, a: object, b: object, meter: Meter, line: Line) -> bool:
    t = type(op)
    if t is ast.In or t is ast.NotIn:
        found = contains(b, a, meter, line)
        return found if t is ast.In else not found
    if (
        t is not ast.Is
        and t is not ast.IsNot
        and type(a) in CONTAINER_TYPES
        and type(b) in CONTAINER_TYPES
    ):
        cap = meter.budget.container_len * 10
        work = min(nested_size(a, cap), nested_size(b, cap))
        if work > cap:
            raise BudgetExceededError(
                f"comparing these values means visiting about {work} nested items (limit {cap})",
                line=line,
            )
        meter.work(work, line)
        if type(a) in _HASHED and type(b) in _HASHED:
            check_hash_spread([*a, *b], meter, line)  # type: ignore[misc]
    symbol, fn = _COMPARE[t]
    try:
        return bool(fn(a, b))
    except TypeError:
        raise ProgramRuntimeError(
            f"'{symbol}' is not supported between '{type_name(a)}' and '{type_name(b)}'",
            line=line,
        ) from None


def contains(container: object, item: object, meter: Meter, line: Line) -> bool:
    t = type(container)
    if t is str:
        if type(item) is not str:
            raise ProgramRuntimeError(
                f"'in <string>' needs a string on the left, not '{type_name(item)}'", line=line
            )
    elif t is dict or t is set or t is frozenset:
        check_key(item, line)
    elif t is list or t is tuple:
        meter.work(len(container), line)  # type: ignore[arg-type]
        if type(item) in CONTAINER_TYPES:
            comparison_work(meter, line, [item], repeat=len(container))  # type: ignore[arg-type]
    elif t is range:
        return range_contains(container, item)  # type: ignore[arg-type]
    else:
        raise ProgramRuntimeError(
            f"'in' needs a list, tuple, dict, set, string or range, not '{t.__name__}'", line=line
        )
    return item in container  # type: ignore[operator]


def range_contains(r: range, item: object) -> bool:
    """``item in r`` in constant time.

    CPython answers ``in range`` arithmetically only for ints; any other item (``0.5 in
    range(10**15)``, ``'a' in range(10**12)``) makes it compare the item with every number
    of the range, in C, where no budget can stop it. A float is in the range if it is a
    whole number that is; nothing else equals an int.
    """
    ti = type(item)
    if ti is int or ti is bool:
        return item in r
    if ti is float:
        f: float = item  # type: ignore[assignment]
        return math.isfinite(f) and f.is_integer() and int(f) in r
    return False


HASH_GUARD_MIN = 256
"""Bulk set / dict builds with fewer items than this skip the hash-collision check."""
COLLISION_PROBES = 200_000
"""Comparisons a bulk set / dict build may need because distinct keys share a hash value."""


def check_hash_spread(items: list[object], meter: Meter, line: Line) -> None:
    """Before a set / dict is built from (or compared with) ``items`` in one C call.

    Python hashes an int by its value modulo 2**61 - 1, so a program can build thousands of
    distinct numbers with one hash value (``[i * (2**61 - 1) for i in range(20000)]``);
    putting them in one set then compares every pair, for seconds, inside a single C call.
    Bounds the distinct values sharing each hash (one comparison per item, never hashing
    again) and refuses the build if the comparisons would pass ``COLLISION_PROBES``.
    """
    n = len(items)
    if n < HASH_GUARD_MIN:
        return
    meter.work(n, line)
    groups: dict[int, list[object]] = {}
    for item in items:
        groups.setdefault(hash(item), []).append(item)
    if len(groups) == n:
        return
    probes = 0
    for group in groups.values():
        if len(group) > 16:
            distinct = _distinct_count(group)
            probes += distinct * distinct // 2
    if probes > COLLISION_PROBES:
        raise BudgetExceededError(
            "too many different values in one set or dict share the same hash value "
            f"(about {probes} comparisons, limit {COLLISION_PROBES}); use fewer or smaller "
            "numbers as keys",
            line=line,
        )


def _distinct_count(group: list[object]) -> int:
    """Upper bound of the distinct values among items sharing one hash value, in one pass.

    Items equal to the first one are duplicates (the common case: one value many times);
    every other item is counted as distinct, which only over-counts when several different
    values share a hash, i.e. for the crafted collisions this guard exists for.
    """
    first = group[0]
    return 1 + sum(1 for v in group if v is not first and v != first)


# ---------------------------------------------------------------- built-in functions

BuiltinImpl = Callable[[Host, list[object], dict[str, object], Line], object]


def _arity(
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
    if type(value) not in NUMBER_TYPES:
        raise ProgramRuntimeError(f"{name}() needs a number, not '{type_name(value)}'", line=line)
    return value  # type: ignore[return-value]


def _keys(host: Host, items: list[object], key: object, line: Line) -> list[object]:
    if key is None:
        return items
    host.meter.allocate(len(items), line)
    return [host.call_value(key, [item], {}, line) for item in items]


def _b_len(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("len", args, kwargs, line, 1, 1)
    value = args[0]
    if type(value) not in ITERABLE_TYPES and not hasattr(type(value), "__len__"):
        raise ProgramRuntimeError(f"len() of a '{type_name(value)}' is not defined", line=line)
    try:
        return len(value)  # type: ignore[arg-type]
    except OverflowError:
        raise ProgramRuntimeError("len() of this range is too large", line=line) from None


def _b_range(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("range", args, kwargs, line, 1, 3)
    for a in args:
        if type(a) not in INT_TYPES:
            raise ProgramRuntimeError(f"range() needs integers, not '{type_name(a)}'", line=line)
    try:
        return range(*args)  # type: ignore[arg-type]
    except ValueError as err:
        raise ProgramRuntimeError(f"range(): {err}", line=line) from None


def _extreme(which: str) -> BuiltinImpl:
    pick = min if which == "min" else max

    def impl(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
        _arity(which, args, kwargs, line, 1, host.meter.budget.container_len, ("key", "default"))
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
            best = pick(range(len(items)), key=keys.__getitem__)
        except TypeError as err:
            raise ProgramRuntimeError(
                f"{which}() cannot compare the items: {err}", line=line
            ) from None
        return items[best]

    return impl


def _b_sum(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("sum", args, kwargs, line, 1, 2, ("start",))
    items = materialize(args[0], host.meter, line, "sum()")
    total: object = args[1] if len(args) > 1 else kwargs.get("start", 0)
    _number("sum", total, line)
    for item in items:
        _number("sum", item, line)
        total = check_result(total + item, host.meter, line)  # type: ignore[operator]
    return total


def _b_abs(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("abs", args, kwargs, line, 1, 1)
    return abs(_number("abs", args[0], line))


def _b_round(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("round", args, kwargs, line, 1, 2, ("ndigits",))
    value = _number("round", args[0], line)
    ndigits = args[1] if len(args) > 1 else kwargs.get("ndigits")
    if ndigits is None:
        try:
            return round(value)
        except (ValueError, OverflowError) as err:
            raise ProgramRuntimeError(f"round(): {err}", line=line) from None
    if type(ndigits) not in INT_TYPES or not -30 <= ndigits <= 30:  # type: ignore[operator]
        raise ProgramRuntimeError("round() needs ndigits between -30 and 30", line=line)
    return round(value, ndigits)  # type: ignore[arg-type]


def _b_sorted(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("sorted", args, kwargs, line, 1, 1, ("key", "reverse"))
    items = materialize(args[0], host.meter, line, "sorted()")
    return sort_items(host, items, kwargs.get("key"), kwargs.get("reverse", False), line)


def sort_items(
    host: Host, items: list[object], key: object, reverse: object, line: Line
) -> list[object]:
    keys = _keys(host, items, key, line)
    comparison_work(host.meter, line, keys, repeat=max(1, len(keys).bit_length()))
    try:
        order = sorted(range(len(items)), key=keys.__getitem__, reverse=bool(reverse))
    except TypeError as err:
        raise ProgramRuntimeError(f"cannot sort these items: {err}", line=line) from None
    return [items[i] for i in order]


def _b_reversed(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("reversed", args, kwargs, line, 1, 1)
    items = materialize(args[0], host.meter, line, "reversed()")
    items.reverse()
    return items


def _b_enumerate(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("enumerate", args, kwargs, line, 1, 2, ("start",))
    items = materialize(args[0], host.meter, line, "enumerate()")
    start = args[1] if len(args) > 1 else kwargs.get("start", 0)
    if type(start) not in INT_TYPES:
        raise ProgramRuntimeError("enumerate() needs an integer start", line=line)
    return [(start + i, item) for i, item in enumerate(items)]  # type: ignore[operator]


def _b_zip(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("zip", args, kwargs, line, 0, 20)
    lists = [materialize(a, host.meter, line, "zip()") for a in args]
    return list(zip(*lists, strict=False))


def _b_list(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("list", args, kwargs, line, 0, 1)
    return materialize(args[0], host.meter, line) if args else []


def _b_tuple(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("tuple", args, kwargs, line, 0, 1)
    return tuple(materialize(args[0], host.meter, line)) if args else ()


def _b_set(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("set", args, kwargs, line, 0, 1)
    items = materialize(args[0], host.meter, line) if args else []
    for item in items:
        check_key(item, line)
    check_hash_spread(items, host.meter, line)
    return set(items)


def _b_dict(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("dict", args, kwargs, line, 0, 1, tuple(kwargs))
    out: dict[object, object] = {}
    if args:
        source = args[0]
        if type(source) is dict:
            pairs: list[object] = list(source.items())  # type: ignore[attr-defined]
        else:
            pairs = materialize(source, host.meter, line)
        host.meter.check_len(len(pairs) + len(kwargs), line)
        for pair in pairs:
            if type(pair) not in (tuple, list) or len(pair) != 2:  # type: ignore[arg-type]
                raise ProgramRuntimeError("dict() needs (key, value) pairs", line=line)
            check_key(pair[0], line)  # type: ignore[index]
        check_hash_spread([pair[0] for pair in pairs], host.meter, line)  # type: ignore[index]
        for pair in pairs:
            out[pair[0]] = pair[1]  # type: ignore[index]
    out.update(kwargs)
    return out


def _b_str(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("str", args, kwargs, line, 0, 1)
    return to_text(args[0], host.meter, line) if args else ""


def _b_int(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("int", args, kwargs, line, 0, 1)
    if not args:
        return 0
    value = args[0]
    t = type(value)
    if t is str:
        if len(value) > host.meter.budget.int_bits // 3 + 10:  # type: ignore[arg-type]
            raise BudgetExceededError("int() of a very long string", line=line)
    elif t not in NUMBER_TYPES:
        raise ProgramRuntimeError(
            f"int() needs a number or a string, not '{t.__name__}'", line=line
        )
    try:
        result = int(value)  # type: ignore[call-overload]
    except (ValueError, OverflowError) as err:
        raise ProgramRuntimeError(f"int(): {err}", line=line) from None
    return check_result(result, host.meter, line)


def _b_float(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("float", args, kwargs, line, 0, 1)
    if not args:
        return 0.0
    value = args[0]
    t = type(value)
    if t is str:
        if len(value) > 400:  # type: ignore[arg-type]
            raise ProgramRuntimeError("float() of a very long string", line=line)
    elif t not in NUMBER_TYPES:
        raise ProgramRuntimeError(
            f"float() needs a number or a string, not '{t.__name__}'", line=line
        )
    try:
        return float(value)  # type: ignore[arg-type]
    except (ValueError, OverflowError) as err:
        raise ProgramRuntimeError(f"float(): {err}", line=line) from None


def _b_bool(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("bool", args, kwargs, line, 0, 1)
    return bool(args[0]) if args else False


def _b_any(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("any", args, kwargs, line, 1, 1)
    return any(materialize(args[0], host.meter, line, "any()"))


def _b_all(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("all", args, kwargs, line, 1, 1)
    return all(materialize(args[0], host.meter, line, "all()"))


def _b_print(host: Host, args: list[object], kwargs: dict[str, object], line: Line) -> object:
    _arity("print", args, kwargs, line, 0, 50, ("sep", "end"))
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
    "dict": _b_dict,
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
def _words(text: str) -> list[str]:
    return text.split()


PYTHON_ONLY_BUILTINS = frozenset(
    _words(
        """
    getattr setattr delattr hasattr type vars dir globals locals open eval exec compile
    __import__ format isinstance issubclass id hash input exit quit help object super
    classmethod staticmethod property iter next map filter chr ord divmod pow repr ascii
    callable memoryview bytes bytearray breakpoint frozenset slice complex bin hex oct aiter
    anext math random os sys Exception BaseException SystemExit
    """
    )
)


# ---------------------------------------------------------------- methods of built-in types

MethodImpl = Callable[[Host, object, list[object], dict[str, object], Line], object]


def _plain(name: str, key_arg: bool = False, searches: bool = False) -> MethodImpl:
    """A method that cannot grow anything much: call it, then bound the result.

    ``key_arg``: the first argument is hashed (dict/set key); ``searches``: it is compared
    with every item (list.index / count / remove).
    """

    def impl(
        host: Host, obj: object, args: list[object], kwargs: dict[str, object], line: Line
    ) -> object:
        if key_arg and args:
            check_key(args[0], line)
        if searches and args:
            comparison_work(host.meter, line, [args[0]], repeat=len(obj))  # type: ignore[arg-type]
        result = getattr(obj, name)(*args, **kwargs)
        t = type(result)
        if t is str:
            host.meter.check_str(len(result), line)
        elif t in CONTAINER_TYPES:
            host.meter.check_len(len(result), line)
        elif name in ("keys", "values", "items"):
            result = list(result)
            host.meter.check_len(len(result), line)
        return result

    return impl


def _str_join(
    host: Host, obj: object, args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    _arity("str.join", args, kwargs, line, 1, 1)
    parts = materialize(args[0], host.meter, line, "join()")
    for p in parts:
        if type(p) is not str:
            raise ProgramRuntimeError(
                f"str.join() needs strings, found '{type_name(p)}' (use str(x) first)", line=line
            )
    sep: str = obj  # type: ignore[assignment]
    host.meter.check_str(sum(map(len, parts)) + len(sep) * max(len(parts) - 1, 0), line)  # type: ignore[arg-type]
    return sep.join(parts)  # type: ignore[arg-type]


def _str_replace(
    host: Host, obj: object, args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    _arity("str.replace", args, kwargs, line, 2, 3)
    s: str = obj  # type: ignore[assignment]
    old, new = args[0], args[1]
    count = args[2] if len(args) > 2 else -1
    if type(old) is not str or type(new) is not str or type(count) not in INT_TYPES:
        raise ProgramRuntimeError(
            "str.replace() needs (old: str, new: str[, count: int])", line=line
        )
    hits = len(s) + 1 if old == "" else s.count(old)
    if count >= 0:  # type: ignore[operator]
        hits = min(hits, count)  # type: ignore[type-var,assignment]
    host.meter.check_str(len(s) + hits * (len(new) - len(old)), line)
    return s.replace(old, new, count)  # type: ignore[arg-type]


def _list_append(
    host: Host, obj: object, args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    _arity("list.append", args, kwargs, line, 1, 1)
    host.meter.check_len(len(obj) + 1, line, added=1)  # type: ignore[arg-type]
    obj.append(args[0])  # type: ignore[attr-defined]
    return None


def _list_insert(
    host: Host, obj: object, args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    _arity("list.insert", args, kwargs, line, 2, 2)
    if type(args[0]) not in INT_TYPES:
        raise ProgramRuntimeError("list.insert() needs an integer index", line=line)
    host.meter.check_len(len(obj) + 1, line, added=1)  # type: ignore[arg-type]
    obj.insert(args[0], args[1])  # type: ignore[attr-defined]
    return None


def _list_extend(
    host: Host, obj: object, args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    _arity("list.extend", args, kwargs, line, 1, 1)
    items = materialize(args[0], host.meter, line)
    host.meter.check_len(len(obj) + len(items), line, added=len(items))  # type: ignore[arg-type]
    obj.extend(items)  # type: ignore[attr-defined]
    return None


def _list_sort(
    host: Host, obj: object, args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    _arity("list.sort", args, kwargs, line, 0, 0, ("key", "reverse"))
    items: list[object] = obj  # type: ignore[assignment]
    items[:] = sort_items(host, list(items), kwargs.get("key"), kwargs.get("reverse", False), line)
    return None


def _dict_update(
    host: Host, obj: object, args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    _arity("dict.update", args, kwargs, line, 0, 1, tuple(kwargs))
    other = _b_dict(host, args, kwargs, line)
    d: dict[object, object] = obj  # type: ignore[assignment]
    host.meter.check_len(len(d) + len(other), line)  # type: ignore[arg-type]
    check_hash_spread([*d, *other], host.meter, line)  # type: ignore[misc]
    d.update(other)  # type: ignore[call-overload]
    return None


def _dict_setdefault(
    host: Host, obj: object, args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    _arity("dict.setdefault", args, kwargs, line, 1, 2)
    check_key(args[0], line)
    d: dict[object, object] = obj  # type: ignore[assignment]
    host.meter.check_len(len(d) + 1, line, added=1)
    return d.setdefault(args[0], args[1] if len(args) > 1 else None)


def _set_add(
    host: Host, obj: object, args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    _arity("set.add", args, kwargs, line, 1, 1)
    check_key(args[0], line)
    host.meter.check_len(len(obj) + 1, line, added=1)  # type: ignore[arg-type]
    obj.add(args[0])  # type: ignore[attr-defined]
    return None


def _set_combine(name: str) -> MethodImpl:
    def impl(
        host: Host, obj: object, args: list[object], kwargs: dict[str, object], line: Line
    ) -> object:
        _arity(f"set.{name}", args, kwargs, line, 0, 10)
        others = [materialize(a, host.meter, line) for a in args]
        host.meter.check_len(len(obj) + sum(map(len, others)), line)  # type: ignore[arg-type]
        for other in others:
            for item in other:
                check_key(item, line)
        check_hash_spread([*obj, *(item for other in others for item in other)], host.meter, line)  # type: ignore[misc]
        return getattr(obj, name)(*others)

    return impl


_STR_PLAIN = tuple(
    _words(
        """
    lower upper strip lstrip rstrip capitalize title casefold swapcase startswith endswith
    find rfind index rindex count isdigit isalpha isalnum isspace islower isupper isnumeric
    isdecimal istitle removeprefix removesuffix partition rpartition split rsplit splitlines
    """
    )
)


def _set_copy(
    host: Host, obj: object, args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    _arity("set.copy", args, kwargs, line, 0, 0)
    check_hash_spread(list(obj), host.meter, line)  # type: ignore[call-overload]
    host.meter.check_len(len(obj), line)  # type: ignore[arg-type]
    return obj.copy()  # type: ignore[attr-defined]


_SET_COMBINE = (
    "union",
    "intersection",
    "difference",
    "symmetric_difference",
    "issubset",
    "issuperset",
    "isdisjoint",
)

METHODS: dict[type, dict[str, MethodImpl]] = {
    str: {
        **{n: _plain(n) for n in _STR_PLAIN},
        "join": _str_join,
        "replace": _str_replace,
    },
    list: {
        **{n: _plain(n) for n in ("pop", "reverse", "copy", "clear")},
        **{n: _plain(n, searches=True) for n in ("remove", "index", "count")},
        "append": _list_append,
        "insert": _list_insert,
        "extend": _list_extend,
        "sort": _list_sort,
    },
    dict: {
        **{n: _plain(n) for n in ("keys", "values", "items", "copy", "clear", "popitem")},
        "get": _plain("get", key_arg=True),
        "pop": _plain("pop", key_arg=True),
        "setdefault": _dict_setdefault,
        "update": _dict_update,
    },
    tuple: {n: _plain(n, searches=True) for n in ("index", "count")},
    set: {
        **{n: _plain(n) for n in ("pop", "clear")},
        "copy": _set_copy,
        **{n: _plain(n, key_arg=True) for n in ("remove", "discard")},
        **{n: _set_combine(n) for n in _SET_COMBINE},
        "add": _set_add,
        "update": _set_combine("update"),
    },
    frozenset: {
        "copy": _set_copy,
        **{n: _set_combine(n) for n in _SET_COMBINE},
    },
}

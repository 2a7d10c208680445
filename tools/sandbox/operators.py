"""Operators of event programs: arithmetic, comparison, ``in``, each bounded before it runs.

``binary``, ``unary`` and ``compare`` check the size of what an operation would build (string
and list repetition, big-integer powers and shifts, set unions, deep comparisons, hash
collisions) against the run's ``Meter`` *before* Python computes it, and turn Python's own
errors into ``ProgramRuntimeError``. Types outside ``OPERAND_TYPES`` take an operator only if
they list its symbol in ``sandbox_operators``.
"""

from __future__ import annotations

import ast
import math
import operator
from collections.abc import Callable, Container, Sized
from typing import Any, TypeAlias, TypeVar, cast

from storyteller.tools.sandbox.boundary import (
    CONTAINER_TYPES,
    OPERAND_TYPES,
    SEQ_TYPES,
    check_key,
    is_hashed,
    is_int,
    is_number,
    type_name,
)
from storyteller.tools.sandbox.budget import SET_ITEM_BYTES, Meter, nested_size
from storyteller.tools.sandbox.errors import (
    BudgetExceededError,
    ForbiddenConstructError,
    Line,
    ProgramRuntimeError,
)

_V = TypeVar("_V")

OperatorFn: TypeAlias = Callable[[Any, Any], object]
"""Python's own operator (``operator.add``...): operand types are checked at run time, and
Python raises ``TypeError`` for a pair it does not support."""

_BINARY: dict[type[ast.operator], tuple[str, OperatorFn]] = {
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
        if type(a) is str and type(b) is str:
            meter.check_str(len(a) + len(b), line)
        elif (type(a) is list and type(b) is list) or (type(a) is tuple and type(b) is tuple):
            meter.check_len(len(a) + len(b), line)
    elif symbol == "*":
        if ta in SEQ_TYPES and is_int(b):
            _check_repeat(a, b, meter, line)
        elif tb in SEQ_TYPES and is_int(a):
            _check_repeat(b, a, meter, line)
        elif is_int(a) and is_int(b):
            meter.check_bits(a.bit_length() + b.bit_length(), line)
    elif symbol == "**":
        if is_int(a) and is_int(b) and b > 1 and abs(a) > 1:
            meter.check_bits(a.bit_length() * b, line)
    elif symbol == "<<":
        if is_int(a) and is_int(b) and b > 0 and a != 0:
            meter.check_bits(a.bit_length() + b, line)
    elif symbol == "%":
        if ta is str:
            raise ForbiddenConstructError(
                "'%' string formatting is not allowed; use an f-string", line=line
            )
    elif symbol in ("|", "&", "^", "-") and is_hashed(a) and is_hashed(b):
        meter.check_len(len(a) + len(b), line, item_bytes=SET_ITEM_BYTES)
        check_hash_spread([*a, *b], meter, line)
    try:
        result = fn(a, b)
    except ZeroDivisionError:
        raise ProgramRuntimeError(f"division by zero in '{symbol}'", line=line) from None
    except (TypeError, ValueError, ArithmeticError) as err:
        raise ProgramRuntimeError(f"'{symbol}' failed: {err}", line=line) from None
    return check_result(result, meter, line)


def _check_repeat(seq: object, n: int, meter: Meter, line: Line) -> None:
    """Before ``seq * n`` (``seq`` a str, list or tuple)."""
    size = len(cast("Sized", seq)) * max(int(n), 0)
    if type(seq) is str:
        meter.check_str(size, line)
    else:
        meter.check_len(size, line)


def check_result(value: _V, meter: Meter, line: Line) -> _V:
    """Post-check of arithmetic results: integer size (charged in bytes), no complex numbers."""
    v: object = value
    if type(v) is int:
        meter.made_int(v, line)
    elif type(v) is complex:
        raise ProgramRuntimeError(
            "the result is a complex number (e.g. a negative number to a fractional power)",
            line=line,
        )
    return value


def unary(op: ast.unaryop, v: object, meter: Meter, line: Line) -> object:
    if isinstance(op, ast.Not):
        return not v
    if isinstance(op, ast.Invert):
        if is_int(v):
            return check_result(~v, meter, line)
    elif is_number(v):
        return check_result(-v if isinstance(op, ast.USub) else +v, meter, line)
    symbol = _UNARY_SYMBOLS.get(type(op), "?")
    raise ProgramRuntimeError(f"bad operand type for unary {symbol}: '{type_name(v)}'", line=line)


_UNARY_SYMBOLS: dict[type[ast.unaryop], str] = {ast.Invert: "~", ast.USub: "-", ast.UAdd: "+"}


_COMPARE: dict[type[ast.cmpop], tuple[str, OperatorFn]] = {
    ast.Eq: ("==", operator.eq),
    ast.NotEq: ("!=", operator.ne),
    ast.Lt: ("<", operator.lt),
    ast.LtE: ("<=", operator.le),
    ast.Gt: (">", operator.gt),
    ast.GtE: (">=", operator.ge),
    ast.Is: ("is", operator.is_),
    ast.IsNot: ("is not", operator.is_not),
}


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
        if is_hashed(a) and is_hashed(b):
            check_hash_spread([*a, *b], meter, line)
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
    elif type(container) is list or type(container) is tuple:
        meter.work(len(container), line)
        if type(item) in CONTAINER_TYPES:
            comparison_work(meter, line, [item], repeat=len(container))
    elif type(container) is range:
        return range_contains(container, item)
    else:
        raise ProgramRuntimeError(
            f"'in' needs a list, tuple, dict, set, string or range, not '{t.__name__}'", line=line
        )
    return item in cast("Container[object]", container)  # one of the types checked above


def range_contains(r: range, item: object) -> bool:
    """``item in r`` in constant time.

    CPython answers ``in range`` arithmetically only for ints; any other item (``0.5 in
    range(10**15)``, ``'a' in range(10**12)``) makes it compare the item with every number
    of the range, in C, where no budget can stop it. A float is in the range if it is a
    whole number that is; nothing else equals an int.
    """
    if type(item) is int or type(item) is bool:
        return item in r
    if type(item) is float:
        return math.isfinite(item) and item.is_integer() and int(item) in r
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

"""Budgets and size guards of the event-program sandbox.

A ``Budget`` bounds everything an event program can spend: interpreter steps, loop
iterations, the size of every string / int / container it builds (checked *before* the
value is computed), the bytes it allocates over the run, call depth, time (the
injected clock) and printed lines; and what the static check may spend on a program (``check_*``). ``Meter``
counts one run against one budget and raises ``BudgetExceededError`` the moment a limit is
passed; its clock is injected (the runner passes one in), so this module reads no clock of
its own.

Memory is charged in bytes as CPython 3.11+ on 64 bits stores values (``str_bytes``,
``int_bytes``, ``container_bytes``): every string, int and container a program creates is
charged when it is created and never refunded, so the total bounds the peak. A string is
charged one byte per character (CPython's ASCII layout); a wider string costs up to four
times that, which ``str_len`` bounds per string and the worker's address-space limit bounds
overall.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass
from typing import cast

from storyteller.tools.errors import SUGGESTION_CHARS, did_you_mean
from storyteller.tools.sandbox.errors import BudgetExceededError, Line


@dataclass(frozen=True)
class Budget:
    """Limits of one program run. Sizes are counts (characters, items, bits); time is seconds."""

    steps: int = 200_000
    """Interpreter steps (one per evaluated expression or statement node)."""
    loop_iterations: int = 20_000
    """Iterations summed over every loop and comprehension of the run."""
    str_len: int = 20_000
    """Characters in any one string."""
    int_bits: int = 4096
    """Bits in any one integer."""
    container_len: int = 20_000
    """Items in any one list / tuple / dict / set (and any iterable consumed whole)."""
    memory_bytes: int = 64 * 2**20
    """Bytes of the strings, ints and containers created over the whole run (never refunded,
    so this also stops quadratic growth)."""
    recursion_depth: int = 40
    """Nested calls of program-defined functions."""
    wall_time: float = 1.0
    """Seconds of the injected clock for the whole run, tool calls included (by default the
    thread's CPU time: see ``storyteller.tools.sandbox.runner``; the name is kept for the budgets already
    written)."""
    output_lines: int = 200
    """Lines the program may print."""
    source_chars: int = 20_000
    """Characters of program text."""
    nesting_depth: int = 100
    """Depth of the syntax tree (nested expressions and blocks)."""
    format_width: int = 100
    """Largest width or precision in an f-string format spec."""
    check_nodes: int = 20_000
    """Syntax-tree nodes the static check visits."""
    check_names: int = 2_000
    """Distinct names (variables, functions, parameters, attributes) in the program text."""
    check_time: float = 1.0
    """Seconds of the injected clock the static check may take."""
    suggestion_candidates: int = 200
    """Names a "did you mean" suggestion compares against (the rest are not considered)."""


STR_BYTES = 49
"""Bytes of an empty ``str`` object; each ASCII character adds one."""
CONTAINER_BYTES = 56
"""Bytes of an empty list / tuple object (dicts and sets are larger: see ``*_ITEM_BYTES``)."""
REF_BYTES = 8
"""Bytes of one item slot of a list or tuple (a pointer)."""
DICT_ITEM_BYTES = 72
"""Bytes per dict entry (hash table slot, index and key/value pointers, over-allocation)."""
SET_ITEM_BYTES = 40
"""Bytes per set item (hash table slot with over-allocation)."""


def int_bytes(bits: int) -> int:
    """Bytes of an int of ``bits`` bits (28 bytes plus 4 per 30-bit digit)."""
    return 28 + 4 * max((bits - 1) // 30, 0)


def str_bytes(n: int) -> int:
    """Bytes of an ASCII string of ``n`` characters."""
    return STR_BYTES + n


def container_bytes(n: int, item_bytes: int = REF_BYTES) -> int:
    """Bytes of a new container of ``n`` items of ``item_bytes`` each."""
    return CONTAINER_BYTES + n * item_bytes


class Meter:
    """Counts one run against a ``Budget``; every ``charge_*`` raises ``BudgetExceededError``."""

    __slots__ = ("budget", "clock", "depth", "loops", "memory", "output", "start", "steps")

    def __init__(self, budget: Budget, clock: Callable[[], float]) -> None:
        self.budget = budget
        self.clock = clock
        self.start = clock()
        self.steps = 0
        self.loops = 0
        self.memory = 0
        """Bytes charged so far."""
        self.depth = 0
        self.output: list[str] = []

    def tick(self, line: Line) -> None:
        """Called every 64 steps (and after tool calls): checks steps and time (the injected clock)."""
        if self.steps > self.budget.steps:
            raise BudgetExceededError(
                f"the program took more than {self.budget.steps} steps; "
                "avoid long loops and large computations",
                line=line,
            )
        self.check_time(line)

    def check_time(self, line: Line) -> None:
        elapsed = self.clock() - self.start
        if elapsed > self.budget.wall_time:
            raise BudgetExceededError(
                f"the program ran longer than {self.budget.wall_time:g} s; "
                "avoid long loops and large computations",
                line=line,
            )

    def work(self, n: int, line: Line) -> None:
        """Charge ``n`` units of C-level work (one step per 8 units) done in a single operation."""
        self.steps += n >> 3
        if self.steps > self.budget.steps:
            self.tick(line)

    def loop(self, line: Line) -> None:
        self.loops += 1
        if self.loops > self.budget.loop_iterations:
            raise BudgetExceededError(
                f"loops ran more than {self.budget.loop_iterations} iterations in total; "
                "event programs only need a few short loops",
                line=line,
            )

    def charge(self, nbytes: int, line: Line) -> None:
        """Charge ``nbytes`` of memory the program is about to create."""
        self.memory += nbytes
        if self.memory > self.budget.memory_bytes:
            raise BudgetExceededError(
                f"the program built more than {self.budget.memory_bytes // 2**20} MiB of "
                "values in total; event programs only need a few small lists",
                line=line,
            )

    def check_str(self, n: int, line: Line) -> None:
        """Before building a string of ``n`` characters."""
        if n > self.budget.str_len:
            raise BudgetExceededError(
                f"a string would have {n} characters (limit {self.budget.str_len})", line=line
            )
        self.charge(str_bytes(n), line)

    def check_len(
        self,
        n: int,
        line: Line,
        *,
        added: int | None = None,
        what: str = "",
        item_bytes: int = REF_BYTES,
    ) -> None:
        """Before building (or consuming whole) a container of ``n`` items.

        ``added`` is how many items are new in an existing container (default: a new
        container of ``n``); ``what`` names a consumer (e.g. ``"sum()"``) for the message;
        ``item_bytes`` is the cost of one item's slot.
        """
        if n > self.budget.container_len:
            subject = (
                f"{what} would go through" if what else "a list, tuple, dict or set would have"
            )
            raise BudgetExceededError(
                f"{subject} {n} items (limit {self.budget.container_len})", line=line
            )
        self.charge(container_bytes(n, item_bytes) if added is None else added * item_bytes, line)

    def check_bits(self, bits: int, line: Line) -> None:
        """Before building an integer of ``bits`` bits (``made_int`` charges it once built)."""
        if bits > self.budget.int_bits:
            raise BudgetExceededError(
                f"an integer would have about {bits} bits (limit {self.budget.int_bits})",
                line=line,
            )

    def made_int(self, value: int, line: Line) -> None:
        """An integer was just built: check its size and charge its bytes."""
        bits = value.bit_length()
        self.check_bits(bits, line)
        self.charge(int_bytes(bits), line)

    def suggest(self, word: str, candidates: Iterable[str], line: Line, n: int = 3) -> str:
        """``did_you_mean`` on at most ``suggestion_candidates`` candidates, charged as work."""
        limit = self.budget.suggestion_candidates
        self.work(limit * SUGGESTION_CHARS * 8, line)
        return did_you_mean(word, candidates, n=n, limit=limit)

    def print_line(self, text: str, line: Line) -> None:
        if len(self.output) >= self.budget.output_lines:
            raise BudgetExceededError(
                f"the program printed more than {self.budget.output_lines} lines", line=line
            )
        self.output.append(text)


_NESTED: frozenset[type] = frozenset({list, tuple, dict, set, frozenset})


def nested_size(value: object, cap: int) -> int:
    """Items in a nested list/tuple/dict/set value (each string counts as one item).

    Counts items as they are pushed, so the walk and its stack stay within ``cap`` plus one
    container's length; returns a number above ``cap`` as soon as it passes it. Flat
    containers are not walked item by item (their item types are collected in C).
    """
    count = 1
    stack = [value]
    while stack:
        v = stack.pop()
        t = type(v)
        if type(v) is dict:
            count += 2 * len(v)
            if count > cap:
                return count
            if not _NESTED.isdisjoint(set(map(type, v.values()))):
                stack.extend(v.values())
            if not _NESTED.isdisjoint(set(map(type, v.keys()))):
                stack.extend(v.keys())
        elif t in _NESTED:
            items = cast("Collection[object]", v)  # t is list, tuple, set or frozenset
            count += len(items)
            if count > cap:
                return count
            if not _NESTED.isdisjoint(set(map(type, items))):
                stack.extend(items)
    return count

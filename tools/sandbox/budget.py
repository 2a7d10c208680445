"""Budgets and size guards of the event-program sandbox.

A ``Budget`` bounds everything an event program can spend: interpreter steps, loop
iterations, the size of every string / int / container it builds (checked *before* the
value is computed), the total number of items it allocates, call depth, wall time and
printed lines. ``Meter`` counts one run against one budget and raises
``BudgetExceededError`` the moment a limit is passed; its clock is injected (the runner
passes one in), so this module reads no clock of its own.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass
from typing import cast

from tools.sandbox.errors import BudgetExceededError, Line


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
    allocated_items: int = 2_000_000
    """Items plus characters created over the whole run (stops quadratic growth)."""
    recursion_depth: int = 40
    """Nested calls of program-defined functions."""
    wall_time: float = 1.0
    """Seconds of the injected clock for the whole run, tool calls included."""
    output_lines: int = 200
    """Lines the program may print."""
    source_chars: int = 20_000
    """Characters of program text."""
    nesting_depth: int = 100
    """Depth of the syntax tree (nested expressions and blocks)."""
    format_width: int = 100
    """Largest width or precision in an f-string format spec."""


class Meter:
    """Counts one run against a ``Budget``; every ``charge_*`` raises ``BudgetExceededError``."""

    __slots__ = ("allocated", "budget", "clock", "depth", "loops", "output", "start", "steps")

    def __init__(self, budget: Budget, clock: Callable[[], float]) -> None:
        self.budget = budget
        self.clock = clock
        self.start = clock()
        self.steps = 0
        self.loops = 0
        self.allocated = 0
        self.depth = 0
        self.output: list[str] = []

    def tick(self, line: Line) -> None:
        """Called every 64 steps (and after tool calls): checks steps and wall time."""
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

    def allocate(self, n: int, line: Line) -> None:
        self.allocated += n
        if self.allocated > self.budget.allocated_items:
            raise BudgetExceededError(
                f"the program built more than {self.budget.allocated_items} items in total",
                line=line,
            )

    def check_str(self, n: int, line: Line) -> None:
        """Before building a string of ``n`` characters."""
        if n > self.budget.str_len:
            raise BudgetExceededError(
                f"a string would have {n} characters (limit {self.budget.str_len})", line=line
            )
        self.allocate(n, line)

    def check_len(self, n: int, line: Line, *, added: int | None = None, what: str = "") -> None:
        """Before building (or consuming whole) a container of ``n`` items.

        ``added`` is how many items are new (default ``n``); ``what`` names a consumer
        (e.g. ``"sum()"``) for the message.
        """
        if n > self.budget.container_len:
            subject = (
                f"{what} would go through" if what else "a list, tuple, dict or set would have"
            )
            raise BudgetExceededError(
                f"{subject} {n} items (limit {self.budget.container_len})", line=line
            )
        self.allocate(n if added is None else added, line)

    def check_bits(self, bits: int, line: Line) -> None:
        """Before (or right after) building an integer of ``bits`` bits."""
        if bits > self.budget.int_bits:
            raise BudgetExceededError(
                f"an integer would have about {bits} bits (limit {self.budget.int_bits})",
                line=line,
            )

    def print_line(self, text: str, line: Line) -> None:
        if len(self.output) >= self.budget.output_lines:
            raise BudgetExceededError(
                f"the program printed more than {self.budget.output_lines} lines", line=line
            )
        self.output.append(text)


def text_len_bound(value: object, limit: int) -> int:
    """Upper bound of ``len(repr(value))``, walking containers without recursion.

    Stops as soon as the bound passes ``limit`` (each visited item adds at least one
    character, so the walk visits at most ``limit`` items). Unknown objects are rendered
    with their own ``repr`` (tool-defined types only).
    """
    total = 0
    stack: list[object] = [value]
    while stack:
        v = stack.pop()
        t = type(v)
        if type(v) is str:
            total += 2 * len(v) + 2 if v.isascii() and v.isprintable() else 10 * len(v) + 2
        elif type(v) is int:
            total += int(v.bit_length() * 0.30103) + 3
        elif t is bool or v is None:
            total += 5
        elif t is float:
            total += 25
        elif type(v) is list or type(v) is tuple or type(v) is set or type(v) is frozenset:
            total += 12 + 2 * len(v)
            stack.extend(v)
        elif type(v) is dict:
            total += 2 + 4 * len(v)
            stack.extend(v.keys())
            stack.extend(v.values())
        elif type(v) is range:
            stack.extend((v.start, v.stop, v.step))
            total += 16
        else:
            total += len(repr(v))
        if total > limit:
            return total
    return total


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

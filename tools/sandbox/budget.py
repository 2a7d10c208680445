"""Budgets, failure types and size guards of the event-program sandbox.

A ``Budget`` bounds everything an event program can spend: interpreter steps, loop
iterations, the size of every string / int / container it builds (checked *before* the
value is computed), the total number of items it allocates, call depth, wall time and
printed lines. ``Meter`` counts one run against one budget. The error classes are the
sandbox's own ``EventProgramError`` subclasses (re-exported by ``tools.sandbox.interpreter``); each
``feedback`` is one sentence fit to show the LLM, prefixed with the program line.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from tools.errors import EventProgramError


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


class ProgramSyntaxError(EventProgramError):
    """The program text is not valid Python (or not text)."""

    kind = "syntax_error"


class ForbiddenConstructError(EventProgramError):
    """The program uses something event programs may not use (imports, classes, `_` names...)."""

    kind = "forbidden_construct"


class BudgetExceededError(EventProgramError):
    """The program ran too long or built something too large."""

    kind = "budget_exceeded"


class ProgramRuntimeError(EventProgramError):
    """The program failed while running (bad operands, index out of range, a tool misused...)."""

    kind = "runtime_error"


class UnknownNameError(ProgramRuntimeError):
    """The program uses a name that is defined nowhere."""

    kind = "unknown_name"


class MissingEntryError(EventProgramError):
    """The program does not define the entry function (``parse_event``)."""

    kind = "missing_entry"


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

    def tick(self, line: int | None) -> None:
        """Called every 64 steps (and after tool calls): checks steps and wall time."""
        if self.steps > self.budget.steps:
            raise BudgetExceededError(
                f"the program took more than {self.budget.steps} steps; "
                "avoid long loops and large computations",
                line=line,
            )
        self.check_time(line)

    def check_time(self, line: int | None) -> None:
        elapsed = self.clock() - self.start
        if elapsed > self.budget.wall_time:
            raise BudgetExceededError(
                f"the program ran longer than {self.budget.wall_time:g} s; "
                "avoid long loops and large computations",
                line=line,
            )

    def work(self, n: int, line: int | None) -> None:
        """Charge ``n`` units of C-level work (one step per 8 units) done in a single operation."""
        self.steps += n >> 3
        if self.steps > self.budget.steps:
            self.tick(line)

    def loop(self, line: int | None) -> None:
        self.loops += 1
        if self.loops > self.budget.loop_iterations:
            raise BudgetExceededError(
                f"loops ran more than {self.budget.loop_iterations} iterations in total; "
                "event programs only need a few short loops",
                line=line,
            )

    def allocate(self, n: int, line: int | None) -> None:
        self.allocated += n
        if self.allocated > self.budget.allocated_items:
            raise BudgetExceededError(
                f"the program built more than {self.budget.allocated_items} items in total",
                line=line,
            )

    def check_str(self, n: int, line: int | None) -> None:
        """Before building a string of ``n`` characters."""
        if n > self.budget.str_len:
            raise BudgetExceededError(
                f"a string would have {n} characters (limit {self.budget.str_len})", line=line
            )
        self.allocate(n, line)

    def check_len(
        self, n: int, line: int | None, *, added: int | None = None, what: str = ""
    ) -> None:
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

    def check_bits(self, bits: int, line: int | None) -> None:
        """Before (or right after) building an integer of ``bits`` bits."""
        if bits > self.budget.int_bits:
            raise BudgetExceededError(
                f"an integer would have about {bits} bits (limit {self.budget.int_bits})",
                line=line,
            )

    def print_line(self, text: str, line: int | None) -> None:
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
        if t is str:
            s: str = v  # type: ignore[assignment]
            total += 2 * len(s) + 2 if s.isascii() and s.isprintable() else 10 * len(s) + 2
        elif t is int:
            total += int(v.bit_length() * 0.30103) + 3  # type: ignore[attr-defined]
        elif t is bool or v is None:
            total += 5
        elif t is float:
            total += 25
        elif t is list or t is tuple or t is set or t is frozenset:
            total += 12 + 2 * len(v)  # type: ignore[arg-type]
            stack.extend(v)  # type: ignore[arg-type]
        elif t is dict:
            d: dict[object, object] = v  # type: ignore[assignment]
            total += 2 + 4 * len(d)
            stack.extend(d.keys())
            stack.extend(d.values())
        elif t is range:
            r: range = v  # type: ignore[assignment]
            stack.extend((r.start, r.stop, r.step))
            total += 16
        else:
            total += len(repr(v))
        if total > limit:
            return total
    return total


_NESTED = frozenset({list, tuple, dict, set, frozenset})


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
        if t is dict:
            d: dict[object, object] = v  # type: ignore[assignment]
            count += 2 * len(d)
            if count > cap:
                return count
            if not _NESTED.isdisjoint(set(map(type, d.values()))):
                stack.extend(d.values())
            if not _NESTED.isdisjoint(set(map(type, d.keys()))):
                stack.extend(d.keys())
        elif t in _NESTED:
            count += len(v)  # type: ignore[arg-type]
            if count > cap:
                return count
            if not _NESTED.isdisjoint(set(map(type, v))):  # type: ignore[call-overload]
                stack.extend(v)  # type: ignore[arg-type]
    return count

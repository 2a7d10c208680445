"""The public entry of the sandbox: check a program, then run its entry function.

``run_program`` (and ``execute``, which returns only the result) raises only
``EventProgramError`` subclasses: ``ToolError`` from a tool unchanged (with its line), the
sandbox's own errors from ``storyteller.tools.sandbox.errors``, and anything else that escapes (even
``SystemExit``) as ``ProgramRuntimeError``; running out of Python stack or memory is
``BudgetExceededError``. The clock that bounds a run's time is a parameter; its default is the
running thread's CPU time (``time.thread_time``), so whether a program runs out of time depends
much less on how busy the machine is than with a wall clock (a replay under load should give the
recording's verdict). A program cannot wait (no I/O, no sleep), so its CPU time is about its wall
time on an idle machine. Limits: CPU time still grows a little when cores are shared (caches);
it counts this thread only (no tool runs work in other threads today); and a wall-clock bound,
where one is needed, belongs to the caller (the worker's parent kills a worker that used
``storyteller.orchestrator.worker_deadline.RUN_SECONDS`` of CPU time on one program, or that did
not answer within its ``WALL_SECONDS``, a backstop six times longer, so load alone turns a
program that passed into a time-out only when its CPU time, stretched by the wait for a core,
passes that backstop).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from storyteller.tools.errors import EventProgramError
from storyteller.tools.sandbox.budget import Budget
from storyteller.tools.sandbox.checker import check_program
from storyteller.tools.sandbox.errors import BudgetExceededError, ProgramRuntimeError, describe
from storyteller.tools.sandbox.interpreter import Interpreter

DEFAULT_CLOCK: Callable[[], float] = time.thread_time
"""The clock a run uses when its caller injects none (the only clock the sandbox names)."""


@dataclass(frozen=True)
class ProgramRun:
    """What one successful run produced: the entry's return value and the printed lines."""

    result: object
    output: tuple[str, ...]
    steps: int


def execute(
    source: str,
    namespace: Mapping[str, object],
    *,
    entry: str = "parse_event",
    budget: Budget | None = None,
    clock: Callable[[], float] = DEFAULT_CLOCK,
) -> object:
    """Run ``source``'s module body, then ``entry()``; return what ``entry`` returns.

    Raises only ``EventProgramError`` subclasses (``ToolError`` from tools unchanged).
    """
    return run_program(source, namespace, entry=entry, budget=budget, clock=clock).result


def run_program(
    source: str,
    namespace: Mapping[str, object],
    *,
    entry: str = "parse_event",
    budget: Budget | None = None,
    clock: Callable[[], float] = DEFAULT_CLOCK,
) -> ProgramRun:
    """Like ``execute`` but also returns the captured ``print`` output and the step count."""
    budget = budget or Budget()
    interpreter: Interpreter | None = None
    try:
        tree, local_names = check_program(source, namespace, budget=budget, clock=clock)
        interpreter = Interpreter(namespace, budget, clock, local_names)
        result = interpreter.run(tree, entry)
        return ProgramRun(result, tuple(interpreter.meter.output), interpreter.meter.steps)
    except EventProgramError as err:
        if interpreter is not None:
            err.steps = interpreter.meter.steps
        raise
    except (RecursionError, MemoryError):
        raise BudgetExceededError(
            "the program nests or recurses too deeply, or uses too much memory"
        ) from None
    except (Exception, SystemExit, KeyboardInterrupt) as err:  # never let anything else out
        raise ProgramRuntimeError(f"the program failed: {describe(err)}") from None

"""How long the parent waits for the event-program worker's answer: CPU time judged, wall clock as a backstop.

:func:`await_answer` returns once the worker's answer can be read, and raises
``BudgetExceededError`` (the worker is then killed by the caller) in two cases only:

- the worker process used more than ``run_seconds`` of CPU time (user + system, all its
  threads) since the request was sent: the program ran too long. CPU time, not wall-clock
  time, because on a shared machine a program can wait for a core for longer than it runs; a
  wall-clock limit then stops a legitimate program because of the machine's load, and a replay
  under load gives another verdict than its recording. CPU time is what the program actually
  ran, whatever else runs beside it (it grows a little when cores are shared: caches).
- ``wall_seconds`` of wall-clock time passed (several times ``run_seconds``): a backstop, so
  that a worker that blocks or is never scheduled (it uses no CPU) still ends.

Why the process's CPU time from ``/proc/<pid>/stat`` and not wall time minus the time spent
waiting for a core (``/proc/<pid>/schedstat``): ``stat`` is on every Linux (``schedstat`` needs
a kernel option), its count is the same one ``RLIMIT_CPU`` in the worker uses, and it does not
depend on how the scheduler accounts throttled (cgroup quota) or stolen time. Where it cannot
be read (not Linux, or ``/proc`` hidden) the wall time so far stands in for the CPU time, which
is the old wall-clock limit of ``run_seconds``.

The parent wakes only when the limit could have been reached: after ``run_seconds`` minus the
CPU time used so far (a single thread cannot use CPU time faster than wall time), never more
often than every :data:`MIN_WAIT_SECONDS`. The clocks and the wait are parameters, so the rules
are tested without a process or a real second.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

from storyteller.tools.sandbox import BudgetExceededError

RUN_SECONDS = 5.0
"""CPU seconds the worker may use on one program (request and answer included) before the
parent kills it."""
WALL_SECONDS = 30.0
"""Wall-clock seconds the parent waits for one answer at most, whatever the CPU time (a
backstop for a worker that blocks or is not scheduled)."""
MIN_WAIT_SECONDS = 0.05
"""Shortest wait between two looks at the worker's CPU time (seconds)."""
_TICKS_PER_SECOND = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def process_cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds of process ``pid`` (all its threads) from ``/proc/<pid>/stat``,
    or None where that cannot be read."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text(encoding="ascii", errors="replace")
    except OSError:
        return None
    fields = text[text.rfind(")") + 2 :].split()  # after "pid (comm) ": the comm may hold spaces
    try:
        return (int(fields[11]) + int(fields[12])) / _TICKS_PER_SECOND  # utime, stime (fields 14, 15)
    except (IndexError, ValueError):
        return None


def await_answer(
    ready: Callable[[float], bool],
    cpu_seconds: Callable[[], float | None],
    *,
    run_seconds: float = RUN_SECONDS,
    wall_seconds: float = WALL_SECONDS,
    wall_clock: Callable[[], float] = time.monotonic,
) -> None:
    """Wait until ``ready(timeout)`` (waits up to ``timeout`` seconds, True once the answer can
    be read) is True; raise ``BudgetExceededError`` when the worker used more than
    ``run_seconds`` of ``cpu_seconds()`` (its CPU time so far, None when unknown: the wall time
    then counts) or ``wall_seconds`` of ``wall_clock`` passed, both counted from this call."""
    start_wall, start_cpu = wall_clock(), cpu_seconds()
    wait = min(run_seconds, wall_seconds)
    while not ready(wait):
        elapsed = wall_clock() - start_wall
        now_cpu = cpu_seconds()
        used = elapsed if start_cpu is None or now_cpu is None else now_cpu - start_cpu
        if used >= run_seconds:
            raise BudgetExceededError(f"the program ran for more than {run_seconds:g} s (CPU time) and was stopped")
        if elapsed >= wall_seconds:
            raise BudgetExceededError(
                f"the program's worker did not answer within {wall_seconds:g} s and was stopped"
            )
        wait = min(max(run_seconds - used, MIN_WAIT_SECONDS), wall_seconds - elapsed)

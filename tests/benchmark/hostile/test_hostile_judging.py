"""The hostile-inputs harness judges time robustly on a busy machine without letting a hang
through (issue 22): the time judged is wall-clock less the time the command's main thread waited
for a CPU, so the same command is judged the same at load 0 and at load 8, while a command that
sleeps or blocks (no CPU wanted, none waited for) is judged on its whole wall-clock time.

No clock is read: the measurements are given.
"""

from __future__ import annotations

import os

from storyteller.benchmark.hostile.harness import Spec
from storyteller.benchmark.hostile.judging import Run, judge, run_queue_delay

LIMIT = 8.0  # a clean command of 2 s + the harness's 6 s


def _run(seconds: float, queued: float, code: int | None = 0) -> Run:
    return Run(code, seconds, queued, cpu=2.0, rss=100 << 20, stdout="", stderr="")


def _spec() -> Spec:
    return Spec(["scene", "inspect", "x.json"], "scene inspect", "either")


def test_time_waiting_for_a_cpu_on_a_busy_machine_is_not_judged() -> None:
    busy = _run(seconds=20.0, queued=15.0)  # 5 s of its own, 15 s behind other processes
    assert busy.judged == 5.0
    assert judge(_spec(), busy, LIMIT) == []


def test_the_same_wall_time_spent_sleeping_or_blocked_fails() -> None:
    problems = judge(_spec(), _run(seconds=20.0, queued=0.0), LIMIT)
    assert problems == ["20.0 s > 8.0 s (wall 20.0 s, 0.0 s waiting for a CPU)"]
    assert judge(_spec(), _run(seconds=20.0, queued=11.0), LIMIT) != []  # 9 s of its own


def test_a_killed_command_fails() -> None:
    assert judge(_spec(), _run(seconds=9.0, queued=0.5, code=None), LIMIT) == ["killed after 8 s"]


def test_the_run_queue_delay_is_read_for_a_live_thread_and_none_for_a_missing_one() -> None:
    delay = run_queue_delay(os.getpid())
    assert delay is not None and delay >= 0.0  # Linux with schedstat (the harness's machine)
    assert run_queue_delay(2**22 + 1) is None  # above the largest pid Linux hands out

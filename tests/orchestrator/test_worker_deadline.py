"""The parent's limit on one program judges the worker's CPU time, with a wall-clock backstop.

The clocks and the wait are injected (:class:`FakeWorker`): no test sleeps or asserts a time.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import pytest

from storyteller.orchestrator.worker_deadline import await_answer, process_cpu_seconds
from storyteller.tools.sandbox import BudgetExceededError


@dataclass
class FakeWorker:
    """A worker that gets ``share`` of a core (CPU seconds per wall second) and answers once it
    has used ``answer_after`` CPU seconds (None: never). ``ready`` advances the fake wall clock."""

    share: float
    answer_after: float | None
    wall: float = 0.0
    cpu: float = 0.0
    cpu_known: bool = True
    waits: int = 0

    def ready(self, timeout: float) -> bool:
        self.waits += 1
        if self.answer_after is not None and self.share > 0:
            needed = (self.answer_after - self.cpu) / self.share
            if needed <= timeout:
                self.wall += needed
                self.cpu = self.answer_after
                return True
        self.wall += timeout
        self.cpu += timeout * self.share
        return False

    def cpu_seconds(self) -> float | None:
        return self.cpu if self.cpu_known else None

    def wait(self, **limits: float) -> None:
        await_answer(self.ready, self.cpu_seconds, wall_clock=lambda: self.wall, **limits)


def test_a_program_that_waited_for_a_core_is_not_stopped() -> None:
    """On a loaded machine (a tenth of a core) a program of 2 CPU seconds answers after 20 wall
    seconds: past the old 5 s wall-clock limit, within 5 s of CPU time and the backstop."""
    worker = FakeWorker(share=0.1, answer_after=2.0)
    worker.wait(run_seconds=5.0, wall_seconds=30.0)
    assert worker.wall > 5.0 and worker.cpu == 2.0


def test_the_same_wait_judged_by_wall_time_is_stopped() -> None:
    """Where the CPU time cannot be read, the wall time stands in for it: the old limit."""
    worker = FakeWorker(share=0.1, answer_after=2.0, cpu_known=False)
    with pytest.raises(BudgetExceededError, match="more than 5 s"):
        worker.wait(run_seconds=5.0, wall_seconds=30.0)


def test_a_cpu_bound_endless_program_is_stopped_at_its_cpu_time() -> None:
    worker = FakeWorker(share=1.0, answer_after=None)
    with pytest.raises(BudgetExceededError, match=r"more than 5 s \(CPU time\) and was stopped"):
        worker.wait(run_seconds=5.0, wall_seconds=30.0)
    assert worker.cpu >= 5.0 and worker.wall < 30.0
    assert worker.waits == 1  # a whole core: the first look finds the limit used up


def test_a_starved_endless_program_is_stopped_at_its_cpu_time_too() -> None:
    """Half a core: the limit is reached later in wall time, and the parent looks again only
    when it could have been reached (a few wake-ups, not a busy poll)."""
    worker = FakeWorker(share=0.5, answer_after=None)
    with pytest.raises(BudgetExceededError, match="CPU time"):
        worker.wait(run_seconds=5.0, wall_seconds=30.0)
    assert worker.cpu >= 5.0 and worker.waits < 20


def test_a_worker_that_uses_no_cpu_ends_at_the_wall_clock_backstop() -> None:
    worker = FakeWorker(share=0.0, answer_after=None)
    with pytest.raises(BudgetExceededError, match="did not answer within 30 s and was stopped"):
        worker.wait(run_seconds=5.0, wall_seconds=30.0)
    assert worker.wall >= 30.0


def test_a_quick_answer_is_one_wait() -> None:
    worker = FakeWorker(share=1.0, answer_after=0.01)
    worker.wait(run_seconds=5.0, wall_seconds=30.0)
    assert worker.waits == 1


@pytest.mark.skipif(not os.path.exists("/proc/self/stat"), reason="no /proc (not Linux)")
def test_process_cpu_seconds_reads_the_kernel_count() -> None:
    """The count ``os.times`` reports for this process (same kernel counters, in clock ticks)."""
    before = os.times()
    seconds = process_cpu_seconds(os.getpid())
    after = os.times()
    assert seconds is not None
    assert before.user + before.system - 0.05 <= seconds <= after.user + after.system + 0.05


def test_process_cpu_seconds_of_no_process_is_none() -> None:
    assert process_cpu_seconds(-1) is None

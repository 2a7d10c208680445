"""Progress of a running sweep on stderr: a rich bar on a terminal, plain lines otherwise.

Both show runs done / total, the pass rate so far and an ETA from this sitting's pace (runs
finished in an earlier sitting count as done but not towards the pace). The clock is
injectable; nothing here reaches the result files.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from typing import IO, Any

from storyteller.benchmark.sweep.results import RunResult
from storyteller.orchestrator.safe_text import plain
from storyteller.orchestrator.terminal import say


class _Tally:
    def __init__(self, clock: Callable[[], float]) -> None:
        self.clock = clock
        self.total = self.done = self.passed = self.fresh = 0
        self.started = clock()

    def start(self, total: int, done: Sequence[RunResult]) -> None:
        self.total, self.done = total, len(done)
        self.passed = sum(r.verdict == "pass" for r in done)
        self.started = self.clock()

    def advance(self, result: RunResult) -> None:
        self.done += 1
        self.fresh += 1
        self.passed += result.verdict == "pass"

    @property
    def pass_rate(self) -> float:
        return self.passed / self.done if self.done else 0.0

    def eta_s(self) -> float | None:
        if not self.fresh:
            return None
        return (self.clock() - self.started) / self.fresh * (self.total - self.done)


def _eta(seconds: float | None) -> str:
    if seconds is None:
        return "?"
    m, s = divmod(int(seconds + 0.5), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class LineProgress:
    """One line per finished run: ``[done/total] run_id: verdict (pass rate so far, ETA)``."""

    def __init__(self, stream: IO[str] | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.stream = stream or sys.stderr
        self.tally = _Tally(clock)

    def start(self, total: int, done: Sequence[RunResult]) -> None:
        self.tally.start(total, done)
        say(f"sweep: {total} runs, {len(done)} already done", file=self.stream)

    def advance(self, result: RunResult) -> None:
        t = self.tally
        t.advance(result)
        say(f"[{t.done}/{t.total}] {plain(result.run_id)}: {plain(result.verdict)} "
            f"(pass rate {t.pass_rate:.2f}, ETA {_eta(t.eta_s())})", file=self.stream)

    def close(self) -> None:
        return None


class RichProgress:
    """A live bar: runs done, pass rate so far, ETA."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, TextColumn
        from rich.progress import Progress as Bar

        self.tally = _Tally(clock)
        self.bar = Bar(TextColumn("sweep"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[status]}"),
                       console=Console(stderr=True), transient=False)
        self.task: Any = None

    def _status(self) -> str:
        return f"pass rate {self.tally.pass_rate:.2f}  ETA {_eta(self.tally.eta_s())}"

    def start(self, total: int, done: Sequence[RunResult]) -> None:
        self.tally.start(total, done)
        self.bar.start()
        self.task = self.bar.add_task("sweep", total=total, completed=len(done), status=self._status())

    def advance(self, result: RunResult) -> None:
        self.tally.advance(result)
        self.bar.update(self.task, completed=self.tally.done, status=self._status())

    def close(self) -> None:
        self.bar.stop()


def progress_for(stream: IO[str] | None = None) -> LineProgress | RichProgress:
    """A rich bar when ``stream`` (stderr) is a terminal, plain lines otherwise."""
    stream = stream or sys.stderr
    return RichProgress() if stream.isatty() else LineProgress(stream)

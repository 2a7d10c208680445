"""How many llama.cpp threads the embedded model uses: chosen from the machine, before every
call and again while it runs.

Guarantee: a choice (:meth:`ThreadChooser.choose`, :meth:`ThreadChooser.recheck`) is never more
threads than the cores this process may run on (``os.sched_getaffinity``, lowered by a cgroup
``cpu.max`` quota) minus the cores other processes keep busy (rounded: a core counts as taken
once more than :data:`IGNORED_BUSY_CORES` of it is in use), never more than
:data:`MAX_THREADS`, and at least 1. ``STORYTELLER_LOCAL_THREADS`` (a whole number >= 1)
fixes the threads instead.

Why: llama.cpp's threads meet at a barrier after every operation of the model's graph
(hundreds per generated token), and a thread that arrives first spins there (libgomp's
``GOMP_SPINCOUNT``) waiting for the others. When another process holds one of 2 cores, the
llama.cpp thread that shares that core gets a time slice only now and then, and every barrier
waits for it: one call (484 prompt tokens, 64 generated) took 23.7-46.6 s with 2 threads and
9.1 s with 1 thread on the same loaded machine. One thread per free core never waits on a
descheduled partner.

The waiting itself cannot be tuned from here: llama-cpp-python 0.3.36 has no binding for
``llama_attach_threadpool`` (ggml's own thread pool and its ``poll`` level), and its wheel
builds ggml with OpenMP (``GGML_OPENMP`` on, ``libggml-cpu.so`` links ``libgomp``), whose
barriers ignore that pool anyway: they wait as libgomp's ``OMP_WAIT_POLICY`` /
``GOMP_SPINCOUNT`` say, read once when libgomp loads. ``OMP_WAIT_POLICY=passive`` (sleep at
once) made 2 threads with a core taken much less bad in one noisy trial (12-16 s instead of
23-47 s; 1 thread 9-11 s) but costs a futex wake per barrier on an idle machine, unmeasured
there, so it is left to the user's environment and the thread count does the work.

How busy: the per-core counters of ``/proc/stat`` for the cores we may use (busy = everything
but idle and iowait; steal counts as busy), less this process's own CPU time (``os.times``)
over the same interval: what other processes use. Before a call the two reads are
:data:`SAMPLE_S` apart while no call of the model runs (the caller holds the model's lock), so
they see the others' whole demand. During a call :meth:`ThreadChooser.recheck` compares with
the previous reading every :data:`RECHECK_S` (no waiting: two file reads), so contention that
starts mid-call lowers the threads at the next token, and contention that ends raises them;
while our threads run, the others get a share of the cores rather than their whole demand, and
the rounding still counts a busy-looping process as a taken core (it gets at least half a
core against 2 of ours). This process's other threads (the simulation) are not counted: they
ran beside the model in every measured quiet run. Where ``/proc/stat`` cannot be read, the
1-minute load average (scaled to our cores) minus the threads of our own previous call stands
in before a call (it lags by a minute; no re-check during the call). Where neither exists,
every usable core counts as free.

Everything the choice reads comes through a :class:`CpuProbe`, so tests give fixed figures.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field

THREADS_ENV = "STORYTELLER_LOCAL_THREADS"
SAMPLE_S = 0.2
"""Seconds between the two ``/proc/stat`` reads before a call (20 clock ticks per core at 100 Hz)."""
RECHECK_S = 2.0
"""Seconds between two re-checks during a call."""
IGNORED_BUSY_CORES = 0.25
"""Load (in cores) left out when rounding the busy cores: a core a quarter busy still counts as free."""
MAX_THREADS = 8
"""Upper bound whatever the core count (a 0.5B-1.5B model gains little from more; not measured here)."""


class ThreadChoice(BaseModel):
    """The threads one local call runs with, and what they were chosen from."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    threads: int = Field(ge=1, description="llama.cpp threads (generation and prompt batches).")
    usable_cores: int = Field(ge=1, description="Cores this process may use (affinity, cgroup quota).")
    busy_cores: float | None = Field(
        default=None, ge=0.0, description="Cores in use by other processes on those cores (None: not measured)."
    )
    source: Literal["override", "proc_stat", "loadavg", "unmeasured"] = Field(
        description="Where busy_cores came from, or override when STORYTELLER_LOCAL_THREADS set the threads."
    )

    def reason(self) -> str:
        """One line a person reads: the threads and why."""
        cores = f"{self.usable_cores} usable core{'s' if self.usable_cores != 1 else ''}"
        if self.source == "override":
            return f"{self.threads} (set by {THREADS_ENV}; {cores})"
        if self.busy_cores is None:
            return f"{self.threads} ({cores}, load not measured)"
        how = "/proc/stat" if self.source == "proc_stat" else "1-minute load average"
        return f"{self.threads} ({cores}, {self.busy_cores:.2f} busy by other processes, {how})"


def threads_for(usable_cores: int, busy_cores: float) -> int:
    """The rule: free cores (busy ones rounded, a quarter core ignored), capped, at least 1."""
    taken = math.ceil(max(0.0, busy_cores - IGNORED_BUSY_CORES))
    return max(1, min(usable_cores - taken, MAX_THREADS))


def busy_cores_between(before: str, after: str, cpus: Collection[int]) -> float | None:
    """Cores' worth of busy time on ``cpus`` between two ``/proc/stat`` texts (None when a
    core's line is missing or no time passed)."""
    first, second = _per_cpu_ticks(before), _per_cpu_ticks(after)
    busy = total = 0
    for cpu in cpus:
        if cpu not in first or cpu not in second:
            return None
        busy += second[cpu][0] - first[cpu][0]
        total += second[cpu][1] - first[cpu][1]
    if total <= 0:
        return None
    return round(len(cpus) * max(0, busy) / total, 3)


def _per_cpu_ticks(text: str) -> dict[int, tuple[int, int]]:
    """cpu number -> (busy ticks, total ticks) from ``/proc/stat``'s ``cpuN`` lines."""
    out: dict[int, tuple[int, int]] = {}
    for line in text.splitlines():
        name, _, rest = line.partition(" ")
        if not name.startswith("cpu") or not name[3:].isdigit():
            continue
        fields = [int(v) for v in rest.split()]
        # user nice system idle iowait irq softirq steal [guest guest_nice: already in user/nice]
        total = sum(fields[:8])
        idle = sum(fields[3:5])
        out[int(name[3:])] = (total - idle, total)
    return out


def quota_cores(cpu_max: str | None) -> float | None:
    """Cores allowed by a cgroup v2 ``cpu.max`` text (``"150000 100000"`` -> 1.5; ``max``: None)."""
    if not cpu_max:
        return None
    parts = cpu_max.split()
    if len(parts) != 2 or parts[0] == "max":
        return None
    try:
        quota, period = float(parts[0]), float(parts[1])
    except ValueError:
        return None
    return quota / period if quota > 0 and period > 0 else None


class CpuProbe(Protocol):
    """What the choice reads from the machine."""

    def cpus(self) -> frozenset[int]: ...  # cores this process may run on
    def cpu_max(self) -> str | None: ...  # the cgroup v2 cpu.max text, None without one
    def proc_stat(self) -> str | None: ...  # /proc/stat, None where it cannot be read
    def loadavg(self) -> float | None: ...  # 1-minute load average of the whole machine
    def cpu_count(self) -> int: ...  # cores of the whole machine
    def own_cpu_s(self) -> float: ...  # CPU seconds (user + system) this process has used
    def monotonic(self) -> float: ...
    def sleep(self, seconds: float) -> None: ...


class SystemProbe:
    """The running machine."""

    def cpus(self) -> frozenset[int]:
        if hasattr(os, "sched_getaffinity"):
            return frozenset(os.sched_getaffinity(0))
        return frozenset(range(os.cpu_count() or 1))

    def cpu_max(self) -> str | None:
        try:
            return Path("/sys/fs/cgroup/cpu.max").read_text(encoding="ascii")
        except OSError:
            return None

    def proc_stat(self) -> str | None:
        try:
            return Path("/proc/stat").read_text(encoding="ascii")
        except OSError:
            return None

    def loadavg(self) -> float | None:
        try:
            return os.getloadavg()[0]
        except (AttributeError, OSError):
            return None

    def cpu_count(self) -> int:
        return os.cpu_count() or 1

    def own_cpu_s(self) -> float:
        t = os.times()
        return t.user + t.system

    def monotonic(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)


def usable_cores(probe: CpuProbe) -> int:
    """Cores this process may use: its affinity, lowered to a cgroup quota (rounded down)."""
    n = max(1, len(probe.cpus()))
    quota = quota_cores(probe.cpu_max())
    if quota is not None:
        n = min(n, max(1, math.floor(quota)))
    return n


def override_threads(env: Mapping[str, str]) -> int | None:
    """``STORYTELLER_LOCAL_THREADS`` as a number, None when unset; ValueError when not a whole number >= 1."""
    raw = env.get(THREADS_ENV, "").strip()
    if not raw:
        return None
    # ASCII digits only ('²' and other Unicode digits pass isdigit() but not int()), and few of
    # them (5,000 digits are past int()'s limit); either way the error names the variable
    if not (raw.isascii() and raw.isdigit()) or len(raw) > 6 or int(raw) < 1:
        raise ValueError(f"environment variable {THREADS_ENV} must be a whole number >= 1, got {raw[:20]!r}")
    return int(raw)


@dataclass(frozen=True)
class _Reading:
    """One look at the machine: ``/proc/stat``, this process's CPU seconds, the time."""

    stat: str
    own_cpu_s: float
    at: float


class ThreadChooser:
    """Chooses the threads of each call and re-checks them during it (see the module doc);
    remembers its last choice (``storyteller model info`` shows one) and its last reading."""

    def __init__(self, probe: CpuProbe | None = None, env: Mapping[str, str] | None = None,
                 sample_s: float = SAMPLE_S, recheck_s: float = RECHECK_S) -> None:
        self._probe: CpuProbe = probe if probe is not None else SystemProbe()
        self._env = env if env is not None else os.environ
        self._sample_s = sample_s
        self._recheck_s = recheck_s
        self._lock = threading.Lock()
        self._mark: _Reading | None = None
        self.last: ThreadChoice | None = None

    def choose(self) -> ThreadChoice:
        """The threads for a call about to start (the model idle): a fresh sample."""
        usable = usable_cores(self._probe)
        fixed = override_threads(self._env)
        if fixed is not None:
            choice = ThreadChoice(threads=fixed, usable_cores=usable, source="override")
        else:
            choice = self._sampled(usable)
        with self._lock:
            self.last = choice
        return choice

    def recheck(self) -> ThreadChoice | None:
        """During a call: a new choice from the load since the last reading, or None when it is
        under :data:`RECHECK_S` old, the threads are fixed, or ``/proc/stat`` cannot be read."""
        with self._lock:
            mark = self._mark
            if mark is None or self._probe.monotonic() - mark.at < self._recheck_s:
                return None
        if override_threads(self._env) is not None:
            return None
        now = self._read()
        if now is None:
            return None
        busy = self._others(mark, now)
        with self._lock:
            self._mark = now
            if busy is None:
                return None
            usable = usable_cores(self._probe)
            self.last = ThreadChoice(threads=threads_for(usable, busy), usable_cores=usable, busy_cores=busy,
                                     source="proc_stat")
            return self.last

    def _read(self) -> _Reading | None:
        stat = self._probe.proc_stat()
        if stat is None:
            return None
        return _Reading(stat, self._probe.own_cpu_s(), self._probe.monotonic())

    def _others(self, before: _Reading, after: _Reading) -> float | None:
        """Cores' worth of busy time by other processes between two readings."""
        busy = busy_cores_between(before.stat, after.stat, self._probe.cpus())
        elapsed = after.at - before.at
        if busy is None or elapsed <= 0:
            return None
        own = (after.own_cpu_s - before.own_cpu_s) / elapsed
        return round(max(0.0, busy - own), 3)

    def _sampled(self, usable: int) -> ThreadChoice:
        probe = self._probe
        before = self._read()
        if before is not None:
            probe.sleep(self._sample_s)
            after = self._read()
            busy = self._others(before, after) if after is not None else None
            if busy is not None:
                with self._lock:
                    self._mark = after
                return ThreadChoice(threads=threads_for(usable, busy), usable_cores=usable, busy_cores=busy,
                                    source="proc_stat")
        load = probe.loadavg()
        if load is not None:
            last = self.last
            own = last.threads if last is not None and last.source == "loadavg" else 0
            busy = round(max(0.0, load * len(probe.cpus()) / max(1, probe.cpu_count()) - own), 3)
            return ThreadChoice(threads=threads_for(usable, busy), usable_cores=usable, busy_cores=busy,
                                source="loadavg")
        return ThreadChoice(threads=threads_for(usable, 0.0), usable_cores=usable, source="unmeasured")

"""The embedded model's threads come from the machine: cores we may use minus busy cores.

A fake probe gives fixed ``/proc/stat`` texts, affinity sets, cgroup quotas and load averages,
so every figure is deterministic; nothing here loads a model.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from storyteller.orchestrator.llm.cpu_threads import (
    MAX_THREADS,
    THREADS_ENV,
    ThreadChooser,
    busy_cores_between,
    quota_cores,
    threads_for,
)


def stat(cores: dict[int, tuple[int, int]]) -> str:
    """A /proc/stat text whose ``cpuN`` line has ``busy`` user ticks and ``idle`` idle ticks."""
    lines = ["cpu  1 2 3 4 5 6 7 8 0 0"]
    for n, (busy, idle) in sorted(cores.items()):
        # user nice system idle iowait irq softirq steal guest guest_nice
        lines.append(f"cpu{n} {busy} 0 0 {idle} 0 0 0 0 {busy} 0")  # guest is inside user: not counted twice
    lines.append("intr 12345 0 0")
    return "\n".join(lines) + "\n"


@dataclass
class FakeProbe:
    """A machine with fixed figures; records what was read."""

    cores: frozenset[int] = frozenset({0, 1})
    stats: list[str | None] = field(default_factory=list)
    quota: str | None = None
    load: float | None = None
    count: int = 2
    own: list[float] = field(default_factory=list)  # CPU seconds of this process at each read
    reads: int = 0
    slept: list[float] = field(default_factory=list)
    now: float = 100.0

    def cpus(self) -> frozenset[int]:
        return self.cores

    def cpu_max(self) -> str | None:
        return self.quota

    def proc_stat(self) -> str | None:
        self.reads += 1
        return self.stats.pop(0) if self.stats else None

    def loadavg(self) -> float | None:
        return self.load

    def cpu_count(self) -> int:
        return self.count

    def own_cpu_s(self) -> float:
        return self.own.pop(0) if self.own else 0.0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self.now += seconds


def sampled(before: dict[int, tuple[int, int]], after: dict[int, tuple[int, int]]) -> list[str | None]:
    return [stat(before), stat(after)]


@pytest.mark.parametrize(
    ("usable", "busy", "threads"),
    [(2, 0.0, 2), (2, 0.2, 2), (2, 0.3, 1), (2, 1.0, 1), (2, 1.9, 1), (2, 2.0, 1),
     (4, 1.5, 2), (4, 0.9, 3), (1, 0.0, 1), (32, 0.0, MAX_THREADS), (32, 30.0, 2)],
)
def test_threads_are_the_free_cores_at_least_one(usable: int, busy: float, threads: int) -> None:
    assert threads_for(usable, busy) == threads


def test_a_core_kept_busy_by_another_process_leaves_one_thread() -> None:
    # over the sample cpu0 stayed idle (20 idle ticks), cpu1 was busy all the time (20 busy ticks)
    probe = FakeProbe(stats=sampled({0: (100, 500), 1: (100, 500)}, {0: (100, 520), 1: (120, 500)}))
    choice = ThreadChooser(probe, env={}).choose()
    assert (choice.threads, choice.usable_cores, choice.busy_cores, choice.source) == (1, 2, 1.0, "proc_stat")
    assert probe.slept == [0.2] and probe.reads == 2
    assert choice.reason() == "1 (2 usable cores, 1.00 busy by other processes, /proc/stat)"


def test_our_own_cpu_time_is_not_counted_as_busy() -> None:
    # both cores fully busy over 0.2 s, 0.2 CPU seconds of it ours (a core's worth): one other core busy
    probe = FakeProbe(stats=sampled({0: (0, 0), 1: (0, 0)}, {0: (20, 0), 1: (20, 0)}), own=[5.0, 5.2])
    choice = ThreadChooser(probe, env={}).choose()
    assert (choice.threads, choice.busy_cores) == (1, 1.0)


def test_a_recheck_during_a_call_follows_contention_that_starts_and_ends() -> None:
    quiet = {0: (0, 20), 1: (0, 20)}
    probe = FakeProbe(stats=sampled({0: (0, 0), 1: (0, 0)}, quiet))
    chooser = ThreadChooser(probe, env={})
    assert chooser.choose().threads == 2
    probe.now += 1.0
    assert chooser.recheck() is None and probe.reads == 2, "under RECHECK_S since the last reading: no read"
    # 2 s later: both cores were busy, our two threads used 1.5 cores of it, another process the rest
    probe.now += 1.0
    probe.stats, probe.own = [stat({0: (200, 20), 1: (200, 20)})], [3.0]
    first = chooser.recheck()
    assert first is not None and (first.threads, first.busy_cores) == (1, 0.5)
    assert probe.slept == [0.2], "a re-check does not wait"
    # 2 s more: the other process is gone (one core busy, all of it ours)
    probe.now += 2.0
    probe.stats, probe.own = [stat({0: (400, 20), 1: (200, 220)})], [5.0]
    second = chooser.recheck()
    assert second is not None and (second.threads, second.busy_cores) == (2, 0.0)
    assert chooser.last == second


def test_no_recheck_with_fixed_threads_or_without_a_first_reading() -> None:
    fixed = FakeProbe(stats=sampled({0: (0, 0), 1: (0, 0)}, {0: (0, 20), 1: (0, 20)}))
    chooser = ThreadChooser(fixed, env={THREADS_ENV: "2"})
    chooser.choose()
    fixed.now += 10.0
    assert chooser.recheck() is None
    assert ThreadChooser(FakeProbe(load=0.5), env={}).recheck() is None


def test_a_quiet_machine_gets_a_thread_per_core() -> None:
    # 1 busy tick of 40: a twentieth of a core is noise, not a taken core
    probe = FakeProbe(stats=sampled({0: (0, 0), 1: (0, 0)}, {0: (1, 19), 1: (0, 20)}))
    choice = ThreadChooser(probe, env={}).choose()
    assert (choice.threads, choice.busy_cores) == (2, 0.05)


def test_only_the_cores_in_our_affinity_count() -> None:
    before = {0: (0, 0), 1: (0, 0), 2: (0, 0), 3: (0, 0)}
    after = {0: (0, 20), 1: (20, 0), 2: (0, 20), 3: (0, 20)}  # cpu1 busy, the rest idle
    pinned = FakeProbe(cores=frozenset({0, 2, 3}), count=4, stats=sampled(before, after))
    assert ThreadChooser(pinned, env={}).choose().threads == 3  # cpu1's load is not on our cores
    on_busy = FakeProbe(cores=frozenset({1}), count=4, stats=sampled(before, after))
    choice = ThreadChooser(on_busy, env={}).choose()
    assert (choice.threads, choice.usable_cores, choice.busy_cores) == (1, 1, 1.0)


def test_a_cgroup_quota_lowers_the_usable_cores() -> None:
    assert quota_cores("150000 100000\n") == 1.5 and quota_cores("max 100000") is None and quota_cores(None) is None
    probe = FakeProbe(cores=frozenset(range(4)), count=4, quota="150000 100000",
                      stats=sampled({n: (0, 0) for n in range(4)}, {n: (0, 20) for n in range(4)}))
    choice = ThreadChooser(probe, env={}).choose()
    assert (choice.threads, choice.usable_cores) == (1, 1)


def test_the_environment_variable_overrides_without_measuring() -> None:
    probe = FakeProbe(stats=sampled({0: (0, 0), 1: (0, 0)}, {0: (20, 0), 1: (20, 0)}))
    choice = ThreadChooser(probe, env={THREADS_ENV: "3"}).choose()
    assert (choice.threads, choice.source, choice.busy_cores) == (3, "override", None)
    assert probe.reads == 0 and probe.slept == []
    assert "set by STORYTELLER_LOCAL_THREADS" in choice.reason()
    with pytest.raises(ValueError, match="STORYTELLER_LOCAL_THREADS must be a whole number >= 1, got 'two'"):
        ThreadChooser(FakeProbe(), env={THREADS_ENV: "two"}).choose()
    with pytest.raises(ValueError, match="got '0'"):
        ThreadChooser(FakeProbe(), env={THREADS_ENV: "0"}).choose()
    # found by the hostile corpus: int()'s own errors, without the variable's name
    for hostile in ("\u00b2", "9" * 5000):
        with pytest.raises(ValueError, match="STORYTELLER_LOCAL_THREADS must be a whole number"):
            ThreadChooser(FakeProbe(), env={THREADS_ENV: hostile}).choose()


def test_without_proc_stat_the_load_average_stands_in_less_our_own_threads() -> None:
    probe = FakeProbe(load=1.1)
    chooser = ThreadChooser(probe, env={})
    first = chooser.choose()
    assert (first.threads, first.busy_cores, first.source) == (1, 1.1, "loadavg")
    probe.load = 1.2  # our own thread of the last call is in the load now
    assert chooser.choose().busy_cores == pytest.approx(0.2)
    assert chooser.choose().threads == 2
    # half the machine's cores are ours: half its load is counted against them
    half = FakeProbe(cores=frozenset({0, 1}), count=4, load=2.0)
    assert ThreadChooser(half, env={}).choose().busy_cores == 1.0


def test_nothing_to_measure_means_every_usable_core() -> None:
    choice = ThreadChooser(FakeProbe(), env={}).choose()
    assert (choice.threads, choice.source, choice.busy_cores) == (2, "unmeasured", None)
    assert "load not measured" in choice.reason()


def test_busy_cores_need_every_core_line_and_elapsed_ticks() -> None:
    same = stat({0: (5, 5)})
    assert busy_cores_between(same, same, [0]) is None  # no tick passed
    assert busy_cores_between(stat({0: (0, 0)}), stat({0: (10, 10)}), [0, 1]) is None  # no cpu1 line
    steal = "cpu0 0 0 0 0 0 0 0 0 0 0\n", "cpu0 0 0 0 10 0 0 0 10 0 0\n"  # half the time stolen by the host
    assert busy_cores_between(*steal, [0]) == 0.5


def test_model_info_reports_the_threads_and_the_progress_floor(monkeypatch: pytest.MonkeyPatch) -> None:
    from typer.testing import CliRunner

    from storyteller.orchestrator.cli.app import app

    monkeypatch.setenv(THREADS_ENV, "3")
    out = CliRunner().invoke(app, ["model", "info"])
    assert out.exit_code == 0
    assert "local threads now: 3 (set by STORYTELLER_LOCAL_THREADS; " in out.output
    assert "local progress floor: decode >= 0.5 tok/s over 30 s" in out.output
    monkeypatch.setenv(THREADS_ENV, "many")
    bad = CliRunner().invoke(app, ["model", "info"])
    assert bad.exit_code == 2 and "STORYTELLER_LOCAL_THREADS must be a whole number >= 1, got 'many'" in bad.output

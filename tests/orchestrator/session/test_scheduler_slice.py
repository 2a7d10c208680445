"""The realtime simulation thread's short scheduler slice (``storyteller.orchestrator.session.scheduler_slice``).

On Linux 6.12 or later (x86_64 or aarch64) the slice is asked for and given back, per thread,
and a realtime session runs its frames with it while a lockstep one does not. Elsewhere the
request changes nothing and says why; the kernel-dependent tests are skipped there, by a check
of the platform that does not go through the code under test.
"""

from __future__ import annotations

import os
import platform
import sys
import threading

import anyio
import pytest

from storyteller.orchestrator.session.pace import Pace
from storyteller.orchestrator.session.runtime import Session
from storyteller.orchestrator.session.scheduler_slice import SLICE_NS, SYSCALLS, short_slice, thread_slice_ns
from storyteller.orchestrator.session.session_types import SessionSettings
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.step import World
from tests.support.session_world import ScriptedPlanner, make_world


def _kernel_keeps_slices() -> bool:
    if not sys.platform.startswith("linux") or platform.machine() not in SYSCALLS:
        return False
    major, minor = (int(part) for part in os.uname().release.split(".")[:2])
    return (major, minor) >= (6, 12)


needs_custom_slices = pytest.mark.skipif(not _kernel_keeps_slices(), reason="custom EEVDF slices: Linux >= 6.12")


@needs_custom_slices
def test_the_slice_is_asked_for_the_calling_thread_and_given_back() -> None:
    before = thread_slice_ns()
    assert before is not None and before != SLICE_NS
    seen_elsewhere: list[int | None] = []
    with short_slice() as request:
        assert request.problem is None
        assert (request.before_ns, request.now_ns) == (before, SLICE_NS)
        assert thread_slice_ns() == SLICE_NS
        other = threading.Thread(target=lambda: seen_elsewhere.append(thread_slice_ns()))
        other.start()
        other.join()
    assert seen_elsewhere == [before]  # another thread keeps its own slice
    assert thread_slice_ns() == before


@needs_custom_slices
def test_a_slice_given_back_after_an_error_in_the_block() -> None:
    before = thread_slice_ns()
    with pytest.raises(RuntimeError, match="boom"), short_slice():
        raise RuntimeError("boom")
    assert thread_slice_ns() == before


def test_not_asked_changes_nothing() -> None:
    before = thread_slice_ns()
    with short_slice(enabled=False) as request:
        assert request.problem == "not asked"
        assert thread_slice_ns() == before


def _slices_seen(world: World, home: Scene, pace: Pace, monkeypatch: pytest.MonkeyPatch) -> set[int | None]:
    """The slice of the simulation's thread at every frame of a short session in ``pace``."""
    real_sleep = anyio.sleep

    async def no_wait(delay: float) -> None:  # realtime frames without waiting for the clock
        await real_sleep(0)

    monkeypatch.setattr(anyio, "sleep", no_wait)
    seen: set[int | None] = set()

    async def main() -> None:
        session = Session(world, ScriptedPlanner(home), SessionSettings(frames=20, pace=pace, max_steps=1),
                          on_frame=lambda _: seen.add(thread_slice_ns()))
        await session.run()

    anyio.run(main)
    return seen


@needs_custom_slices
@pytest.mark.parametrize("pace", ["realtime", "lockstep"])
def test_a_realtime_session_runs_its_frames_with_the_short_slice_and_gives_it_back(
    home: Scene, motion: MotionMatcher, monkeypatch: pytest.MonkeyPatch, pace: Pace
) -> None:
    before = thread_slice_ns()
    seen = _slices_seen(make_world(home, motion, ["Ava", "Ben"]), home, pace, monkeypatch)
    assert seen == ({SLICE_NS} if pace == "realtime" else {before})
    assert thread_slice_ns() == before

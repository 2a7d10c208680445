"""The session checkpoint writer thread: newest-wins bounded queue, order, flush, errors.

A real world on the bundled home scene (so the checkpoints are the session's own); the write
function is injected where a slow or full disk is simulated.
"""

from __future__ import annotations

import errno
import threading
from pathlib import Path

import anyio
import pytest

from storyteller.orchestrator.planning.state import StepProgress
from storyteller.orchestrator.session.checkpoint_writer import CheckpointWriter
from storyteller.orchestrator.session.runtime import Session
from storyteller.orchestrator.session.session_types import (
    Outcome,
    PlanningRequest,
    SessionCheckpoint,
    SessionSettings,
)
from storyteller.orchestrator.session.snapshot_file import load_checkpoint, save_checkpoint
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.step import World, step
from storyteller.sim.world.track_chunks import ChunkStore

NAMES = ["Ava", "Ben"]


def _world(home: Scene, motion: MotionMatcher) -> World:
    return World(home, {"Ava": ((1.0, 1.0), 0.0), "Ben": ((2.5, 1.0), 0.0)}, motion)


class _Planner:
    """Always waits (no event): the world only stands."""

    async def plan(self, request: PlanningRequest, progress: StepProgress | None = None) -> Outcome:
        return None


def _checkpoints(world: World, frames: list[int]) -> list[SessionCheckpoint]:
    """Checkpoints of a session on ``world`` at each of ``frames`` (stepping the world between)."""
    session = Session(world, _Planner(), SessionSettings(frames=max(frames)))
    out = []
    for f in frames:
        while session.world.frame < f:
            session.world, _ = step(session.world, [], session.world.dt)
        out.append(session.checkpoint())
    return out


class _SlowDisk:
    """A write function that waits for ``release`` on its first write and records every write."""

    def __init__(self, fail_on: int | None = None) -> None:
        self.release = threading.Event()
        self.started = threading.Event()
        self.frames: list[int] = []
        self.fail_on = fail_on

    def __call__(self, path: Path, cp: SessionCheckpoint, shared: dict[int, str], store: ChunkStore | None) -> None:
        self.started.set()
        self.release.wait(timeout=30)
        if self.fail_on is not None and cp.world.frame == self.fail_on:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        self.frames.append(cp.world.frame)


@pytest.mark.slow
def test_the_file_is_the_newest_checkpoint_as_a_synchronous_save_writes_it(
    home: Scene, motion: MotionMatcher, tmp_path: Path
) -> None:
    world = _world(home, motion)
    world.stream_tracks(ChunkStore.open(tmp_path / "motion", NAMES), window=4)  # frames go to disk as it steps
    cps = _checkpoints(world, [3, 9, 14])
    writer = CheckpointWriter(tmp_path / "session.snapshot")
    for cp in cps:
        writer.submit(world, cp)
    writer.close()
    save_checkpoint(tmp_path / "sync.snapshot", world, cps[-1])
    assert (tmp_path / "session.snapshot").read_bytes() == (tmp_path / "sync.snapshot").read_bytes()
    loaded = load_checkpoint(tmp_path / "session.snapshot", _world(home, motion))
    assert loaded.world.frame == 14 and 0 < loaded.world.buffers.base <= 14  # some frames in the chunk files
    assert writer.written + writer.replaced == 3
    assert not (tmp_path / "session.snapshot.tmp").exists()


def test_a_newer_checkpoint_replaces_the_one_waiting_and_flush_waits_for_it(
    home: Scene, motion: MotionMatcher, tmp_path: Path
) -> None:
    world = _world(home, motion)
    cps = _checkpoints(world, [1, 2, 3, 4])
    disk = _SlowDisk()
    writer = CheckpointWriter(tmp_path / "session.snapshot", write=disk)
    writer.submit(world, cps[0])
    assert disk.started.wait(timeout=30)  # the first write is in progress (and stuck)
    for cp in cps[1:]:
        writer.submit(world, cp)  # returns at once although the disk is stuck
    assert writer.replaced == 2  # frames 2 and 3 were waiting when a newer one came
    disk.release.set()
    writer.flush()
    assert disk.frames == [1, 4]
    writer.close()
    assert disk.frames == [1, 4] and writer.written == 2


def test_a_failed_write_is_raised_by_the_next_call_and_nothing_is_written_after_it(
    home: Scene, motion: MotionMatcher, tmp_path: Path
) -> None:
    world = _world(home, motion)
    cps = _checkpoints(world, [1, 2, 3])
    disk = _SlowDisk(fail_on=1)
    writer = CheckpointWriter(tmp_path / "session.snapshot", write=disk)
    writer.submit(world, cps[0])
    disk.release.set()
    with pytest.raises(OSError, match="No space left on device") as caught:
        writer.flush()
    assert caught.value.filename == str(tmp_path / "session.snapshot")
    with pytest.raises(OSError):
        writer.submit(world, cps[1])
    writer.close(raise_errors=False)  # the caller handles the error already: not raised again
    assert disk.frames == []


def test_a_session_checkpointing_through_the_writer_is_resumable(
    home: Scene, motion: MotionMatcher, tmp_path: Path
) -> None:
    """The run job's wiring: ``on_checkpoint`` submits, the file holds the session's last checkpoint."""
    world = _world(home, motion)
    writer = CheckpointWriter(tmp_path / "session.snapshot")
    taken: list[int] = []

    def keep(cp: SessionCheckpoint) -> None:
        taken.append(cp.world.frame)
        writer.submit(world, cp)

    async def main() -> None:
        session = Session(world, _Planner(), SessionSettings(frames=45, pace="fast", checkpoint_every_s=0.5),
                          on_checkpoint=keep)
        await session.run()

    anyio.run(main)
    writer.close()
    loaded = load_checkpoint(tmp_path / "session.snapshot", _world(home, motion))
    assert len(taken) >= 3 and loaded.world.frame == taken[-1]  # the last one taken is the one on disk
    assert writer.written + writer.replaced == len(taken)

"""Session checkpoints written by one worker thread, so the frame loop never waits on a disk.

Writing a checkpoint (``storyteller.orchestrator.session.snapshot_file.write_checkpoint``) fsyncs every
motion chunk file, the pickled checkpoint and the run folder: tens of milliseconds on an
ordinary disk, a hundred under load, which on the event loop is a frame or three missed in
``realtime`` pace. :class:`CheckpointWriter` takes the checkpoint (a copy the session no longer
touches, taken on the loop between two frames) and writes it in its own thread.

Bounded: one write in progress and at most one waiting. A newer checkpoint replaces the one
still waiting (it holds everything that one held), so a slow disk costs checkpoints, never
memory or frames. Order and durability are those of the synchronous write: checkpoints reach
the file in the order they were taken, each atomically (the previous file stays until the new
one is renamed over it), and :meth:`flush` / :meth:`close` return once the newest one taken is
on disk. A failed write (a full disk) is raised, naming the file, by the next :meth:`submit`,
:meth:`flush` or :meth:`close` in the caller's thread; nothing is written after it.

A kill -9 may now find on disk the checkpoint before the one being written (a few frames or
one applied step older). ``storyteller resume`` handles it as any earlier checkpoint: steps the
trace shows applied after it are applied again at their recorded frames, answered from the
planner's story log (``storyteller.orchestrator.session.run_job``).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path

from storyteller.orchestrator.session.session_types import SessionCheckpoint
from storyteller.orchestrator.session.snapshot_file import shared_names, write_checkpoint
from storyteller.sim.world.step import World
from storyteller.sim.world.track_chunks import ChunkStore

WriteFn = Callable[[Path, SessionCheckpoint, dict[int, str], ChunkStore | None], None]


class CheckpointWriter:
    """Writes checkpoints of a session on ``world``-like worlds to ``path`` in a worker thread."""

    def __init__(self, path: Path, write: WriteFn = write_checkpoint) -> None:
        self.path = path
        self._write = write
        self._cond = threading.Condition()
        self._waiting: tuple[SessionCheckpoint, dict[int, str], ChunkStore | None] | None = None
        self._busy = False
        self._error: BaseException | None = None
        self._closed = False
        self.written = 0
        """Checkpoints written so far."""
        self.replaced = 0
        """Checkpoints dropped unwritten because a newer one came first."""
        self._thread = threading.Thread(target=self._run, name="checkpoint-writer", daemon=True)
        self._thread.start()

    def submit(self, world: World, checkpoint: SessionCheckpoint) -> None:
        """Write ``checkpoint`` (taken from a session on ``world``) soon; returns at once.
        Raises the error of an earlier write, if one failed."""
        shared = shared_names(world)
        store = world.buffers.store
        with self._cond:
            self._raise_error()
            if self._closed:
                raise ValueError(f"{self.path}: the checkpoint writer is closed")
            if self._waiting is not None:
                self.replaced += 1
            self._waiting = (checkpoint, shared, store)
            self._cond.notify_all()

    def flush(self) -> None:
        """Wait until every checkpoint submitted so far is written (or replaced by a newer one
        that is); raise the error of a failed write."""
        with self._cond:
            while (self._waiting is not None or self._busy) and self._error is None:
                self._cond.wait()
            self._raise_error()

    def close(self, *, raise_errors: bool = True) -> None:
        """:meth:`flush`, then stop the thread. ``raise_errors=False``: a failed write is not
        raised (the caller is already handling another error)."""
        try:
            if raise_errors:
                self.flush()
            else:
                with self._cond:
                    while (self._waiting is not None or self._busy) and self._error is None:
                        self._cond.wait()
        finally:
            with self._cond:
                self._closed = True
                self._cond.notify_all()
            self._thread.join()

    def _raise_error(self) -> None:
        if self._error is not None:
            raise self._error

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._waiting is None and not self._closed:
                    self._cond.wait()
                if self._waiting is None:  # closed, nothing left
                    return
                job, self._waiting = self._waiting, None
                self._busy = True
            try:
                self._write(self.path, *job)
            except BaseException as exc:  # raised in the caller's thread; nothing written after it
                with self._cond:
                    self._error = exc
                    self._waiting = None
                    self._busy = False
                    self._cond.notify_all()
                return
            with self._cond:
                self.written += 1
                self._busy = False
                self._cond.notify_all()

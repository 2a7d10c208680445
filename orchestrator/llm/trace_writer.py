"""Writing a trace (:mod:`storyteller.orchestrator.llm.traces`): the :class:`TraceSink` the LLM clients
record to, the :class:`TraceWriter` that appends to a JSONL file, and a :class:`NullTraceSink`.

``seq`` is unique within a file (a writer that reopens a file continues after the last seq).
Each record is written with a single ``os.write`` of one complete line on an ``O_APPEND``
descriptor before :meth:`TraceWriter.write` returns, so a killed writer leaves at most one torn
line, at the end, and a kill -9 never loses a record whose ``write`` returned (the kernel holds
it; only a power loss or a crash of the machine needs the fsync).

Durability (``fsync``): with ``"always"`` every record is fsynced by the writer's own thread
soon after its ``write`` (one fsync covers every record written before it started), so a
caller on the event loop never waits on the disk (13-35 ms a record under load).
:meth:`TraceWriter.sync` blocks, and ``await`` :meth:`TraceWriter.durable` waits in a worker
thread, until every record written so far is on disk. The run waits there before anything
durable that counts on a record is written: the LLM client before it returns a response (the
planning graph checkpoints the node after it), the planning graph before it logs a step's
outcome (``record_outcome``; the session applies an outcome only after that), the session's
checkpoint writer before each checkpoint, and :meth:`TraceWriter.close`. With ``"close"``
records are fsynced at close only, with ``"never"`` not at all (``sync`` returns at once).
Reopening a file with a torn tail for writing cuts that tail off first (and logs it).
A write that fails (a full disk, a file-size limit) cuts the part of its line that was
written and raises ``OSError`` naming the file: the lines before it stay whole.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

import structlog
from pydantic import JsonValue

from storyteller.agents.llm_port import NodeName, TraceRecorder
from storyteller.orchestrator.llm.config import FsyncPolicy
from storyteller.orchestrator.llm.traces import (
    AppliedRecord,
    InstructionRecord,
    ParsedRecord,
    RequestedRecord,
    RunRecord,
    TraceRecord,
    read_trace,
)
from storyteller.sim.no_follow_writes import open_append

_log = structlog.get_logger("storyteller.traces")


class TraceSink(TraceRecorder, Protocol):
    """What the LLM clients need from a trace destination; callers see it as the port's
    :class:`agents.llm_port.TraceRecorder` (``record_parsed``, ``record_applied``)."""

    run_id: str

    def next_seq(self) -> int: ...

    def write(self, record: TraceRecord) -> None: ...

    def record_instruction(self, text: str, sim_frame: int, *, source: str) -> None:
        """A new instruction took effect at ``sim_frame``."""
        ...

    def record_requested(self, step: int, sim_frame: int, *, phase: str, after_steps: Sequence[int]) -> None:
        """Planning step ``step`` was requested at ``sim_frame`` beside the steps ``after_steps``."""
        ...

    async def durable(self) -> None:
        """Wait, off the event loop, until every record written so far is on disk (as
        :meth:`~storyteller.agents.llm_port.TraceRecorder.sync`)."""
        ...

    def close(self) -> None:
        """Flush and close the destination (nothing to do for a sink that stores nothing). Safe to call twice."""
        ...


class NullTraceSink:
    """A sink that numbers records but stores nothing."""

    def __init__(self, run_id: str | None = None) -> None:
        self.run_id = run_id or uuid.uuid4().hex[:12]
        self._seq = 0
        self._lock = threading.Lock()

    def next_seq(self) -> int:
        with self._lock:
            self._seq += 1
            return self._seq - 1

    def write(self, record: TraceRecord) -> None:
        return None

    def record_parsed(
        self, ref_seq: int, parsed_output: JsonValue, *, node: NodeName | None = None,
        error_type: str | None = None, error_message: str | None = None,
    ) -> None:
        return None

    def record_applied(
        self, ref_seqs: Sequence[int], sim_frame: int, *, step: int | None = None,
        requested_frame: int | None = None,
    ) -> None:
        return None

    def record_instruction(self, text: str, sim_frame: int, *, source: str) -> None:
        return None

    def record_requested(self, step: int, sim_frame: int, *, phase: str, after_steps: Sequence[int]) -> None:
        return None

    def sync(self) -> None:
        return None

    async def durable(self) -> None:
        return None

    def close(self) -> None:
        return None


class TraceWriter:
    """Appends records to a JSONL file. Thread-safe; one ``os.write`` per record, in the caller's
    thread; with ``fsync="always"`` the fsyncs run in the writer's own thread (module doc)."""

    def __init__(
        self,
        path: Path | str,
        *,
        run_id: str | None = None,
        fsync: FsyncPolicy = "always",
        meta: dict[str, Any] | None = None,
    ) -> None:
        self.path = Path(path)
        self.run_id = run_id or uuid.uuid4().hex[:12]
        self.fsync: FsyncPolicy = fsync
        self._lock = threading.Lock()  # seq numbers, and one os.write at a time
        self._synced_cv = threading.Condition()  # the counters below, and the syncer's wake-ups
        self._written = 0  # records whose os.write returned
        self._synced = 0  # of those, the ones an fsync covered
        self._sync_error: OSError | None = None
        self._closing = False
        self._syncer: threading.Thread | None = None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # opened first, without following a link (``sim.no_follow_writes``): a symbolic link, a
        # FIFO or a hard-linked file at the path is refused, never read, cut or appended through
        self._fd: int | None = open_append(self.path)
        try:
            self._seq = self._recover(self._fd)
        except BaseException:
            os.close(self._fd)
            raise
        if fsync == "always":
            self._syncer = threading.Thread(target=self._sync_loop, name="trace-fsync", daemon=True)
            self._syncer.start()
        self.write(RunRecord(run_id=self.run_id, seq=self.next_seq(), time_unix=time.time(), meta=meta or {}))

    def _recover(self, fd: int) -> int:
        """Cut a torn tail off the file open as ``fd``; return the next free seq."""
        if os.fstat(fd).st_size == 0:
            return 0
        contents = read_trace(self.path)
        if contents.torn_tail is not None:
            _log.warning("trace_tail_truncated", path=str(self.path), bytes=contents.torn_tail.size)
            os.ftruncate(fd, contents.torn_tail.byte_offset)
        return max((r.seq for r in contents.records), default=-1) + 1

    def next_seq(self) -> int:
        with self._lock:
            self._seq += 1
            return self._seq - 1

    def write(self, record: TraceRecord) -> None:
        """Append ``record`` (in the file when this returns; on disk soon after, see :meth:`sync`).
        Raises ``OSError`` naming the file when the write, or an earlier fsync, failed."""
        line = record.model_dump_json().encode("utf-8") + b"\n"
        with self._lock:
            if self._fd is None:
                raise ValueError(f"trace writer for {self.path} is closed")
            self._raise_sync_error()
            start = os.fstat(self._fd).st_size
            view = memoryview(line)
            try:
                while view:  # a regular-file write is complete unless the disk is full
                    n = os.write(self._fd, view)
                    view = view[n:]
            except OSError as exc:  # a full disk, a file-size limit: keep the file whole lines
                with contextlib.suppress(OSError):
                    os.ftruncate(self._fd, start)
                raise OSError(exc.errno, exc.strerror, str(self.path)) from None
            with self._synced_cv:
                self._written += 1
                self._synced_cv.notify_all()

    def sync(self) -> None:
        """Block until every record written so far is on disk (``fsync="always"``; at once
        otherwise). Raises ``OSError`` naming the file when an fsync failed."""
        if self._syncer is None:
            return
        with self._synced_cv:
            target = self._written
            while self._synced < target and self._sync_error is None:
                self._synced_cv.wait()
            self._raise_sync_error()

    async def durable(self) -> None:
        """:meth:`sync` in a worker thread, so the event loop goes on; returns without leaving
        the task when nothing is waiting for its fsync (always with ``fsync`` "close" or "never")."""
        if self._syncer is None:
            return
        with self._synced_cv:
            if self._synced >= self._written and self._sync_error is None:
                return
        import anyio.to_thread

        await anyio.to_thread.run_sync(self.sync)

    def _raise_sync_error(self) -> None:
        err = self._sync_error
        if err is not None:
            raise OSError(err.errno, f"fsync failed: {err.strerror}", str(self.path))

    def _sync_loop(self) -> None:
        """The writer's thread: fsync whenever records were written since the last fsync."""
        while True:
            with self._synced_cv:
                while self._synced >= self._written and not self._closing:
                    self._synced_cv.wait()
                if self._synced >= self._written:  # closing, nothing left
                    return
                target = self._written
                fd = self._fd
            assert fd is not None  # close() stops this thread before it closes the file
            try:
                os.fsync(fd)
            except OSError as exc:  # raised by the next write, sync or close
                with self._synced_cv:
                    self._sync_error = exc
                    self._synced_cv.notify_all()
                return
            with self._synced_cv:
                self._synced = max(self._synced, target)
                self._synced_cv.notify_all()

    def record_parsed(
        self, ref_seq: int, parsed_output: JsonValue, *, node: NodeName | None = None,
        error_type: str | None = None, error_message: str | None = None,
    ) -> None:
        self.write(ParsedRecord(run_id=self.run_id, seq=self.next_seq(), time_unix=time.time(),
                                ref_seq=ref_seq, node=node, parsed_output=parsed_output,
                                error_type=error_type, error_message=error_message))

    def record_applied(
        self, ref_seqs: Sequence[int], sim_frame: int, *, step: int | None = None,
        requested_frame: int | None = None,
    ) -> None:
        self.write(AppliedRecord(run_id=self.run_id, seq=self.next_seq(), time_unix=time.time(),
                                 ref_seqs=tuple(ref_seqs), step=step, requested_frame=requested_frame,
                                 sim_frame=sim_frame))

    def record_instruction(self, text: str, sim_frame: int, *, source: str) -> None:
        """A new instruction took effect at ``sim_frame``."""
        self.write(InstructionRecord(run_id=self.run_id, seq=self.next_seq(), time_unix=time.time(),
                                     text=text, source=source, sim_frame=sim_frame))

    def record_requested(self, step: int, sim_frame: int, *, phase: str, after_steps: Sequence[int]) -> None:
        """Planning step ``step`` was requested at ``sim_frame`` beside the steps ``after_steps``."""
        self.write(RequestedRecord.model_validate({
            "run_id": self.run_id, "seq": self.next_seq(), "time_unix": time.time(), "step": step,
            "sim_frame": sim_frame, "phase": phase, "after_steps": tuple(after_steps),
        }))

    def close(self) -> None:
        """Fsync (unless ``fsync="never"``) and close; raises the error of a failed fsync."""
        if self._syncer is not None:
            with self._synced_cv:
                self._closing = True
                self._synced_cv.notify_all()
            self._syncer.join()
        with self._lock:
            if self._fd is None:
                return
            try:
                if self.fsync != "never":
                    os.fsync(self._fd)
            except OSError as exc:
                with self._synced_cv:
                    self._sync_error = self._sync_error or exc
                    self._synced_cv.notify_all()
            else:
                with self._synced_cv:
                    self._synced = self._written
                    self._synced_cv.notify_all()
            finally:
                os.close(self._fd)
                self._fd = None
            self._raise_sync_error()

    def __enter__(self) -> TraceWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


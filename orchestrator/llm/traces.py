"""Append-only JSONL traces of every LLM call attempt, crash-safe, readable after a hard kill.

One line per record. Record kinds (``kind`` discriminator):

- ``run``: written when a writer opens the file (run id, wall-clock start, free-form meta);
- ``attempt``: one per LLM call attempt (success or failure), with the full request, the
  resolved model and parameters, response text, token usage, latency and error;
- ``parsed``: what the caller made of the response of attempt ``ref_seq``: the accepted
  output (narrator event, event-parser plans per character, describer areas) or the typed
  error that rejected it (``error_type``, ``error_message`` = the feedback sent back);
- ``applied``: the simulation frame at which one planning step's outcome took effect, with
  ``ref_seqs`` = the seqs of the attempts that produced it (the final attempt of every
  narrator and event-parser call of that step; all attempts of a call that failed outright);
- ``requested``: when a planning step was requested (frame, phase of the frame, the steps in
  flight beside it); written only by a session with more than one step in flight at once, so
  a replay makes every request at the same point;
- ``instruction``: a new instruction (``text``, from ``source``: a timed script, the Python
  API, stdin, ...) and the simulation frame it took effect at (before that frame's step);
  a replay applies the recorded ones at the same frames and ignores live sources.

Simulation frames: an attempt's ``request.sim_frame`` is the frame of the world snapshot the
request was built from (metadata: it is not part of ``request_hash``, so a replay matches
whatever frame it runs at); the ``applied`` record gives the frame its result was applied
at. ``storyteller plan`` runs no simulation, so its requests carry ``sim_frame: null`` and
it writes no ``applied`` records (consistently; there is no nominal frame).

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
records are fsynced at close only, with ``"never"`` not at all (``sync`` returns at once). Reading tolerates
and reports a torn last line; a bad line anywhere else raises :class:`TraceCorruptError`.
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
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, Protocol

import structlog
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    JsonValue,
    TypeAdapter,
    ValidationError,
    model_validator,
)

from agents.llm_port import LLMRequest, NodeName, TokenUsage, TraceRecorder
from orchestrator.llm.config import FsyncPolicy
from orchestrator.llm.retry_policy import ErrorClass
from sim.bounded_files import (
    MAX_OBJECT_KEYS,
    BoundedFileError,
    json_keys_exceed,
    read_bounded_bytes,
)
from sim.no_follow_writes import open_append
from sim.validation_text import problem_field, problem_message

_log = structlog.get_logger("storyteller.traces")


MAX_TRACE_BYTES = 256 << 20
"""Bytes of the largest trace file read (a recorded hour of story is tens of megabytes)."""
MAX_TRACE_RECORDS = 150_000
"""Records of the largest trace file read: each costs a validated model in memory (a 150-byte
record about 3 KB), so 500,000 tiny lines (75 MB) took 1.6 GB. A run of the longest allowed
duration (``orchestrator.session.run_manifest.MAX_DURATION_S``, 2.5 h) records about four per
planning step: 150,000 is 37,500 steps, one every 0.24 s."""


class _Record(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    run_id: str
    seq: int = Field(ge=0, description="Unique, increasing within one trace file.")
    time_unix: float = Field(description="Wall-clock time the record was written, seconds.")


class RunRecord(_Record):
    kind: Literal["run"] = "run"
    meta: dict[str, Any] = Field(default_factory=dict)


class AttemptRecord(_Record):
    """One attempt of one LLM call on one model."""

    kind: Literal["attempt"] = "attempt"
    call: int = Field(ge=0, description="Seq of the first attempt of the same logical call.")
    node: NodeName
    attempt: int = Field(ge=1, description="1-based attempt number within the call, all models.")
    model: str
    params: dict[str, Any] = Field(description="Resolved call parameters sent to the provider.")
    request: LLMRequest
    request_hash: str = Field(description="LLMRequest.content_hash() of ``request``.")
    response_text: str | None = None
    finish_reason: str | None = None
    parsed_output: Any = Field(default=None, description="Decoded JSON when a schema was set.")
    usage: TokenUsage | None = None
    latency_s: float = Field(ge=0.0, description="Wall time of this attempt, seconds.")
    error_type: str | None = None
    error_message: str | None = None
    error_class: ErrorClass | None = None
    final: bool = Field(description="True when this attempt's response was returned to the caller.")

    @property
    def ok(self) -> bool:
        return self.error_type is None


class ParsedRecord(_Record):
    kind: Literal["parsed"] = "parsed"
    ref_seq: int = Field(ge=0, description="Seq of the attempt whose response was parsed.")
    node: NodeName | None = None
    parsed_output: Any = Field(default=None, description="The accepted output (None when rejected).")
    error_type: str | None = Field(default=None, description="Type of the error that rejected the response.")
    error_message: str | None = Field(default=None, description="That error as fed back to the model.")

    @property
    def ok(self) -> bool:
        return self.error_type is None


class AppliedRecord(_Record):
    """When one planning step's outcome took effect in the simulation."""

    kind: Literal["applied"] = "applied"
    ref_seqs: tuple[int, ...] = Field(
        default=(), description="Seqs of the attempts that produced the outcome (empty: no LLM call, e.g. a resumed step)."
    )
    step: int | None = Field(default=None, ge=0, description="Planning step index.")
    requested_frame: int | None = Field(default=None, ge=0, description="Frame the step's request was made at.")
    sim_frame: int = Field(ge=0, description="Simulation frame at which the result took effect.")

    @model_validator(mode="before")
    @classmethod
    def _legacy_ref_seq(cls, data: Any) -> Any:
        """Traces written before ``ref_seqs`` held one ``ref_seq``."""
        if isinstance(data, dict) and "ref_seq" in data and "ref_seqs" not in data:
            data = dict(data)
            ref = data.pop("ref_seq")
            data["ref_seqs"] = [] if ref is None else [ref]
        return data


class RequestedRecord(_Record):
    """When one planning step was requested, beside which steps in flight (overlapping planning)."""

    kind: Literal["requested"] = "requested"
    step: int = Field(ge=0, description="Planning step index.")
    sim_frame: int = Field(ge=0, description="Frame the step's request was built at.")
    phase: Literal["frame_start", "frame_end"] = Field(
        description="frame_start: before that frame's outcomes were applied; frame_end: after the world stepped."
    )
    after_steps: tuple[int, ...] = Field(default=(), description="Steps in flight then (their characters left out).")


class InstructionRecord(_Record):
    """A new instruction (it replaces the one before) and the frame it took effect at."""

    kind: Literal["instruction"] = "instruction"
    text: str = Field(min_length=1)
    source: str = Field(description="Where it came from: script, api, stdin, replay, ...")
    sim_frame: int = Field(ge=0, description="Simulation frame it took effect at (before that frame's step).")


TraceRecord = Annotated[
    RunRecord | AttemptRecord | ParsedRecord | AppliedRecord | RequestedRecord | InstructionRecord,
    Field(discriminator="kind"),
]
_RECORD_ADAPTER: TypeAdapter[TraceRecord] = TypeAdapter(TraceRecord)


class TraceCorruptError(Exception):
    """A complete line of a trace file is not a valid record (``line_no`` None: the file cannot be
    read at all, e.g. it is larger than :data:`MAX_TRACE_BYTES` or not a regular file)."""

    def __init__(self, path: Path, line_no: int | None, message: str) -> None:
        self.path = path
        self.line_no = line_no
        if line_no is None:
            super().__init__(f"{path}: cannot read the trace ({message})")
        else:
            super().__init__(f"{path}: line {line_no}: corrupt trace record ({message})")


@dataclass(frozen=True)
class TornTail:
    """An incomplete last line (the writer died mid-record)."""

    line_no: int
    byte_offset: int
    size: int


@dataclass(frozen=True)
class TraceContents:
    records: list[TraceRecord]
    torn_tail: TornTail | None

    def attempts(self) -> Iterator[AttemptRecord]:
        return (r for r in self.records if isinstance(r, AttemptRecord))

    def parsed_by_seq(self) -> dict[int, list[ParsedRecord]]:
        """Attempt seq -> the parsed records about it (more than one after a resumed node)."""
        out: dict[int, list[ParsedRecord]] = {}
        for r in self.records:
            if isinstance(r, ParsedRecord):
                out.setdefault(r.ref_seq, []).append(r)
        return out

    def instructions(self) -> list[InstructionRecord]:
        """The instructions that took effect, in the order they did."""
        return [r for r in self.records if isinstance(r, InstructionRecord)]

    def requests(self) -> list[RequestedRecord]:
        """The ``requested`` records (runs with overlapping planning steps), in step order."""
        return sorted((r for r in self.records if isinstance(r, RequestedRecord)), key=lambda r: r.step)

    def applied_frame_by_seq(self) -> dict[int, int]:
        """Attempt seq -> the frame at which the outcome it contributed to was applied."""
        return {seq: r.sim_frame for r in self.records if isinstance(r, AppliedRecord) for seq in r.ref_seqs}


def _parse_line(path: Path, line_no: int, raw: bytes) -> TraceRecord:
    if json_keys_exceed(raw, MAX_OBJECT_KEYS):  # before pydantic builds an error per unknown key
        raise TraceCorruptError(path, line_no, f"more than {MAX_OBJECT_KEYS} keys in one record")
    try:
        return _RECORD_ADAPTER.validate_json(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc, message = problem_field(err), problem_message(err)
        raise TraceCorruptError(path, line_no, f"{loc}: {message}" if loc else message) from None


def read_trace(path: Path | str) -> TraceContents:
    """Read every complete record. A torn last line is reported in ``torn_tail`` (and logged).
    The file is read within :data:`MAX_TRACE_BYTES`; each line is validated by pydantic's JSON
    parser, which bounds nesting and integer size, and finite numbers only are accepted."""
    p = Path(path)
    try:
        data = read_bounded_bytes(p, MAX_TRACE_BYTES, str(p))
    except BoundedFileError as exc:
        if exc.missing:
            raise FileNotFoundError(2, "No such file or directory", str(p)) from None
        raise TraceCorruptError(p, None, exc.problem) from None
    lines = data.count(b"\n")
    if lines > MAX_TRACE_RECORDS:  # refused before a record is built
        raise TraceCorruptError(p, None, f"{lines} records, more than the {MAX_TRACE_RECORDS} a trace may hold")
    records: list[TraceRecord] = []
    start = 0
    line_no = 0
    torn: TornTail | None = None
    while start < len(data):
        line_no += 1
        end = data.find(b"\n", start)
        if end < 0:
            torn = TornTail(line_no=line_no, byte_offset=start, size=len(data) - start)
            _log.info("trace_torn_tail", path=str(p), line=line_no, bytes=torn.size)  # the caller says what it does with it
            break
        records.append(_parse_line(p, line_no, data[start:end]))
        start = end + 1
    return TraceContents(records=records, torn_tail=torn)


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
        :meth:`~agents.llm_port.TraceRecorder.sync`)."""
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


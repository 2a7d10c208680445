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

Reading (:func:`read_trace`) tolerates and reports a torn last line (a writer killed
mid-record); a bad line anywhere else raises :class:`TraceCorruptError`. Writing, and when a
record is on disk: :mod:`storyteller.orchestrator.llm.trace_writer`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import structlog
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    TypeAdapter,
    ValidationError,
    model_validator,
)

from storyteller.agents.llm_port import LLMRequest, NodeName, TokenUsage
from storyteller.orchestrator.llm.retry_policy import ErrorClass
from storyteller.sim.bounded_files import (
    MAX_OBJECT_KEYS,
    BoundedFileError,
    json_keys_exceed,
    read_bounded_bytes,
)
from storyteller.sim.validation_text import problem_field, problem_message

_log = structlog.get_logger("storyteller.traces")


MAX_TRACE_BYTES = 256 << 20
"""Bytes of the largest trace file read (a recorded hour of story is tens of megabytes)."""
MAX_TRACE_RECORDS = 150_000
"""Records of the largest trace file read: each costs a validated model in memory (a 150-byte
record about 3 KB), so 500,000 tiny lines (75 MB) took 1.6 GB. A run of the longest allowed
duration (``storyteller.orchestrator.session.run_manifest.MAX_DURATION_S``, 2.5 h) records about four per
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

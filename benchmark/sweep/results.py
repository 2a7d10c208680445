"""One line of ``results.jsonl`` per finished run, and the file's crash-safe append and rewrite.

A :class:`RunResult` is derived from the run's outcome, its verdict and its trace only (tokens
and latencies are the ones the trace recorded), never from the wall clock, so replaying the
trace gives the same line. Lines are appended with one ``os.write`` each and fsync'd
(:func:`append_result`); a sweep killed mid-write leaves at most one torn last line, which
:func:`read_results` drops (and :func:`repair_results` cuts off before appending again).
When a sweep completes, the file is rewritten in grid order (:func:`write_results`, atomic).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from storyteller.benchmark.sweep.sweep_files import (
    append_line,
    cut_torn_line,
    read_json_lines,
    write_sweep_file,
)

Verdict = Literal["pass", "fail", "error"]


class CallStat(BaseModel):
    """One logical LLM call of a run, as the trace recorded it (final attempt)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    node: str
    model: str
    attempts: int = Field(ge=1, description="Attempts the client made (transient errors retried).")
    prompt_tokens: int
    completion_tokens: int
    latency_s: float = Field(description="Summed over the call's attempts, seconds, rounded to 1 ms.")


class RunResult(BaseModel):
    """The verdict of one run of the grid (see :mod:`benchmark.plan_scoring`)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    run_id: str
    case_set: str
    case: int
    group: str = Field(description="The case's tags, e.g. 'OA+RC'.")
    characters: int = Field(description="Characters in the case at this level.")
    level: int
    repeat: int
    seed: int
    method: str
    description: str = Field(description="Scene description kind: describer, object-list or scene-graph.")
    model: str = Field(description="The model label of the sweep's model axis.")
    models: dict[str, str] = Field(description="The model of each role.")
    verdict: Verdict
    executed: bool = Field(description="A plan or a wait came out (no planning failure).")
    executed_first: bool = Field(description="Executed with every role's first reply accepted.")
    kind: str = Field(description="event, wait or failure")
    error_class: str | None = Field(description="Why it did not pass (None when it passed).")
    reason: str
    calls: tuple[CallStat, ...]
    prompt_tokens: int
    completion_tokens: int
    latency_s: float = Field(description="LLM latency of the run's calls, seconds (from the trace).")


def append_result(path: Path, result: RunResult) -> None:
    """Append one line and fsync it (a single ``os.write`` of the whole line; never through a link)."""
    append_line(path, result.model_dump_json().encode("utf-8") + b"\n")


def read_results(path: Path) -> list[RunResult]:
    """Every complete line (a torn last line, from a kill mid-write, is ignored); a line that is
    not a result is a :class:`~storyteller.benchmark.sweep.sweep_files.SweepFileError` naming it."""
    return read_json_lines(path, RunResult)


def repair_results(path: Path) -> None:
    """Cut a torn last line off ``path`` before appending to it."""
    cut_torn_line(path)


def write_atomic(path: Path, data: bytes) -> None:
    """Replace ``path`` with ``data`` (fresh temporary name, fsync, rename: never through a link)."""
    write_sweep_file(path, data)


def write_results(path: Path, results: Iterable[RunResult]) -> None:
    """Rewrite ``path`` with ``results`` (in the order given), atomically."""
    write_atomic(path, b"".join(r.model_dump_json().encode("utf-8") + b"\n" for r in results))


CSV_FIELDS = (
    "run_id", "case_set", "case", "group", "characters", "level", "repeat", "seed", "method", "description",
    "model", "verdict", "executed", "executed_first", "kind", "error_class", "calls", "prompt_tokens",
    "completion_tokens", "latency_s", "reason",
)


def results_csv(results: Sequence[RunResult]) -> bytes:
    """One row per run (``calls`` is the number of LLM calls; models per role are in the JSONL)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CSV_FIELDS)
    for r in results:
        row = r.model_dump()
        row["calls"] = len(r.calls)
        row["latency_s"] = f"{r.latency_s:.3f}"
        writer.writerow(["" if row[f] is None else row[f] for f in CSV_FIELDS])
    return buf.getvalue().encode("utf-8")

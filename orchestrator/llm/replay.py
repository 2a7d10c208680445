"""Replay LLM answers from a recorded trace, and the switch between live, record and replay.

:class:`ReplayClient` serves, for each (node, request hash), the responses that were returned
to the caller when the trace was recorded, in recorded order when the same request repeats.
A request that is not in the trace (or asked more often than recorded) raises
:class:`ReplayMissError` naming the node and showing a unified diff against the closest
recorded request of that node. It never falls through to a live call. Failed attempts of a
call that then succeeded are not replayed (only the answer returned matters to the run); a call
whose every attempt failed (the caller got an :class:`~storyteller.agents.llm_port.LLMError`: a context
window exceeded, a provider out of retries) is replayed as that error, with the same type and
message, so a run that failed a step replays to the same failure.

A call cut short by cancellation never got an answer. When the same request was asked again
later (a stopped run, resumed) the later answer is served. When it was not (the call was still
in flight when the recorded story ended, or the run was stopped for good), the request is
*unanswered*: with ``unanswered="wait"`` (a story session, whose end cancels the steps still in
flight) the replay asks it at the same simulation frame and it waits, as the recorded call did,
until the session ends and cancels it, so the step stays in flight to the end and the replay
ends with the recorded story (its own trace gets the cut attempts again, so it replays the
same); with ``"miss"`` (the default) and for a request at another frame it is a
:class:`ReplayMissError` saying the recorded call was never answered.
"""

from __future__ import annotations

import difflib
import json
import time
from collections import defaultdict, deque
from pathlib import Path
from typing import Literal

import anyio

from storyteller.agents.llm_port import (
    LLMError,
    LLMPort,
    LLMRequest,
    LLMResponse,
    NodeName,
    ReplayMissError,
    TokenUsage,
)
from storyteller.orchestrator.llm.config import ConfigError, StorytellerConfig
from storyteller.orchestrator.llm.retry_policy import failed_call_error, unavailable_error_names
from storyteller.orchestrator.llm.trace_writer import NullTraceSink, TraceSink, TraceWriter
from storyteller.orchestrator.llm.traces import AttemptRecord, TraceCorruptError, read_trace

_MAX_DIFF_LINES = 60


def render_request(request: LLMRequest) -> list[str]:
    """Human-readable lines of everything that enters the request hash."""
    lines: list[str] = []
    for i, m in enumerate(request.messages):
        lines.append(f"### message {i} ({m.role})")
        lines.extend(m.content.splitlines() or [""])
    if request.json_schema is not None:
        lines.append("### json_schema")
        lines.extend(json.dumps(request.json_schema, indent=1, sort_keys=True).splitlines())
    lines.append(f"### max_tokens={request.max_tokens} temperature={request.temperature} seed={request.seed}")
    return lines


def request_diff(recorded: LLMRequest, requested: LLMRequest, recorded_label: str) -> str:
    diff = list(difflib.unified_diff(
        render_request(recorded), render_request(requested),
        fromfile=recorded_label, tofile="requested", lineterm="", n=2,
    ))
    if len(diff) > _MAX_DIFF_LINES:
        diff = [*diff[:_MAX_DIFF_LINES], f"... ({len(diff) - _MAX_DIFF_LINES} more diff lines)"]
    return "\n".join(diff)


class ReplayClient:
    """:class:`agents.llm_port.LLMPort` that answers only from a trace file.

    With ``trace_sink`` set, every served answer is also written there as an attempt record
    (so a replayed run produces a trace of its own)."""

    def __init__(
        self,
        trace_path: Path | str,
        *,
        trace_sink: TraceSink | None = None,
        unanswered: Literal["miss", "wait"] = "miss",
    ) -> None:
        self.path = Path(trace_path)
        self.trace: TraceSink = trace_sink if trace_sink is not None else NullTraceSink()
        self.unanswered: Literal["miss", "wait"] = unanswered
        """What a request whose recorded call was cut short, never answered, gets (module doc)."""
        contents = read_trace(self.path)
        self._queues: dict[tuple[str, str], deque[AttemptRecord | tuple[AttemptRecord, ...]]] = defaultdict(deque)
        # cut short and not asked again after: (node, hash) -> the attempts of each such call
        self._cut: dict[tuple[str, str], deque[tuple[AttemptRecord, ...]]] = defaultdict(deque)
        self._recorded_counts: dict[tuple[str, str], int] = defaultdict(int)
        self._by_node: dict[NodeName, list[AttemptRecord]] = defaultdict(list)
        calls: dict[int, list[AttemptRecord]] = defaultdict(list)
        seen: set[tuple[str, str]] = set()
        for line_no, rec in enumerate(contents.records, start=1):
            if not isinstance(rec, AttemptRecord):
                continue
            if rec.request.content_hash() != rec.request_hash:
                raise TraceCorruptError(self.path, line_no, "request_hash does not match the recorded request")
            calls[rec.call].append(rec)
        for call in sorted(calls):
            attempts = calls[call]
            last = attempts[-1]
            outcome: AttemptRecord | tuple[AttemptRecord, ...] | None
            if last.final and last.ok and last.response_text is not None:
                outcome = last
            elif all(a.error_class is not None and not a.final for a in attempts):
                outcome = tuple(attempts)  # every attempt failed with an error the caller got
            else:  # cut short by cancellation: unanswered unless asked again later
                outcome = None
            key = (last.node, last.request_hash)
            if key not in seen:  # a miss is diffed against the closest of these
                seen.add(key)
                self._by_node[last.node].append(last)
            if outcome is None:
                self._cut[key].append(tuple(attempts))
                continue
            self._cut.pop(key, None)  # asked again after a stop (a resumed run): this answer counts
            self._queues[key].append(outcome)
            self._recorded_counts[key] += 1

    def recorded_nodes(self) -> frozenset[NodeName]:
        """The nodes whose requests the trace holds."""
        return frozenset(self._by_node)

    def remaining(self) -> int:
        """Recorded answers not served yet."""
        return sum(len(q) for q in self._queues.values())

    def unanswered_calls(self) -> int:
        """Recorded calls cut short and never answered, not asked for yet."""
        return sum(len(q) for q in self._cut.values())

    def _miss(self, request: LLMRequest, request_hash: str) -> ReplayMissError:
        key = (request.node, request_hash)
        where = f"trace {self.path}"
        cut = self._cut.get(key)
        if cut:
            first = cut[0][-1]
            why = (
                f"it was asked at frame {first.request.sim_frame}, this request at frame {request.sim_frame}"
                if self.unanswered == "wait"
                else "a replay without a story session does not wait for it"
            )
            return ReplayMissError(
                f"replay miss for node {request.node}: the recorded call of this request (hash "
                f"{request_hash[:12]}, seq {first.call} in {where}) was cut short and never answered; {why}",
                node=request.node,
            )
        if self._recorded_counts.get(key):
            n = self._recorded_counts[key]
            return ReplayMissError(
                f"replay miss for node {request.node}: this request (hash {request_hash[:12]}) was "
                f"recorded {n} time(s) in {where} and all have been served", node=request.node,
            )
        candidates = self._by_node.get(request.node, [])
        if not candidates:
            nodes = ", ".join(sorted(self._by_node)) or "none"
            return ReplayMissError(
                f"replay miss for node {request.node}: {where} holds no request of this node "
                f"(nodes recorded: {nodes})", node=request.node,
            )
        wanted = render_request(request)

        def similarity(rec: AttemptRecord) -> float:
            return difflib.SequenceMatcher(None, render_request(rec.request), wanted, autojunk=False).ratio()

        closest = max(candidates, key=similarity)
        diff = request_diff(closest.request, request, f"recorded (seq {closest.seq})")
        return ReplayMissError(
            f"replay miss for node {request.node}: request (hash {request_hash[:12]}) is not in {where}; "
            f"diff against the closest recorded request of that node:\n{diff}",
            node=request.node, diff=diff,
        )

    async def complete(self, request: LLMRequest) -> LLMResponse:
        request_hash = request.content_hash()
        queue = self._queues.get((request.node, request_hash))
        if not queue:
            cut = self._cut.get((request.node, request_hash))
            if self.unanswered == "wait" and cut and cut[0][-1].request.sim_frame == request.sim_frame:
                await self._never_answered(request, cut.popleft())
            raise self._miss(request, request_hash)
        outcome = queue.popleft()
        if isinstance(outcome, tuple):
            raise await self._failed_call(request, outcome)
        rec = outcome
        assert rec.response_text is not None
        seq = rec.seq
        if not isinstance(self.trace, NullTraceSink):
            seq = self.trace.next_seq()
            self.trace.write(rec.model_copy(update={
                "run_id": self.trace.run_id, "seq": seq, "call": seq, "attempt": 1,
                "time_unix": time.time(), "request": request,
                "params": {**rec.params, "replayed_from_seq": rec.seq},
            }))
            await self.trace.durable()
        return LLMResponse(
            text=rec.response_text, model=rec.model, usage=rec.usage or TokenUsage(),
            latency_s=rec.latency_s, attempts=rec.attempt, trace_seq=seq,
        )

    async def _never_answered(self, request: LLMRequest, attempts: tuple[AttemptRecord, ...]) -> None:
        """Wait as the recorded call did, until cancelled (the session's end); the cut attempts
        go to this run's trace then, as the live client writes them, so this run replays alike."""
        try:
            await anyio.sleep_forever()
        finally:
            if not isinstance(self.trace, NullTraceSink):
                seqs = [self.trace.next_seq() for _ in attempts]
                for a, seq in zip(attempts, seqs, strict=True):
                    self.trace.write(a.model_copy(update={
                        "run_id": self.trace.run_id, "seq": seq, "call": seqs[0], "time_unix": time.time(),
                        "request": request, "params": {**a.params, "replayed_from_seq": a.seq},
                    }))

    async def _failed_call(self, request: LLMRequest, attempts: tuple[AttemptRecord, ...]) -> LLMError:
        """The error the recorded call raised, rebuilt from its attempts as the live client
        builds it (same type, same message); the attempts go to this run's trace too."""
        seqs: list[int] = []
        if not isinstance(self.trace, NullTraceSink):
            for a in attempts:
                seq = self.trace.next_seq()
                seqs.append(seq)
                self.trace.write(a.model_copy(update={
                    "run_id": self.trace.run_id, "seq": seq, "call": seqs[0], "time_unix": time.time(),
                    "request": request, "params": {**a.params, "replayed_from_seq": a.seq},
                }))
            await self.trace.durable()
        else:
            seqs = [a.seq for a in attempts]
        names = unavailable_error_names()
        err = failed_call_error(
            request.node, [(a.model, a.error_type or "", a.error_message or "") for a in attempts],
            unavailable=all(a.error_type in names for a in attempts),
        )
        err.trace_seqs = tuple(seqs)
        return err

    def close(self) -> None:
        """Close the sink of the replayed run's own trace (when it records one)."""
        self.trace.close()


def build_llm_port(
    config: StorytellerConfig,
    record: Path | None = None,
    replay: Path | None = None,
    *,
    run_id: str | None = None,
    unanswered: Literal["miss", "wait"] = "miss",
) -> LLMPort:
    """The run's LLM port: live (optionally recording to ``record``) or replaying ``replay``
    (``unanswered``: what a recorded call cut short and never answered gets, see the module doc).

    Its ``trace`` (where callers record parsed outputs and applied frames) and ``close()`` are
    part of :class:`storyteller.agents.llm_port.LLMPort`. Raises :class:`ConfigError` when both paths name the same file."""
    if replay is not None:
        if record is not None and Path(record).resolve() == Path(replay).resolve():
            raise ConfigError("command line", "--record", "must name a different file than --replay")
        sink = TraceWriter(record, run_id=run_id, fsync=config.trace.fsync, meta={"mode": "replay", "replay": str(replay)}) if record else None
        return ReplayClient(replay, trace_sink=sink, unanswered=unanswered)
    from storyteller.orchestrator.llm.client import LiteLLMClient

    live_sink: TraceSink = (
        TraceWriter(record, run_id=run_id, fsync=config.trace.fsync, meta={"mode": "record", "config": config.source})
        if record else NullTraceSink(run_id)
    )
    return LiteLLMClient(config, live_sink)

"""The one LLM port every agent talks to: typed requests in, typed responses out.

Implementations live in ``orchestrator/`` (litellm client, trace recorder, trace replayer);
agents never import litellm or langgraph. A port also says where callers record what they
made of its answers (``trace``, or None when nothing is recorded) and releases what it holds
on ``close()``; so no caller has to probe a port with ``getattr``. A fake for tests needs
``complete`` plus two lines: ``trace = None`` and ``def close(self) -> None: pass``.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from typing import Any, ClassVar, Literal, Protocol, runtime_checkable

from pydantic import BaseModel, ConfigDict, Field, JsonValue

NodeName = Literal["describer", "narrator", "event_parser", "planner"]
LLMErrorKind = Literal["llm_error", "llm_unavailable", "replay_miss"]
"""``kind`` of an :class:`LLMError` (what a trace or a report calls the failure)."""


class ChatMessage(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    role: Literal["system", "user", "assistant"]
    content: str


class LLMRequest(BaseModel):
    """What an agent asks for. ``node`` selects the per-node model config."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    node: NodeName
    messages: tuple[ChatMessage, ...]
    json_schema: dict[str, Any] | None = Field(
        default=None, description="When set, the reply must be one JSON value of this schema."
    )
    max_tokens: int | None = Field(default=None, gt=0)
    temperature: float | None = Field(default=None, ge=0.0)
    seed: int | None = None
    sim_frame: int | None = Field(default=None, description="Simulation frame when the request was made.")
    grammar: str | None = Field(
        default=None,
        description="GBNF grammar the reply must follow; local llama.cpp models decode under it, "
        "other providers ignore it.",
    )
    choices: tuple[str, ...] | None = Field(
        default=None,
        max_length=64,
        description="A choice among these continuations: a local model scores each one's "
        "log-likelihood as the whole reply (one prompt, no generation); other providers answer "
        "under json_schema, which must admit exactly these (agents.scored_choice builds both).",
    )

    def content_hash(self) -> str:
        """Hash of everything that determines the answer (not the sim frame; no grammar or
        choices key when there is none, so requests made before those existed keep their hash)."""
        unset = {k for k in ("grammar", "choices") if getattr(self, k) is None}
        payload = self.model_dump(mode="json", exclude={"sim_frame"} | unset)
        blob = json.dumps(payload, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
        return hashlib.sha256(blob.encode("utf-8")).hexdigest()


class TokenUsage(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    prompt_tokens: int = 0
    completion_tokens: int = 0


class LLMResponse(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    text: str
    model: str
    usage: TokenUsage = TokenUsage()
    latency_s: float = 0.0
    attempts: int = 1
    trace_seq: int | None = Field(
        default=None,
        description="Seq of the trace record holding this response (for parsed/applied records).",
    )


class TraceRecorder(Protocol):
    """Where callers record what became of an answer the port traced (``trace_seq``).

    The orchestrator's trace sinks implement it (and more: attempt records, seq numbering)."""

    def record_parsed(
        self, ref_seq: int, parsed_output: JsonValue, *, node: NodeName | None = None,
        error_type: str | None = None, error_message: str | None = None,
    ) -> None:
        """The output accepted from attempt ``ref_seq``, or the error that rejected it
        (``error_message`` = the feedback sent back to the model)."""
        ...

    def record_applied(
        self, ref_seqs: Sequence[int], sim_frame: int, *, step: int | None = None,
        requested_frame: int | None = None,
    ) -> None:
        """The simulation frame at which the outcome built from attempts ``ref_seqs`` took effect."""
        ...

    def sync(self) -> None:
        """Block until every record so far is as durable as the recorder promises (a trace file
        with fsync "always": on disk). Callers run it off the event loop, before they write
        anything durable that counts on those records (e.g. a step's outcome)."""
        ...


@runtime_checkable
class LLMPort(Protocol):
    async def complete(self, request: LLMRequest) -> LLMResponse: ...

    @property
    def trace(self) -> TraceRecorder | None:
        """Where callers record parsed outputs and applied frames for this port's answers
        (None: the port records nothing)."""
        ...

    def close(self) -> None:
        """Release what the port holds (flush and close its trace file). Safe to call twice."""
        ...


class LLMError(Exception):
    """The LLM could not produce an answer (after the configured retries and fallbacks).

    ``trace_seqs``: seqs of the traced attempts of the failed call (set by the client)."""

    kind: ClassVar[LLMErrorKind] = "llm_error"
    trace_seqs: tuple[int, ...] = ()


class LLMUnavailableError(LLMError):
    """No model is usable (weights missing, no API key...). The message says how to fix it."""

    kind: ClassVar[LLMErrorKind] = "llm_unavailable"


class ReplayMissError(LLMError):
    """A replayed run asked for a request that the trace does not hold."""

    kind: ClassVar[LLMErrorKind] = "replay_miss"

    def __init__(self, message: str, *, node: str | None = None, diff: str | None = None) -> None:
        super().__init__(message)
        self.node = node
        self.diff = diff

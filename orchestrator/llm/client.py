"""The LLM port over litellm: per-node models, our own retries, fallbacks, one trace record per attempt.

A request with ``choices`` (a choice among candidates, :mod:`storyteller.agents.scored_choice`) goes to the
embedded model as scored continuations (``response_format`` ``{"type": "choices"}``: the local
provider reads the log-likelihood of each choice from the model's logits); any other provider
gets the request's JSON schema, whose enum admits only the choices (constrained generation).
Either way the reply is the JSON the schema describes, so traces and replays treat it alike.

For each request the node's models are tried in order (primary, then fallbacks). On each
model, transient errors are retried up to ``retry.max_attempts`` attempts in total, waiting
an exponential, jittered, seeded delay between attempts; a permanent error (400, 401, 403,
404, 422, missing weights or key) moves on to the next model at once. The deterministic
embedded model is retried only when the machine was short of memory or a file
(:mod:`storyteller.orchestrator.llm.local_errors`): an unusable answer or a call stopped for lack of
progress would only come again, so they move on to the next model at once. litellm's own retries
are disabled (``max_retries=0``, never ``num_retries``).

Secrets stay secret: every reply, trace record and error this client produces has the known
secret values (``storyteller.orchestrator.llm.secrets``: the ``api_key_env`` variables and every secret-named
environment variable) replaced by ``[redacted]``, so a provider echoing the key it was sent puts
it in no trace, story or message.
"""

from __future__ import annotations

import json
import os
import time
import warnings
from collections.abc import Awaitable, Callable
from typing import Any

os.environ.setdefault("LITELLM_LOCAL_MODEL_COST_MAP", "True")

import anyio
import litellm
import structlog

from storyteller.agents.llm_port import LLMError, LLMRequest, LLMResponse, LLMUnavailableError, TokenUsage
from storyteller.agents.llm_schemas import schema_instruction
from storyteller.orchestrator.llm.config import NodeConfig, StorytellerConfig
from storyteller.orchestrator.llm.local_errors import LocalModelStalledError
from storyteller.orchestrator.llm.local_model import (
    ensure_local_model_available,
    local_timeout_s,
    register_local_provider,
)
from storyteller.orchestrator.llm.retry_policy import (
    ErrorClass,
    InvalidResponseError,
    RetryPolicy,
    classify_error,
    failed_call_error,
)
from storyteller.orchestrator.llm.secrets import redact, secret_values
from storyteller.orchestrator.llm.trace_writer import NullTraceSink, TraceSink
from storyteller.orchestrator.llm.traces import AttemptRecord

litellm.suppress_debug_info = True


def _prebuild_litellm_models() -> None:
    """Build litellm's lazily-validated response models once, with warnings silenced: pydantic
    warns (UserWarning) that some litellm TypedDicts use ``ReadOnly``, which is harmless but
    would otherwise surface in the middle of the first call (and fail warning-strict tests)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        litellm.ModelResponse(
            choices=[{"index": 0, "finish_reason": "stop", "message": {"role": "assistant", "content": "x"}}],
            usage={"prompt_tokens": 1, "completion_tokens": 1, "total_tokens": 2},
        )


_prebuild_litellm_models()
_log = structlog.get_logger("storyteller.llm")

Completion = Callable[..., Awaitable[Any]]
Sleep = Callable[[float], Awaitable[None]]


def provider_of(model: str) -> str:
    """The litellm provider prefix of a model name (``openai/gpt-4o`` -> ``openai``)."""
    return model.split("/", 1)[0] if "/" in model else ""


def response_format_for(model: str, schema: dict[str, Any]) -> tuple[dict[str, Any], bool]:
    """The ``response_format`` to send for a JSON-schema request, and whether the schema must
    also be stated in the prompt (providers that only know plain JSON mode)."""
    if provider_of(model) == "local":
        # llama.cpp turns this into a grammar; the OpenAI json_schema form is ignored in-process.
        return {"type": "json_object", "schema": schema}, False
    try:
        native = litellm.supports_response_schema(model=model)
    except Exception:  # litellm reports unknown models by raising on some versions
        native = False
    if native:
        return {"type": "json_schema", "json_schema": {"name": "reply", "schema": schema}}, False
    return {"type": "json_object"}, True


def _schema_instruction(schema: dict[str, Any]) -> dict[str, str]:
    return {"role": "system", "content": schema_instruction(schema)}


class LiteLLMClient:
    """:class:`agents.llm_port.LLMPort` over ``litellm.acompletion``.

    ``acompletion`` and ``sleep`` are injectable (tests use a fake provider and no real
    sleeping); ``clock`` measures latency in seconds.
    """

    def __init__(
        self,
        config: StorytellerConfig,
        trace_sink: TraceSink | None = None,
        *,
        acompletion: Completion | None = None,
        sleep: Sleep = anyio.sleep,
        clock: Callable[[], float] = time.perf_counter,
        check_local: Callable[[str], None] = ensure_local_model_available,
    ) -> None:
        self.config = config
        self.trace: TraceSink = trace_sink if trace_sink is not None else NullTraceSink()
        self._acompletion = acompletion or litellm.acompletion
        self._sleep = sleep
        self._clock = clock
        self._check_local = check_local
        register_local_provider()

    def close(self) -> None:
        """Close the trace sink (a file writer flushes and closes its file)."""
        self.trace.close()

    def _params(self, node: NodeConfig, model: str, request: LLMRequest) -> tuple[dict[str, Any], bool]:
        max_tokens = node.max_tokens if request.max_tokens is None else min(request.max_tokens, node.max_tokens)
        timeout = node.timeout_s
        if provider_of(model) == "local" and "timeout_s" not in node.model_fields_set:
            prompt_chars = sum(len(m.content) for m in request.messages)
            timeout = local_timeout_s(model, prompt_chars, max_tokens, floor_s=node.timeout_s)
        params: dict[str, Any] = {
            "temperature": node.temperature if request.temperature is None else request.temperature,
            "max_tokens": max_tokens,
            "timeout": timeout,
        }
        if request.seed is not None:
            params["seed"] = request.seed
        if node.api_base:
            params["api_base"] = node.api_base
        schema_in_prompt = False
        if request.choices is not None and provider_of(model) == "local":
            # scored continuations: the provider reads the model's log-likelihood of each choice
            params["response_format"] = {"type": "choices", "choices": list(request.choices)}
        elif request.json_schema is not None:  # (a choice elsewhere: the schema's enum constrains it)
            params["response_format"], schema_in_prompt = response_format_for(model, request.json_schema)
        elif request.grammar is not None and provider_of(model) == "local":
            params["response_format"] = {"type": "gbnf", "grammar": request.grammar}
        return params, schema_in_prompt

    def _api_key(self, node: NodeConfig) -> str | None:
        if node.api_key_env is None:
            return None
        key = os.environ.get(node.api_key_env)
        if not key:
            raise LLMUnavailableError(
                f"environment variable {node.api_key_env} (api_key_env in {self.config.source}) is not set"
            )
        return key

    async def _ask(self, node: NodeConfig, model: str, messages: list[dict[str, Any]], params: dict[str, Any]) -> Any:
        """One provider call for ``node`` on ``model`` (litellm's own retries off): its raw response."""
        api_key = self._api_key(node)
        if provider_of(model) == "local":
            self._check_local(model)
        return await self._acompletion(
            model=model, messages=messages, max_retries=0, drop_params=True,
            **({"api_key": api_key} if api_key else {}), **params,
        )

    async def complete(self, request: LLMRequest) -> LLMResponse:
        node = self.config.node(request.node)
        secrets = secret_values(n.api_key_env for n in self.config.nodes.values() if n.api_key_env)
        request_hash = request.content_hash()
        messages = [m.model_dump() for m in request.messages]
        call_seq = -1  # seq of the first attempt, set below
        seqs: list[int] = []
        attempt_no = 0
        failures: list[tuple[str, BaseException]] = []
        for model_index, model in enumerate(node.models):
            policy = RetryPolicy(node.retry, salt=model_index)
            params, schema_in_prompt = self._params(node, model, request)
            sent = [*messages, _schema_instruction(request.json_schema)] if schema_in_prompt and request.json_schema else messages
            for k in range(policy.max_attempts):
                if k > 0:
                    await self._sleep(policy.delay_s(k))
                attempt_no += 1
                seq = self.trace.next_seq()
                seqs.append(seq)
                if call_seq < 0:
                    call_seq = seq

                traced_params = {**params, "schema_in_prompt": True} if schema_in_prompt else params
                local_threads: dict[str, Any] | None = None

                def record(**fields: Any) -> None:
                    for name in ("response_text", "error_message"):
                        if fields.get(name) is not None:
                            fields[name] = redact(fields[name], secrets)
                    sent_params = traced_params if local_threads is None else {  # noqa: B023
                        **traced_params, "local_threads": local_threads}  # noqa: B023
                    self.trace.write(AttemptRecord(
                        run_id=self.trace.run_id, seq=seq, time_unix=time.time(), call=call_seq,  # noqa: B023
                        node=request.node, attempt=attempt_no, model=model, params=sent_params,  # noqa: B023
                        request=request, request_hash=request_hash, **fields,
                    ))

                t0 = self._clock()
                text: str | None = None
                finish: str | None = None
                usage: TokenUsage | None = None
                try:
                    raw = await self._ask(node, model, sent, params)
                    local_threads = _local_threads(raw)
                    text, finish, usage = _extract(raw)
                    text = redact(text, secrets)
                    parsed = _validate(text, finish, request)
                except Exception as exc:
                    latency = self._clock() - t0
                    if isinstance(exc, LocalModelStalledError):
                        local_threads = exc.local_threads
                    klass = _error_class(exc, model)
                    record(response_text=text, finish_reason=finish, usage=usage, latency_s=latency,
                           error_type=type(exc).__name__, error_message=str(exc)[:2000],
                           error_class=klass, final=False)
                    failures.append((model, exc))
                    _log.warning("llm_attempt_failed", node=request.node, model=model, attempt=attempt_no,
                                 error=type(exc).__name__, error_class=klass)
                    if klass == "permanent":
                        break
                    continue
                except BaseException as exc:  # cancellation: trace it, then let it through
                    record(latency_s=self._clock() - t0, error_type=type(exc).__name__,
                           error_message=str(exc)[:2000], final=False)
                    raise
                latency = self._clock() - t0
                assert text is not None
                record(response_text=text, finish_reason=finish, parsed_output=parsed, usage=usage,
                       latency_s=latency, final=True)
                await self.trace.durable()  # on disk before the caller checkpoints what it made of it
                return LLMResponse(text=text, model=model, usage=usage, latency_s=latency,
                                   attempts=attempt_no, trace_seq=seq)
        err = _final_error(request, failures, secrets)
        err.trace_seqs = tuple(seqs)
        await self.trace.durable()
        raise err


def _error_class(exc: Exception, model: str) -> ErrorClass:
    """How a failed attempt on ``model`` is retried (:func:`classify_error`; a model that cannot
    be used at all, :class:`LLMUnavailableError`, is permanent)."""
    if isinstance(exc, LLMUnavailableError):
        return "permanent"
    return classify_error(exc, local=provider_of(model) == "local")


def _local_threads(raw: Any) -> dict[str, Any] | None:
    """The thread choice the embedded model's provider attached to its answer (None for others)."""
    hidden = raw._hidden_params if isinstance(raw, litellm.ModelResponse) else None
    value = hidden.get("local_threads") if isinstance(hidden, dict) else None
    return value if isinstance(value, dict) else None


def _extract(raw: Any) -> tuple[str, str | None, TokenUsage]:
    try:
        choice = raw.choices[0]
        text = choice.message.content or ""
        finish = getattr(choice, "finish_reason", None)
    except (AttributeError, IndexError, TypeError) as exc:
        raise InvalidResponseError(f"malformed provider response ({exc})") from None
    u = getattr(raw, "usage", None)
    usage = TokenUsage(
        prompt_tokens=int(getattr(u, "prompt_tokens", 0) or 0),
        completion_tokens=int(getattr(u, "completion_tokens", 0) or 0),
    )
    return text, finish, usage


def _validate(text: str, finish: str | None, request: LLMRequest) -> Any:
    """Decoded JSON for schema requests (None otherwise). Raises InvalidResponseError."""
    if not text.strip():
        raise InvalidResponseError("empty response", text)
    if request.json_schema is None:
        return None
    if finish == "length":
        raise InvalidResponseError("JSON response truncated at max_tokens", text)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InvalidResponseError(f"response is not valid JSON ({exc})", text) from None


def _final_error(request: LLMRequest, failures: list[tuple[str, BaseException]], secrets: tuple[str, ...] = ()) -> LLMError:
    """The error a failed call raises; its message and cause name no secret value."""
    err = failed_call_error(
        request.node, [(model, type(exc).__name__, redact(str(exc), secrets)) for model, exc in failures],
        unavailable=bool(failures) and all(isinstance(e, LLMUnavailableError) for _, e in failures),
    )
    if failures:
        cause = failures[-1][1]
        # a cause quoting a secret (in its message or arguments) is left off: a traceback would show it
        if all(redact(str(part), secrets) == str(part) for part in (cause, *cause.args)):
            err.__cause__ = cause
        else:
            err.__suppress_context__ = True
    return err

"""The embedded model as a litellm custom provider ``local`` (llama-cpp-python, in process).

Model names: ``local/qwen2.5-coder-0.5b`` (default) and ``local/qwen2.5-coder-1.5b``. Up to
:data:`PREFIX_SLOTS` ``llama_cpp.Llama`` instances per model per process, created lazily, one
per role's system prompt (:func:`get_llama`): llama.cpp reuses the longest common prompt prefix
held in an instance's KV cache, so with narrator and parser calls taking turns each role's
stable prefix (rules, examples, scene description) is evaluated once per story, not per call. No ``LlamaRAMCache``: it snapshots whole
states, each holding n_ctx x vocab logits (GBs with Qwen's 152k vocab).

Calls are serialised per model (a Llama object is not thread-safe) and run in a worker
thread so the event loop (and the simulation) keeps running. Generation is streamed so a
deadline derived from the call's timeout, or a cancellation, stops it between two tokens.

Default timeout: a node whose config does not set ``timeout_s`` gets, for a local model,
:func:`local_timeout_s` of the request: the expected time on an idle machine (prompt
characters / 3 as tokens at the measured prompt speed, plus ``max_tokens`` at the measured
generation speed) times :data:`LOAD_MARGIN`, plus :data:`BASE_TIMEOUT_S`, and never less
than the configured default. A loaded machine (several processes on 2 cores) can be that
much slower; ``max_tokens`` still bounds a runaway generation.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

os.environ.setdefault("LITELLM_LOCAL_MODEL_COST_MAP", "True")

import anyio
import litellm
from litellm import ModelResponse
from litellm.exceptions import (
    ContextWindowExceededError,
    InternalServerError,
    NotFoundError,
    Timeout,
)
from litellm.llms.custom_llm import CustomLLM

from agents.llm_port import LLMUnavailableError
from orchestrator.llm.model_weights import (
    WeightsSpec,
    ensure_weights,
    spec_for,
    verified_weights_path,
)

N_CTX = 4096
N_THREADS = int(os.environ.get("STORYTELLER_LOCAL_THREADS", "2"))  # llama.cpp threads
SEED = 1234
MAX_TOKENS_CAP = 2048
DEFAULT_ARRAY_MAX_ITEMS = 64

MEASURED_TOK_S: dict[str, tuple[float, float]] = {
    "qwen2.5-coder-0.5b": (150.0, 37.0),
    "qwen2.5-coder-1.5b": (70.0, 21.0),
}
"""(prompt, generated) tokens per second with 2 threads on an idle machine (DESIGN.md)."""
LOAD_MARGIN = 10.0
BASE_TIMEOUT_S = 30.0
CHARS_PER_TOKEN = 3.0

PREFIX_SLOTS = max(1, int(os.environ.get("STORYTELLER_LOCAL_PREFIX_SLOTS", "3")))
"""Llama instances per model, each keeping the KV cache of the last prompt it saw."""


@dataclass
class _Pool:
    """The instances of one model: by prompt key (the system message), least recently used
    first, and the lock that serialises every call to the model."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    slots: OrderedDict[str, Any] = field(default_factory=OrderedDict)


_load_lock = threading.Lock()
_instances: dict[str, _Pool] = {}


class _Abort(Exception):
    """Raised between two streamed tokens to stop a generation (deadline or cancellation)."""


def ensure_local_model_available(model: str) -> None:
    """Raise :class:`LLMUnavailableError` (with install instructions) unless the weights verify
    and llama-cpp-python imports. Cheap after the first call (stamp check)."""
    spec = spec_for(model)
    try:
        import llama_cpp  # noqa: F401
    except ImportError:
        raise LLMUnavailableError(
            f"llama-cpp-python is not installed, so local/{spec.model} cannot run; install it "
            "with `pip install -e '.[local]'`, or point the node at an API model in the config"
        ) from None
    ensure_weights(spec)


def local_timeout_s(model: str, prompt_chars: int, max_tokens: int, floor_s: float) -> float:
    """Default per-attempt timeout of a local model for a prompt of ``prompt_chars``
    characters and ``max_tokens`` generated tokens (see the module doc); at least ``floor_s``."""
    prompt_rate, gen_rate = MEASURED_TOK_S.get(model.removeprefix("local/"), MEASURED_TOK_S["qwen2.5-coder-1.5b"])
    idle_s = prompt_chars / CHARS_PER_TOKEN / prompt_rate + max_tokens / gen_rate
    return round(max(floor_s, BASE_TIMEOUT_S + LOAD_MARGIN * idle_s), 1)


def bound_arrays(schema: Any, max_items: int = DEFAULT_ARRAY_MAX_ITEMS) -> Any:
    """A copy of a JSON schema where every array without ``maxItems`` gets one.

    An unbounded array lets a small model loop until ``max_tokens``; a bound makes the
    grammar close the array."""
    if isinstance(schema, dict):
        out = {k: bound_arrays(v, max_items) for k, v in schema.items()}
        if out.get("type") == "array" and "maxItems" not in out:
            out["maxItems"] = max_items
        return out
    if isinstance(schema, list):
        return [bound_arrays(v, max_items) for v in schema]
    return schema


@contextmanager
def plain_cpu_buffers() -> Iterator[None]:
    """Load models with llama.cpp's plain CPU weight buffers (``use_extra_bufts`` off).

    llama-cpp-python builds llama.cpp with ``-march=native``; on a CPU with AMX (Intel Sapphire
    Rapids and later) the weights are then repacked into an AMX buffer whose matrix product
    segfaults on the first decode of our Q4_K_M files (llama.cpp issue 20824, closed unfixed).
    Repacking also makes the model's output depend on the machine's instruction set. Measured
    on a 2-core Xeon with AMX: 200 prompt tokens/s and 25 generated tokens/s with and without
    the extra buffers, so nothing is lost by turning them off everywhere.

    ``Llama()`` takes no switch for it and builds its parameters from
    ``llama_model_default_params()`` inside its constructor, so that function is wrapped for the
    duration of the load (callers hold ``_load_lock``; nothing else loads a model meanwhile)."""
    try:
        import llama_cpp.llama_cpp as bindings
    except ImportError:  # a stand-in ``llama_cpp`` (tests) has no C bindings to configure
        yield
        return
    original = bindings.llama_model_default_params

    def defaults_without_repacking() -> Any:
        params = original()
        if hasattr(params, "use_extra_bufts"):
            params.use_extra_bufts = False
        return params

    bindings.llama_model_default_params = defaults_without_repacking
    try:
        yield
    finally:
        bindings.llama_model_default_params = original


def get_llama(spec: WeightsSpec, key: str = "") -> tuple[Any, threading.Lock]:
    """A Llama instance for ``spec`` and the lock that serialises the model's use.

    Calls with the same ``key`` (the prompt's stable system message) go to the same instance,
    whose KV cache still holds that prefix: a narrator call after a parser call evaluates only
    its new tokens instead of its whole prompt. There are at most :data:`PREFIX_SLOTS`
    instances per model (they share the memory-mapped weights; each adds its KV cache); a new
    key takes the least recently used one over.

    The weights file is sha256-checked in full right before an instance is loaded (the stamp
    alone does not see in-place edits); a mismatch raises :class:`WeightsIntegrityError`."""
    with _load_lock:
        pool = _instances.get(spec.model)
        if pool is not None and key in pool.slots:
            pool.slots.move_to_end(key)
            return pool.slots[key], pool.lock
        if pool is None or len(pool.slots) < PREFIX_SLOTS:
            from llama_cpp import Llama

            path = verified_weights_path(spec)
            with plain_cpu_buffers():
                llm = Llama(
                    model_path=str(path), n_ctx=N_CTX, n_threads=N_THREADS,
                    n_threads_batch=N_THREADS, seed=SEED, n_gpu_layers=0, verbose=False,
                )
            pool = _instances.setdefault(spec.model, _Pool())
        else:
            _, llm = pool.slots.popitem(last=False)
        pool.slots[key] = llm
        return llm, pool.lock


def prompt_key(messages: list[dict[str, Any]]) -> str:
    """The routing key of a chat: a digest of its system message ("" without one)."""
    first = messages[0] if messages else {}
    if first.get("role") != "system":
        return ""
    return hashlib.sha256(str(first.get("content", "")).encode()).hexdigest()[:16]


def loaded_models() -> list[str]:
    return sorted(_instances)


@atexit.register
def close_models() -> None:
    """Free every loaded model while the interpreter can still run llama.cpp's destructors
    (left to ``__del__`` at shutdown they fail noisily on half-torn-down modules)."""
    with _load_lock:
        while _instances:
            _, pool = _instances.popitem()
            with pool.lock:
                for llm in pool.slots.values():
                    llm.close()


def _chat_blocking(
    spec: WeightsSpec, messages: list[dict[str, Any]], params: dict[str, Any], timeout_s: float,
    cancel: threading.Event,
) -> dict[str, Any]:
    """Run one chat completion, token by token, stopping after ``timeout_s`` seconds (counted
    from when the model is loaded and free, so queueing behind another call or loading the
    weights does not count) or when ``cancel`` is set (raises :class:`_Abort`). Returns an
    OpenAI-shaped dict.

    Streaming is what makes the abort possible: exceptions raised in llama.cpp sampler
    callbacks are swallowed by ctypes. Usage: completion tokens = streamed content pieces,
    prompt tokens = tokens in the context afterwards minus those."""
    llm, lock = get_llama(spec, prompt_key(messages))
    with lock:
        deadline = time.monotonic() + timeout_s
        pieces: list[str] = []
        finish: str | None = None
        stream = llm.create_chat_completion(messages=messages, stream=True, **params)
        try:
            for chunk in stream:
                if cancel.is_set() or time.monotonic() > deadline:
                    raise _Abort
                choice = chunk["choices"][0]
                content = choice["delta"].get("content")
                if content:
                    pieces.append(content)
                finish = choice.get("finish_reason") or finish
        finally:
            stream.close()
        completion_tokens = len(pieces)
        prompt_tokens = max(0, int(llm.n_tokens) - completion_tokens)
    return {
        "id": "local",
        "choices": [{"index": 0, "finish_reason": finish or "stop",
                     "message": {"role": "assistant", "content": "".join(pieces)}}],
        "usage": {"prompt_tokens": prompt_tokens, "completion_tokens": completion_tokens,
                  "total_tokens": prompt_tokens + completion_tokens},
    }


def _llama_params(optional_params: dict[str, Any]) -> dict[str, Any]:
    max_tokens = optional_params.get("max_tokens") or optional_params.get("max_completion_tokens") or 512
    params: dict[str, Any] = {
        "temperature": float(optional_params.get("temperature", 0.0) or 0.0),
        "max_tokens": max(1, min(int(max_tokens), MAX_TOKENS_CAP)),
        "seed": int(optional_params.get("seed", SEED)),
    }
    fmt = optional_params.get("response_format")
    if isinstance(fmt, dict) and fmt.get("type") == "gbnf":
        from llama_cpp.llama_grammar import LlamaGrammar

        try:
            params["grammar"] = LlamaGrammar.from_string(str(fmt.get("grammar", "")), verbose=False)
        except ValueError as exc:
            raise ValueError(f"bad GBNF grammar in the request: {exc}") from None
    elif isinstance(fmt, dict):
        if fmt.get("type") == "json_schema" and isinstance(fmt.get("json_schema"), dict):
            fmt = {"type": "json_object", "schema": fmt["json_schema"].get("schema", {})}
        if isinstance(fmt.get("schema"), dict):
            fmt = {**fmt, "schema": bound_arrays(fmt["schema"])}
        params["response_format"] = fmt
    if optional_params.get("stop"):
        params["stop"] = optional_params["stop"]
    return params


class LocalLlamaProvider(CustomLLM):
    """litellm ``CustomLLM`` serving ``local/<model>`` with llama.cpp."""

    def __init__(
        self,
        chat: Callable[..., dict[str, Any]] = _chat_blocking,
        check: Callable[[str], None] = ensure_local_model_available,
    ) -> None:
        super().__init__()
        self._chat = chat
        self._check = check

    def _spec(self, model: str) -> WeightsSpec:
        try:
            spec = spec_for(model)
            self._check(model)
        except LLMUnavailableError as exc:
            raise NotFoundError(message=str(exc), llm_provider="local", model=model) from None
        return spec

    @staticmethod
    def _timeout(timeout: Any) -> float:
        if isinstance(timeout, int | float) and timeout > 0:
            return float(timeout)
        read = getattr(timeout, "read", None)
        return float(read) if isinstance(read, int | float) and read > 0 else 600.0

    def _to_response(self, model: str, out: dict[str, Any]) -> ModelResponse:
        choice = out["choices"][0]
        usage = out.get("usage") or {}
        return ModelResponse(
            id=out.get("id"), model=model,
            choices=[{"index": 0, "finish_reason": choice.get("finish_reason") or "stop",
                      "message": {"role": "assistant", "content": choice["message"].get("content") or ""}}],
            usage={"prompt_tokens": usage.get("prompt_tokens", 0),
                   "completion_tokens": usage.get("completion_tokens", 0),
                   "total_tokens": usage.get("total_tokens", 0)},
        )

    def _map_error(self, model: str, exc: BaseException, timeout_s: float) -> Exception:
        if isinstance(exc, _Abort):
            return Timeout(message=f"local model exceeded {timeout_s:.1f} s", model=model, llm_provider="local")
        if isinstance(exc, ValueError) and "context window" in str(exc):
            return ContextWindowExceededError(message=str(exc), model=model, llm_provider="local")
        return InternalServerError(message=f"{type(exc).__name__}: {exc}", llm_provider="local", model=model)

    async def acompletion(self, model: str, messages: list[Any], api_base: str, custom_prompt_dict: dict[str, Any],
                          model_response: ModelResponse, print_verbose: Callable[..., Any], encoding: Any, api_key: Any,
                          logging_obj: Any, optional_params: dict[str, Any], acompletion: Any = None,
                          litellm_params: Any = None, logger_fn: Any = None, headers: Any = None,
                          timeout: Any = None, client: Any = None) -> ModelResponse:
        spec = self._spec(model)
        timeout_s = self._timeout(timeout)
        params = _llama_params(optional_params)
        cancel = threading.Event()
        try:
            out = await anyio.to_thread.run_sync(
                lambda: self._chat(spec, list(messages), params, timeout_s, cancel), abandon_on_cancel=True
            )
        except BaseException as exc:
            cancel.set()
            if isinstance(exc, Exception):
                raise self._map_error(model, exc, timeout_s) from exc
            raise
        return self._to_response(model, out)

    def completion(self, model: str, messages: list[Any], api_base: str, custom_prompt_dict: dict[str, Any],
                   model_response: ModelResponse, print_verbose: Callable[..., Any], encoding: Any, api_key: Any,
                   logging_obj: Any, optional_params: dict[str, Any], acompletion: Any = None, litellm_params: Any = None,
                   logger_fn: Any = None, headers: Any = None, timeout: Any = None, client: Any = None) -> ModelResponse:
        spec = self._spec(model)
        timeout_s = self._timeout(timeout)
        try:
            out = self._chat(spec, list(messages), _llama_params(optional_params), timeout_s, threading.Event())
        except Exception as exc:
            raise self._map_error(model, exc, timeout_s) from exc
        return self._to_response(model, out)


_provider_lock = threading.Lock()


def register_local_provider(provider: LocalLlamaProvider | None = None) -> LocalLlamaProvider:
    """Register (once) the ``local`` provider in ``litellm.custom_provider_map``; return it.

    Passing ``provider`` replaces a previous registration (tests use a fake chat function)."""
    with _provider_lock:
        existing = [e["custom_handler"] for e in litellm.custom_provider_map if e.get("provider") == "local"]
        if existing and isinstance(existing[0], LocalLlamaProvider) and provider is None:
            return existing[0]
        handler = provider or LocalLlamaProvider()
        litellm.custom_provider_map = [
            e for e in litellm.custom_provider_map if e.get("provider") != "local"
        ] + [{"provider": "local", "custom_handler": handler}]
        return handler

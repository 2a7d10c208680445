"""The embedded model as a litellm custom provider ``local`` (llama-cpp-python, in process).

Model names: ``local/qwen2.5-coder-0.5b`` (default) and ``local/qwen2.5-coder-1.5b``. Up to
:data:`PREFIX_SLOTS` ``llama_cpp.Llama`` instances per model per process, created lazily, one
per role's system prompt (:func:`get_llama`): llama.cpp reuses the longest common prompt prefix
held in an instance's KV cache, so with narrator and parser calls taking turns each role's
stable prefix (rules, examples, scene description) is evaluated once per story, not per call. No ``LlamaRAMCache``: it snapshots whole
states, each holding n_ctx x vocab logits (GBs with Qwen's 152k vocab).

Calls are serialised per model (a Llama object is not thread-safe) and run in a worker
thread so the event loop (and the simulation) keeps running. Before each call, with the
model's lock held, the threads are chosen from the machine
(:mod:`storyteller.orchestrator.llm.cpu_threads`: never more than the free cores, so another process
holding a core does not make llama.cpp's threads wait on each other) and set on the context
(``llama_set_n_threads``; the answer does not depend on the thread count). The call is limited
by its progress (:mod:`storyteller.orchestrator.llm.decode_progress`), not by a fixed time: it stops, with
:class:`~storyteller.orchestrator.llm.local_errors.LocalModelStalledError`, only when it decodes under the
floor, reads its prompt past the allowance or passes its hard cap. The request's ``timeout``
is that hard cap; a node whose config does not set ``timeout_s`` gets
:func:`local_timeout_s`, the time the floors themselves allow. The chosen threads go back with
the answer (``_hidden_params["local_threads"]``) and into the trace.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import threading
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

from storyteller.agents.llm_port import LLMUnavailableError
from storyteller.orchestrator.llm.config import prefix_slots
from storyteller.orchestrator.llm.cpu_threads import ThreadChooser
from storyteller.orchestrator.llm.decode_progress import ProgressWatch, default_hard_cap_s
from storyteller.orchestrator.llm.llama_decoding import _Abort, score_continuations, stream_chat
from storyteller.orchestrator.llm.local_errors import LocalModelBusyError, LocalModelStalledError
from storyteller.orchestrator.llm.model_weights import (
    WeightsSpec,
    ensure_weights,
    spec_for,
    verified_weights_path,
)

N_CTX = 4096
SEED = 1234
MAX_TOKENS_CAP = 2048
DEFAULT_ARRAY_MAX_ITEMS = 64

PREFIX_SLOTS = prefix_slots(os.environ)
"""Llama instances per model, each keeping the KV cache of the last prompt it saw
(``storyteller.orchestrator.llm.config.prefix_slots``)."""


@dataclass
class _Pool:
    """The instances of one model: by prompt key (the system message), least recently used
    first, and the lock that serialises every call to the model."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    slots: OrderedDict[str, Any] = field(default_factory=OrderedDict)


_load_lock = threading.Lock()
_instances: dict[str, _Pool] = {}


_chooser = ThreadChooser()


def thread_chooser() -> ThreadChooser:
    """The process's thread chooser (its ``last`` choice is what ``storyteller model info`` shows)."""
    return _chooser


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
    """Default hard cap of one local call for a prompt of ``prompt_chars`` characters and
    ``max_tokens`` generated tokens: what the progress floors allow
    (:func:`~storyteller.orchestrator.llm.decode_progress.default_hard_cap_s`), at least ``floor_s``. The
    same for every local model: the floors are rates, not the model's speed."""
    del model
    return max(floor_s, default_hard_cap_s(prompt_chars, max_tokens))


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
                llm = Llama(  # threads: set per call (set_threads)
                    model_path=str(path), n_ctx=N_CTX, n_threads=1, n_threads_batch=1,
                    seed=SEED, n_gpu_layers=0, verbose=False,
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


def set_threads(llm: Any, threads: int) -> None:
    """Run ``llm``'s next evaluations with ``threads`` threads (prompt batches and generation).

    ``llama_set_n_threads`` changes the context's parameters only (no reallocation); the
    thread pool of each evaluation is built from them."""
    if llm.n_threads == threads and llm.n_threads_batch == threads:
        return
    import llama_cpp

    llama_cpp.llama_set_n_threads(llm.ctx, threads, threads)
    llm.n_threads = llm.n_threads_batch = threads
    llm.context_params.n_threads = llm.context_params.n_threads_batch = threads


def _chat_blocking(
    spec: WeightsSpec, messages: list[dict[str, Any]], params: dict[str, Any], timeout_s: float,
    cancel: threading.Event,
) -> dict[str, Any]:
    """One chat completion: the instance for the prompt, threads chosen now and re-checked
    between evaluations, then :func:`stream_chat` with ``timeout_s`` as the hard cap (counted
    from when the model is loaded and free, so queueing behind another call or loading the
    weights does not count). The answer carries the thread choice under ``local_threads``
    (:class:`~storyteller.orchestrator.llm.cpu_threads.ThreadChoice` fields, and ``rechosen``: the threads
    after each change during the call)."""
    llm, lock = get_llama(spec, prompt_key(messages))
    with lock:
        choice = _chooser.choose()
        set_threads(llm, choice.threads)
        rechosen: list[int] = []
        threads: dict[str, Any] = {**choice.model_dump(), "rechosen": rechosen}

        def rethread() -> None:
            new = _chooser.recheck()
            if new is not None and new.threads != llm.n_threads:
                set_threads(llm, new.threads)
                rechosen.append(new.threads)

        watch = ProgressWatch(f"local/{spec.model}", hard_cap_s=timeout_s, local_threads=threads)
        if "choices" in params:
            out = score_continuations(llm, messages, params["choices"], watch, cancel, before_eval=rethread)
        else:
            out = stream_chat(llm, messages, params, watch, cancel, before_eval=rethread)
    return {**out, "local_threads": threads}


def _llama_params(optional_params: dict[str, Any]) -> dict[str, Any]:
    max_tokens = optional_params.get("max_tokens") or optional_params.get("max_completion_tokens") or 512
    params: dict[str, Any] = {
        "temperature": float(optional_params.get("temperature", 0.0) or 0.0),
        "max_tokens": max(1, min(int(max_tokens), MAX_TOKENS_CAP)),
        "seed": int(optional_params.get("seed", SEED)),
    }
    fmt = optional_params.get("response_format")
    if isinstance(fmt, dict) and fmt.get("type") == "choices":
        params["choices"] = [str(c) for c in fmt.get("choices", [])]
    elif isinstance(fmt, dict) and fmt.get("type") == "gbnf":
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
        response = ModelResponse(
            id=out.get("id"), model=model,
            choices=[{"index": 0, "finish_reason": choice.get("finish_reason") or "stop",
                      "message": {"role": "assistant", "content": choice["message"].get("content") or ""}}],
            usage={"prompt_tokens": usage.get("prompt_tokens", 0),
                   "completion_tokens": usage.get("completion_tokens", 0),
                   "total_tokens": usage.get("total_tokens", 0)},
        )
        if out.get("local_threads") is not None:
            response._hidden_params["local_threads"] = out["local_threads"]
        return response

    def _map_error(self, model: str, exc: BaseException) -> Exception:
        if isinstance(exc, LocalModelStalledError):
            return exc
        if isinstance(exc, _Abort):
            return Timeout(message="local model call cancelled", model=model, llm_provider="local")
        if isinstance(exc, MemoryError | OSError):
            return LocalModelBusyError(f"{type(exc).__name__}: {exc}", model=model)
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
                raise self._map_error(model, exc) from exc
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
            raise self._map_error(model, exc) from exc
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

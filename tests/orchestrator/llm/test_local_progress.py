"""A local call is limited by its progress, not a wall timeout; only fixable errors are retried.

A fake streaming llama stands in for ``llama_cpp.Llama``: like llama-cpp-python's
``generate`` it evaluates the prompt through ``eval`` and then each generated token, and it
advances an injected clock by what each evaluation costs, so no test waits or measures time.
"""

from __future__ import annotations

import sys
import threading
import types
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest

from storyteller.agents.llm_port import ChatMessage, LLMError, LLMRequest
from storyteller.orchestrator.llm import local_model
from storyteller.orchestrator.llm.client import LiteLLMClient
from storyteller.orchestrator.llm.config import RetryConfig, default_config
from storyteller.orchestrator.llm.cpu_threads import ThreadChoice, ThreadChooser
from storyteller.orchestrator.llm.decode_progress import ProgressFloor, ProgressWatch
from storyteller.orchestrator.llm.llama_decoding import _Abort, stream_chat
from storyteller.orchestrator.llm.local_errors import LocalModelStalledError
from storyteller.orchestrator.llm.local_model import LocalLlamaProvider, register_local_provider
from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.llm.traces import read_trace
from storyteller.orchestrator.session.run_report import local_threads_metrics


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


class StreamingLlama:
    """Evaluates ``prompt_tokens`` at ``prompt_s`` seconds each, then generates ``pieces``;
    generated token ``i`` costs ``token_s(i)`` seconds."""

    def __init__(self, clock: Clock, pieces: list[str], token_s: Callable[[int], float], *,
                 prompt_tokens: int = 300, prompt_s: float = 0.01, n_batch: int = 128) -> None:
        self.clock, self.pieces, self.token_s = clock, pieces, token_s
        self.prompt_len, self.prompt_s, self.n_batch = prompt_tokens, prompt_s, n_batch
        self.n_tokens = 0
        self.n_threads = self.n_threads_batch = 2
        self.context_params = types.SimpleNamespace(n_threads=2, n_threads_batch=2)
        self.ctx = object()
        self.batches: list[int] = []  # sizes of the evaluations, in order
        self._generated = 0

    def eval(self, tokens: Sequence[int]) -> None:
        if self.n_tokens < self.prompt_len:
            self.clock.t += self.prompt_s * len(tokens)
        else:
            self.clock.t += self.token_s(self._generated)
            self._generated += 1
        self.batches.append(len(tokens))
        self.n_tokens += len(tokens)

    def create_chat_completion(self, messages: list[dict[str, Any]], stream: bool, **params: Any) -> Iterator[Any]:
        assert stream

        def chunks() -> Iterator[dict[str, Any]]:
            self.eval(list(range(self.prompt_len)))
            yield {"choices": [{"delta": {"role": "assistant"}, "finish_reason": None}]}
            for i, piece in enumerate(self.pieces):
                yield {"choices": [{"delta": {"content": piece}, "finish_reason": None}]}
                self.eval([i])  # the token just sampled, so the next one can be
            yield {"choices": [{"delta": {}, "finish_reason": "stop"}]}

        return chunks()


def run(llm: StreamingLlama, clock: Clock, hard_cap_s: float = 10_000.0,
        cancel: threading.Event | None = None) -> dict[str, Any]:
    watch = ProgressWatch("local/qwen2.5-coder-0.5b", hard_cap_s, ProgressFloor(), clock=clock)
    return stream_chat(llm, [{"role": "user", "content": "x"}], {"temperature": 0.0}, watch,
                       cancel or threading.Event())


def test_a_slow_but_progressing_call_runs_to_its_end() -> None:
    """1 token/s for 200 s and a slow prompt: far past any old fixed timeout, never under the floor."""
    clock = Clock()
    llm = StreamingLlama(clock, ["w"] * 200, token_s=lambda i: 1.0, prompt_tokens=400, prompt_s=0.2)
    out = run(llm, clock)
    assert out["choices"][0]["message"]["content"] == "w" * 200
    assert out["usage"]["completion_tokens"] == 200 and out["usage"]["prompt_tokens"] == 400
    assert clock.t - 1000.0 == pytest.approx(280.0)  # 80 s of prompt + 200 s of decoding
    assert llm.batches[:4] == [128, 128, 128, 16]  # the prompt in llama.cpp's own n_batch batches
    assert "eval" not in vars(llm)  # the wrapper is gone afterwards


def test_a_stalled_decode_fails_naming_the_rate_and_the_floor() -> None:
    clock = Clock()
    # 20 quick tokens, then 5 s per token: 0.2 tok/s once the window holds only slow tokens
    llm = StreamingLlama(clock, ["w"] * 100, token_s=lambda i: 0.1 if i < 20 else 5.0)
    with pytest.raises(LocalModelStalledError) as info:
        run(llm, clock)
    err = info.value
    assert err.phase == "decode" and err.floor_tok_s == 0.5
    assert err.rate_tok_s is not None and err.rate_tok_s < 0.5
    assert f"decoded {err.rate_tok_s:.2f} tok/s over the last 30 s, under the floor of 0.5 tok/s" in str(err)
    assert llm._generated < 40, "stopped soon after the rate fell, not at the end"
    assert "eval" not in vars(llm)


def test_a_prompt_past_its_allowance_stops_between_batches() -> None:
    clock = Clock()
    # 1000 tokens at 1 s each: the allowance is 30 s + 1000 / 5 = 230 s, passed after two batches
    llm = StreamingLlama(clock, ["w"], token_s=lambda i: 0.1, prompt_tokens=1000, prompt_s=1.0)
    with pytest.raises(LocalModelStalledError) as info:
        run(llm, clock)
    assert info.value.phase == "prompt" and "allowance of 230.0 s" in str(info.value)
    assert "floor of 5 tok/s" in str(info.value)
    assert llm.batches == [128, 128], "the rest of the prompt is not evaluated"


def test_the_hard_cap_stops_even_a_progressing_call() -> None:
    clock = Clock()
    llm = StreamingLlama(clock, ["w"] * 100, token_s=lambda i: 0.5)
    with pytest.raises(LocalModelStalledError) as info:
        run(llm, clock, hard_cap_s=20.0)
    assert info.value.phase == "hard_cap" and "hard cap of 20.0 s" in str(info.value)
    assert "decoding 2.00 tok/s, floor 0.5 tok/s" in str(info.value)


def test_a_cancelled_call_stops_at_the_next_evaluation() -> None:
    clock = Clock()
    cancel = threading.Event()
    llm = StreamingLlama(clock, ["w"] * 50, token_s=lambda i: 0.1)
    cancel.set()
    with pytest.raises(_Abort):
        run(llm, clock, cancel=cancel)
    assert llm.batches == []


class FailingChat:
    """A chat function for LocalLlamaProvider raising ``errors`` in turn, then answering."""

    def __init__(self, *errors: BaseException) -> None:
        self.errors = list(errors)
        self.calls = 0

    def __call__(self, *args: Any) -> dict[str, Any]:
        self.calls += 1
        if self.errors:
            raise self.errors.pop(0)
        return {"id": "x", "choices": [{"index": 0, "finish_reason": "stop",
                                         "message": {"role": "assistant", "content": "hello"}}],
                "usage": {"prompt_tokens": 3, "completion_tokens": 1, "total_tokens": 4}}


async def _no_sleep(seconds: float) -> None:
    return None


def _client(tmp_path: Path) -> LiteLLMClient:
    base = default_config()
    node = base.nodes["narrator"].model_copy(update={"retry": RetryConfig(max_attempts=3)})
    cfg = base.model_copy(update={"nodes": {**base.nodes, "narrator": node}})
    return LiteLLMClient(cfg, TraceWriter(tmp_path / "t.jsonl"), sleep=_no_sleep, check_local=lambda m: None)


REQUEST = LLMRequest(node="narrator", messages=(ChatMessage(role="user", content="Say hello."),))


@pytest.fixture
def restore_provider() -> Iterator[None]:
    yield
    register_local_provider(LocalLlamaProvider())


@pytest.mark.usefixtures("restore_provider")
async def test_a_stalled_local_call_is_not_retried(tmp_path: Path) -> None:
    stall = LocalModelStalledError("local model decoded 0.10 tok/s over the last 30 s, under the floor of 0.5 tok/s",
                                   model="local/qwen2.5-coder-0.5b", phase="decode", rate_tok_s=0.1, floor_tok_s=0.5,
                                   local_threads={"threads": 2, "usable_cores": 2, "busy_cores": 0.0,
                                                  "source": "proc_stat"})
    chat = FailingChat(stall, stall, stall)
    register_local_provider(LocalLlamaProvider(chat=chat, check=lambda m: None))
    client = _client(tmp_path)
    with pytest.raises(LLMError, match=r"LocalModelStalledError: .*0\.10 tok/s.*floor of 0\.5 tok/s"):
        await client.complete(REQUEST)
    client.close()
    assert chat.calls == 1
    (rec,) = read_trace(tmp_path / "t.jsonl").attempts()
    assert rec.error_class == "permanent" and rec.error_type == "LocalModelStalledError"
    assert rec.params["local_threads"]["threads"] == 2


@pytest.mark.usefixtures("restore_provider")
@pytest.mark.parametrize("error", [RuntimeError("llama_decode returned -1"), ValueError("bad grammar")])
async def test_a_llama_failure_is_not_retried(tmp_path: Path, error: Exception) -> None:
    chat = FailingChat(error, error, error)
    register_local_provider(LocalLlamaProvider(chat=chat, check=lambda m: None))
    client = _client(tmp_path)
    with pytest.raises(LLMError):
        await client.complete(REQUEST)
    client.close()
    assert chat.calls == 1


@pytest.mark.usefixtures("restore_provider")
async def test_a_machine_short_of_memory_is_retried(tmp_path: Path) -> None:
    chat = FailingChat(MemoryError("cannot allocate the KV cache"))
    register_local_provider(LocalLlamaProvider(chat=chat, check=lambda m: None))
    client = _client(tmp_path)
    resp = await client.complete(REQUEST)
    client.close()
    assert resp.text == "hello" and resp.attempts == 2 and chat.calls == 2
    first, second = read_trace(tmp_path / "t.jsonl").attempts()
    assert first.error_type == "LocalModelBusyError" and first.error_class == "transient" and second.final


class ContentionProbe:
    """A 2-core machine on the test's clock: another process keeps cpu1 busy from ``busy_from`` on."""

    def __init__(self, clock: Clock, busy_from: float) -> None:
        self.clock, self.busy_from = clock, busy_from

    def cpus(self) -> frozenset[int]:
        return frozenset({0, 1})

    def cpu_max(self) -> str | None:
        return None

    def proc_stat(self) -> str | None:
        ticks = round(100 * (self.clock.t - 1000.0))
        busy = max(0, round(100 * (self.clock.t - self.busy_from)))
        return f"cpu0 0 0 0 {ticks} 0 0 0 0 0 0\ncpu1 {busy} 0 0 {ticks - busy} 0 0 0 0 0 0\n"

    def loadavg(self) -> float | None:
        return None

    def cpu_count(self) -> int:
        return 2

    def own_cpu_s(self) -> float:
        return 0.0

    def monotonic(self) -> float:
        return self.clock.t

    def sleep(self, seconds: float) -> None:
        self.clock.t += seconds


@pytest.mark.usefixtures("restore_provider")
async def test_each_call_runs_with_the_threads_chosen_then_and_the_trace_and_metrics_say_so(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Quiet when the call starts (2 threads); another process takes cpu1 5 s into the call:
    the next re-check lowers the threads to 1 between two tokens."""
    clock = Clock()
    llm = StreamingLlama(clock, ["hi"] * 40, token_s=lambda i: 0.5)
    llm.n_threads = llm.n_threads_batch = 1  # as loaded: the call's choice is set before it starts
    set_calls: list[tuple[Any, int, int]] = []
    monkeypatch.setitem(sys.modules, "llama_cpp", types.SimpleNamespace(
        llama_set_n_threads=lambda ctx, n, nb: set_calls.append((ctx, n, nb))))
    monkeypatch.setattr(local_model, "get_llama", lambda spec, key="": (llm, threading.Lock()))
    monkeypatch.setattr(local_model, "_chooser", ThreadChooser(ContentionProbe(clock, busy_from=1005.0), env={}))
    register_local_provider(LocalLlamaProvider(check=lambda m: None))
    client = _client(tmp_path)
    resp = await client.complete(REQUEST)
    client.close()
    assert resp.text == "hi" * 40
    assert set_calls == [(llm.ctx, 2, 2), (llm.ctx, 1, 1)]
    assert (llm.n_threads, llm.n_threads_batch, llm.context_params.n_threads) == (1, 1, 1)
    (rec,) = read_trace(tmp_path / "t.jsonl").attempts()
    threads = dict(rec.params["local_threads"])
    assert threads.pop("rechosen") == [1]
    chosen = ThreadChoice.model_validate(threads)
    assert (chosen.threads, chosen.usable_cores, chosen.busy_cores, chosen.source) == (2, 2, 0.0, "proc_stat")
    assert local_threads_metrics(tmp_path / "t.jsonl") == {
        "attempts_by_threads": {"2": 1}, "rethreaded_attempts": 1, "usable_cores": 2,
        "busy_cores": {"min": 0.0, "max": 0.0}, "sources": ["proc_stat"]}

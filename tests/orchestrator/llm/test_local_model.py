"""The ``local`` litellm provider: parameter mapping with a fake llama, and the real 0.5B model."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, ClassVar

import anyio
import litellm
import pytest
from litellm import exceptions as litellm_errors

from storyteller.agents.llm_port import ChatMessage, LLMError, LLMRequest
from storyteller.orchestrator.llm.client import LiteLLMClient
from storyteller.orchestrator.llm.config import RetryConfig, default_config
from storyteller.orchestrator.llm.llama_decoding import _Abort
from storyteller.orchestrator.llm.local_model import (
    DEFAULT_ARRAY_MAX_ITEMS,
    MAX_TOKENS_CAP,
    LocalLlamaProvider,
    bound_arrays,
    register_local_provider,
)
from storyteller.orchestrator.llm.model_weights import (
    QWEN_15B,
    WeightsIntegrityError,
    WeightsMissingError,
    WeightsSpec,
    ensure_weights,
    forget_hashes,
    locate_chunks,
)
from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.llm.traces import read_trace
from tests.support.embedded_weights import embedded_weights_or_skip

SCHEMA = {
    "type": "object",
    "properties": {"animal": {"type": "string", "enum": ["cat", "dog"]},
                   "legs": {"type": "integer"},
                   "tags": {"type": "array", "items": {"type": "string", "maxLength": 10}}},
    "required": ["animal", "legs", "tags"],
}


class FakeLlama:
    """Records what the provider asks of llama.cpp and answers like create_chat_completion."""

    def __init__(self, reply: str = '{"animal": "cat", "legs": 4, "tags": []}', block_s: float = 0.0,
                 error: Exception | None = None) -> None:
        self.reply, self.block_s, self.error = reply, block_s, error
        self.calls: list[dict[str, Any]] = []

    def __call__(self, spec: Any, messages: list[dict[str, Any]], params: dict[str, Any], timeout_s: float,
                 cancel: threading.Event) -> dict[str, Any]:
        self.calls.append({"model": spec.model, "messages": messages, "params": params, "timeout_s": timeout_s})
        if self.block_s:
            time.sleep(self.block_s)  # a blocking native call, like llama.cpp
        if self.error is not None:
            raise self.error
        return {"id": "chatcmpl-1", "choices": [{"index": 0, "finish_reason": "stop",
                                                  "message": {"role": "assistant", "content": self.reply}}],
                "usage": {"prompt_tokens": 12, "completion_tokens": 9, "total_tokens": 21}}


@pytest.fixture
def fake_llama() -> Iterator[FakeLlama]:
    fake = FakeLlama()
    register_local_provider(LocalLlamaProvider(chat=fake, check=lambda m: None))
    yield fake
    register_local_provider(LocalLlamaProvider())


def request(schema: dict[str, Any] | None = SCHEMA, max_tokens: int | None = None) -> LLMRequest:
    return LLMRequest(node="narrator", messages=(ChatMessage(role="user", content="Name an animal."),),
                      json_schema=schema, max_tokens=max_tokens)


async def test_client_sends_grammar_schema_to_llama(fake_llama: FakeLlama, tmp_path: Path) -> None:
    client = LiteLLMClient(default_config(), TraceWriter(tmp_path / "t.jsonl"), check_local=lambda m: None)
    resp = await client.complete(request(max_tokens=100))
    client.close()
    assert resp.text == fake_llama.reply and resp.model == "local/qwen2.5-coder-0.5b"
    assert resp.usage.prompt_tokens == 12 and resp.usage.completion_tokens == 9
    call = fake_llama.calls[0]
    assert call["model"] == "qwen2.5-coder-0.5b"
    assert call["messages"] == [{"role": "user", "content": "Name an animal."}]
    params = call["params"]
    assert params["temperature"] == 0.0 and params["max_tokens"] == 100
    fmt = params["response_format"]
    assert fmt["type"] == "json_object"
    assert fmt["schema"]["properties"]["tags"]["maxItems"] == DEFAULT_ARRAY_MAX_ITEMS
    rec = next(read_trace(tmp_path / "t.jsonl").attempts())
    assert rec.params["response_format"] == {"type": "json_object", "schema": SCHEMA}
    assert rec.parsed_output == {"animal": "cat", "legs": 4, "tags": []}


async def test_max_tokens_capped_and_openai_schema_form_converted(fake_llama: FakeLlama) -> None:
    fmt = {"type": "json_schema", "json_schema": {"name": "x", "schema": SCHEMA}}
    await litellm.acompletion(model="local/qwen2.5-coder-0.5b", messages=[{"role": "user", "content": "x"}],
                              max_tokens=10**6, response_format=fmt, timeout=5)
    assert fake_llama.calls[0]["timeout_s"] == 5.0
    params = fake_llama.calls[0]["params"]
    assert params["max_tokens"] == MAX_TOKENS_CAP
    assert params["response_format"]["type"] == "json_object"
    assert params["response_format"]["schema"]["required"] == ["animal", "legs", "tags"]


async def test_event_loop_keeps_running_during_generation() -> None:
    fake = FakeLlama(block_s=0.3)
    register_local_provider(LocalLlamaProvider(chat=fake, check=lambda m: None))
    ticks = 0

    async def ticker() -> None:
        nonlocal ticks
        while True:
            await anyio.sleep(0.01)
            ticks += 1

    try:
        async with anyio.create_task_group() as tg:
            tg.start_soon(ticker)
            await litellm.acompletion(model="local/qwen2.5-coder-0.5b", messages=[{"role": "user", "content": "x"}])
            tg.cancel_scope.cancel()
    finally:
        register_local_provider(LocalLlamaProvider())
    assert ticks >= 3, "the blocking llama call must run off the event loop"


@pytest.mark.parametrize(
    ("error", "expected"),
    [(_Abort(), litellm_errors.Timeout),
     (ValueError("Requested tokens (5000) exceed context window of 4096"), litellm_errors.ContextWindowExceededError),
     (RuntimeError("llama_decode failed"), litellm_errors.InternalServerError)],
)
async def test_llama_errors_map_to_litellm_types(error: Exception, expected: type[Exception]) -> None:
    register_local_provider(LocalLlamaProvider(chat=FakeLlama(error=error), check=lambda m: None))
    try:
        with pytest.raises(expected):
            await litellm.acompletion(model="local/qwen2.5-coder-0.5b", messages=[{"role": "user", "content": "x"}])
    finally:
        register_local_provider(LocalLlamaProvider())


async def test_unknown_local_model_is_not_found() -> None:
    with pytest.raises(litellm_errors.NotFoundError, match="unknown local model"):
        await litellm.acompletion(model="local/giant-70b", messages=[{"role": "user", "content": "x"}])


def test_bound_arrays_only_adds_missing_bounds() -> None:
    schema: dict[str, Any] = {"type": "object", "properties": {
        "a": {"type": "array", "items": {"type": "array", "items": {"type": "integer"}}},
        "b": {"type": "array", "maxItems": 3}}}
    out = bound_arrays(schema, 8)
    assert out["properties"]["a"]["maxItems"] == 8 and out["properties"]["a"]["items"]["maxItems"] == 8
    assert out["properties"]["b"]["maxItems"] == 3
    assert "maxItems" not in schema["properties"]["a"], "input must not be mutated"


@pytest.mark.embedded_model
async def test_real_embedded_model_answers_schema_json(tmp_path: Path) -> None:
    embedded_weights_or_skip()
    register_local_provider(LocalLlamaProvider())
    client = LiteLLMClient(default_config(), TraceWriter(tmp_path / "t.jsonl"))
    resp = await client.complete(LLMRequest(
        node="narrator",
        messages=(ChatMessage(role="system", content="You answer with JSON only."),
                  ChatMessage(role="user", content="A cat: which animal is it, how many legs, two tags?")),
        json_schema=SCHEMA, max_tokens=80,
    ))
    client.close()
    value = json.loads(resp.text)
    assert set(value) == {"animal", "legs", "tags"} and value["animal"] in ("cat", "dog")
    assert isinstance(value["legs"], int) and isinstance(value["tags"], list)
    assert resp.model == "local/qwen2.5-coder-0.5b" and resp.usage.completion_tokens > 0
    rec = next(read_trace(tmp_path / "t.jsonl").attempts())
    assert rec.final and rec.parsed_output == value


@pytest.mark.embedded_model
async def test_real_embedded_model_timeout_aborts_and_model_stays_usable() -> None:
    embedded_weights_or_skip()
    register_local_provider(LocalLlamaProvider())
    base = default_config()
    node = base.nodes["narrator"].model_copy(update={
        "timeout_s": 0.05, "max_tokens": 2000, "retry": RetryConfig(max_attempts=1)})
    fast_fail = LiteLLMClient(base.model_copy(update={"nodes": {**base.nodes, "narrator": node}}))
    poem = LLMRequest(node="narrator", messages=(ChatMessage(role="user", content="Write a very long poem."),))
    with pytest.raises(LLMError, match="Timeout"):
        await fast_fail.complete(poem)
    ok = await LiteLLMClient(base).complete(
        LLMRequest(node="narrator", messages=(ChatMessage(role="user", content="Say hi."),), max_tokens=8))
    assert ok.text.strip() and ok.usage.completion_tokens <= 8


async def test_truncated_local_json_goes_to_fallback_without_retry(tmp_path: Path) -> None:
    truncated = FakeLlama(reply='{"animal": "ca')
    truncated_out = truncated.__call__

    def chat(*args: Any) -> dict[str, Any]:
        out = truncated_out(*args)
        out["choices"][0]["finish_reason"] = "length"
        return out

    register_local_provider(LocalLlamaProvider(chat=chat, check=lambda m: None))
    base = default_config()
    node = base.nodes["narrator"].model_copy(update={"fallbacks": ("local/qwen2.5-coder-1.5b",)})
    client = LiteLLMClient(base.model_copy(update={"nodes": {**base.nodes, "narrator": node}}),
                           TraceWriter(tmp_path / "t.jsonl"), check_local=lambda m: None)
    try:
        with pytest.raises(LLMError, match="truncated"):
            await client.complete(request())
    finally:
        client.close()
        register_local_provider(LocalLlamaProvider())
    recs = list(read_trace(tmp_path / "t.jsonl").attempts())
    assert [r.model for r in recs] == ["local/qwen2.5-coder-0.5b", "local/qwen2.5-coder-1.5b"]
    assert all(r.error_class == "permanent" for r in recs) and len(truncated.calls) == 2


class FakeLlamaClass:
    """Stands in for ``llama_cpp.Llama``: records every load, loads nothing."""

    loads: ClassVar[list[str]] = []

    def __init__(self, model_path: str, **kw: Any) -> None:
        FakeLlamaClass.loads.append(model_path)

    def close(self) -> None:
        return None


def test_get_llama_hashes_the_file_before_loading_and_refuses_a_tampered_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import hashlib
    import os
    import sys
    import types

    from storyteller.orchestrator.llm import local_model

    blob = b"GGUF" + bytes(range(256)) * 64
    spec = WeightsSpec(model="fake-tamper", filename="fake-tamper.gguf", packages=("x",), version="1",
                       sha256=hashlib.sha256(blob).hexdigest(), size=len(blob), description="test")
    monkeypatch.setenv("STORYTELLER_CACHE_DIR", str(tmp_path))
    models = tmp_path / "models"
    models.mkdir()
    path = models / spec.filename
    path.write_bytes(blob)
    assert ensure_weights(spec) == path  # hashed and stamped (no chunks needed: the file is right)
    monkeypatch.setitem(sys.modules, "llama_cpp", types.SimpleNamespace(Llama=FakeLlamaClass))
    FakeLlamaClass.loads = []
    forget_hashes()  # as in a later process, which has only the stamp
    st = path.stat()
    data = bytearray(blob)
    data[100] ^= 0x01
    path.write_bytes(bytes(data))
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))  # same size, same mtime: the stamp still matches
    try:
        with pytest.raises(WeightsIntegrityError, match="Refusing to load it"):
            local_model.get_llama(spec)
        assert FakeLlamaClass.loads == [] and spec.model not in local_model.loaded_models()
        path.write_bytes(blob)  # restored: loads, once per process
        local_model.get_llama(spec)
        local_model.get_llama(spec)
        assert FakeLlamaClass.loads == [str(path)]
    finally:
        local_model._instances.pop(spec.model, None)


def test_each_system_prompt_keeps_its_own_instance_up_to_the_slot_count(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Narrator and parser calls taking turns each find their prefix in their own instance's
    KV cache; a fourth prompt takes the least recently used instance over."""
    import hashlib
    import sys
    import types

    from storyteller.orchestrator.llm import local_model

    blob = b"GGUF" + bytes(range(256)) * 8
    spec = WeightsSpec(model="fake-slots", filename="fake-slots.gguf", packages=("x",), version="1",
                       sha256=hashlib.sha256(blob).hexdigest(), size=len(blob), description="test")
    monkeypatch.setenv("STORYTELLER_CACHE_DIR", str(tmp_path))
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / spec.filename).write_bytes(blob)
    ensure_weights(spec)
    monkeypatch.setitem(sys.modules, "llama_cpp", types.SimpleNamespace(Llama=FakeLlamaClass))
    monkeypatch.setattr(local_model, "PREFIX_SLOTS", 3)
    FakeLlamaClass.loads = []

    def key(text: str) -> str:
        return local_model.prompt_key([{"role": "system", "content": text}, {"role": "user", "content": "x"}])

    try:
        narrator, lock = local_model.get_llama(spec, key("narrator rules"))
        parser, lock2 = local_model.get_llama(spec, key("parser rules"))
        assert narrator is not parser and lock is lock2  # one model, calls serialised
        assert local_model.get_llama(spec, key("narrator rules"))[0] is narrator
        describer = local_model.get_llama(spec, key("describer rules"))[0]
        assert len(FakeLlamaClass.loads) == 3
        assert local_model.get_llama(spec, key("planner rules"))[0] is parser  # least recently used
        assert local_model.get_llama(spec, key("narrator rules"))[0] is narrator
        assert len(FakeLlamaClass.loads) == 3 and describer is not narrator
        assert local_model.prompt_key([{"role": "user", "content": "x"}]) == ""
    finally:
        local_model._instances.pop(spec.model, None)


async def test_missing_quality_weights_message_names_the_install_command(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    try:
        import llama_cpp  # noqa: F401
    except ImportError:
        pytest.skip("llama-cpp-python is not installed (pip install -e '.[local]')")
    try:
        locate_chunks(QWEN_15B)
    except WeightsMissingError:
        pass
    else:
        pytest.skip("the quality weights are installed here")
    monkeypatch.setenv("STORYTELLER_CACHE_DIR", str(tmp_path))
    base = default_config()
    node = base.nodes["narrator"].model_copy(update={"model": "local/qwen2.5-coder-1.5b"})
    client = LiteLLMClient(base.model_copy(update={"nodes": {**base.nodes, "narrator": node}}))
    from storyteller.agents.llm_port import LLMUnavailableError

    with pytest.raises(LLMUnavailableError) as info:
        await client.complete(request())
    msg = str(info.value)
    assert "local/qwen2.5-coder-1.5b" in msg and "pip install -e '.[local,quality]'" in msg


@pytest.mark.embedded_model
async def test_real_quality_model_answers_schema_json(tmp_path: Path) -> None:
    """The 1.5B "quality" option end to end (skipped unless `.[local,quality]` is installed)."""
    try:
        import llama_cpp  # noqa: F401
        locate_chunks(QWEN_15B)
    except (ImportError, WeightsMissingError):
        pytest.skip("quality weights not installed (pip install -e '.[local,quality]')")
    register_local_provider(LocalLlamaProvider())
    base = default_config()
    node = base.nodes["narrator"].model_copy(update={"model": "local/qwen2.5-coder-1.5b", "timeout_s": 600.0})
    client = LiteLLMClient(base.model_copy(update={"nodes": {**base.nodes, "narrator": node}}),
                           TraceWriter(tmp_path / "t.jsonl"))
    resp = await client.complete(LLMRequest(
        node="narrator",
        messages=(ChatMessage(role="system", content="You answer with JSON only."),
                  ChatMessage(role="user", content="A cat: which animal is it, how many legs, two tags?")),
        json_schema=SCHEMA, max_tokens=60,
    ))
    client.close()
    value = json.loads(resp.text)
    assert value["animal"] in ("cat", "dog") and resp.model == "local/qwen2.5-coder-1.5b"


async def test_default_local_hard_cap_grows_with_the_prompt_and_an_explicit_one_wins(
    fake_llama: FakeLlama, tmp_path: Path
) -> None:
    """Unset, a local call's hard cap is what the progress floors allow (prompt allowance plus
    max_tokens at the decode floor plus one window), never under the configured default."""
    from storyteller.orchestrator.llm.config import load_config
    from storyteller.orchestrator.llm.decode_progress import (
        CHARS_PER_TOKEN,
        DECODE_WINDOW_S,
        MIN_DECODE_TOK_S,
        MIN_PROMPT_TOK_S,
        PROMPT_BASE_S,
    )
    from storyteller.orchestrator.llm.local_model import local_timeout_s

    long_prompt = LLMRequest(node="event_parser", messages=(ChatMessage(role="user", content="x" * 9000),), max_tokens=400)
    client = LiteLLMClient(default_config(), check_local=lambda m: None)
    await client.complete(request(max_tokens=20))
    await client.complete(long_prompt)
    short_s, long_s = fake_llama.calls[0]["timeout_s"], fake_llama.calls[1]["timeout_s"]
    assert short_s == 120.0  # a short prompt keeps the configured default as the floor
    expected = PROMPT_BASE_S + 9000 / CHARS_PER_TOKEN / MIN_PROMPT_TOK_S + 400 / MIN_DECODE_TOK_S + DECODE_WINDOW_S
    assert long_s == pytest.approx(expected, abs=0.1) and long_s > 120.0
    assert long_s == local_timeout_s("local/qwen2.5-coder-0.5b", 9000, 400, floor_s=120.0)
    # a timeout set in the config is used as it is
    cfg = tmp_path / "c.toml"
    cfg.write_text("[llm]\ntimeout_s = 45.0\n", encoding="utf-8")
    await LiteLLMClient(load_config(cfg, env={}), check_local=lambda m: None).complete(long_prompt)
    assert fake_llama.calls[2]["timeout_s"] == 45.0


def test_models_load_without_repacked_weight_buffers() -> None:
    """AMX repacking segfaults on the first decode (llama.cpp issue 20824): every load turns
    llama.cpp's extra weight buffers off, and only for the duration of the load."""
    bindings = pytest.importorskip("llama_cpp.llama_cpp")
    from storyteller.orchestrator.llm.local_model import plain_cpu_buffers

    assert bindings.llama_model_default_params().use_extra_bufts is True
    with plain_cpu_buffers():
        assert bindings.llama_model_default_params().use_extra_bufts is False
    assert bindings.llama_model_default_params().use_extra_bufts is True


def test_prefix_slots_variable_is_checked_by_name() -> None:
    """Found by the hostile corpus: STORYTELLER_LOCAL_PREFIX_SLOTS=abc ended `run` with int()'s
    own 'invalid literal' line (at the import of this module, after the run's setup), which does
    not say which setting was wrong; load_config now checks it by name, before the setup."""
    from storyteller.orchestrator.llm.config import ConfigError, load_config, prefix_slots

    assert prefix_slots({}) == 3 and prefix_slots({"STORYTELLER_LOCAL_PREFIX_SLOTS": "0"}) == 1
    for hostile in ("abc", "\u00b2", "9" * 5000, "-1"):
        with pytest.raises(ConfigError, match="STORYTELLER_LOCAL_PREFIX_SLOTS: must be a whole number"):
            load_config(None, {"STORYTELLER_LOCAL_PREFIX_SLOTS": hostile})

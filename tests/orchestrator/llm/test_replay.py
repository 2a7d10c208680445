"""Record with the live client (fake provider), then replay: order, misses with diffs, no live calls."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import litellm
import pytest
from litellm.exceptions import RateLimitError

from storyteller.agents.llm_port import ChatMessage, LLMRequest, NodeName, ReplayMissError
from storyteller.orchestrator.llm.client import LiteLLMClient
from storyteller.orchestrator.llm.config import ConfigError, default_config
from storyteller.orchestrator.llm.replay import ReplayClient, build_llm_port
from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.llm.traces import AttemptRecord, TraceCorruptError, read_trace

PROMPT = "You are the narrator.\nCharacters: Ann, Bob.\nRules: one event at a time."


def req(user: str, node: NodeName = "narrator", system: str = PROMPT, frame: int = 0) -> LLMRequest:
    return LLMRequest(node=node, messages=(ChatMessage(role="system", content=system),
                                           ChatMessage(role="user", content=user)), sim_frame=frame)


class ScriptedProvider:
    """A stand-in for litellm.acompletion: answers from a list, raising exceptions when listed."""

    def __init__(self, answers: list[Any]) -> None:
        self.answers = list(answers)
        self.calls = 0

    async def __call__(self, **kwargs: Any) -> Any:
        self.calls += 1
        answer = self.answers.pop(0)
        if isinstance(answer, BaseException):
            raise answer
        return SimpleNamespace(
            choices=[SimpleNamespace(message=SimpleNamespace(content=answer), finish_reason="stop")],
            usage=SimpleNamespace(prompt_tokens=7, completion_tokens=3),
        )


async def no_sleep(_: float) -> None:
    return None


async def record(path: Path, requests: list[LLMRequest], answers: list[Any], model: str | None = None) -> list[str]:
    cfg = default_config()
    if model is not None:
        cfg = cfg.model_copy(update={"nodes": {k: v.model_copy(update={"model": model}) for k, v in cfg.nodes.items()}})
    client = LiteLLMClient(cfg, TraceWriter(path), acompletion=ScriptedProvider(answers),
                           sleep=no_sleep, check_local=lambda m: None)
    texts = [(await client.complete(r)).text for r in requests]
    client.close()
    return texts


@pytest.fixture
def no_live_calls(monkeypatch: pytest.MonkeyPatch) -> None:
    async def forbidden(**kwargs: Any) -> Any:
        raise AssertionError("replay reached a live provider")

    monkeypatch.setattr(litellm, "acompletion", forbidden)


async def test_replay_serves_recorded_answers_in_order(tmp_path: Path, no_live_calls: None) -> None:
    path = tmp_path / "t.jsonl"
    reqs = [req("frame 0: who is free?"), req("same question"), req("same question", frame=99),
            req("parse it", node="event_parser")]
    texts = await record(path, reqs, ["A", "B1", "B2", "P"])
    replay = ReplayClient(path)
    assert replay.remaining() == 4
    # sim_frame is not part of the key: the repeat is served in recorded order
    out = [(await replay.complete(r)) for r in [reqs[0], reqs[2], reqs[1], reqs[3]]]
    assert [o.text for o in out] == ["A", "B1", "B2", "P"] == [texts[0], texts[1], texts[2], texts[3]]
    assert all(o.model == "local/qwen2.5-coder-0.5b" and o.usage.prompt_tokens == 7 for o in out)
    with pytest.raises(ReplayMissError, match=r"narrator.*recorded 2 time\(s\)"):
        await replay.complete(reqs[1])


async def test_edited_prompt_misses_with_diff_naming_node(tmp_path: Path, no_live_calls: None) -> None:
    path = tmp_path / "t.jsonl"
    await record(path, [req("who is free?"), req("something else entirely, much longer text here")], ["A", "B"])
    edited = req("who is free?", system=PROMPT.replace("one event", "one evnt"))
    with pytest.raises(ReplayMissError) as info:
        await ReplayClient(path).complete(edited)
    err = info.value
    assert err.node == "narrator" and "narrator" in str(err)
    assert err.diff is not None
    assert "-Rules: one event at a time." in err.diff and "+Rules: one evnt at a time." in err.diff
    assert "who is free?" not in [ln[1:] for ln in err.diff.splitlines() if ln[:1] in "+-"]


async def test_schema_change_is_a_miss(tmp_path: Path, no_live_calls: None) -> None:
    path = tmp_path / "t.jsonl"
    await record(path, [req("q")], ["A"])
    changed = req("q").model_copy(update={"json_schema": {"type": "object", "maxProperties": 1}})
    with pytest.raises(ReplayMissError, match="json_schema"):
        await ReplayClient(path).complete(changed)


async def test_unknown_node_lists_recorded_nodes(tmp_path: Path, no_live_calls: None) -> None:
    path = tmp_path / "t.jsonl"
    await record(path, [req("q")], ["A"])
    with pytest.raises(ReplayMissError, match=r"no request of this node \(nodes recorded: narrator\)"):
        await ReplayClient(path).complete(req("q", node="describer"))


async def test_failed_attempts_are_not_served(tmp_path: Path, no_live_calls: None) -> None:
    path = tmp_path / "t.jsonl"
    boom = RateLimitError(message="slow down", llm_provider="openai", model="m")
    await record(path, [req("q")], [boom, "", "final answer"], model="openai/gpt-4o-mini")
    recs = list(read_trace(path).attempts())
    assert [r.final for r in recs] == [False, False, True]
    resp = await ReplayClient(path).complete(req("q"))
    assert resp.text == "final answer" and resp.attempts == 3 and resp.model == "openai/gpt-4o-mini"


async def test_a_call_that_failed_replays_as_the_same_error(tmp_path: Path, no_live_calls: None) -> None:
    """A call whose every attempt failed raised an LLMError at record time (a prompt over the
    context window, a provider out of retries): the replay raises the same type and message,
    then serves the next recorded call of the same request."""
    from litellm.exceptions import ContextWindowExceededError

    from storyteller.agents.llm_port import LLMError

    path = tmp_path / "t.jsonl"
    too_long = ContextWindowExceededError(message="Requested tokens (4895) exceed context window", model="m",
                                          llm_provider="openai")
    cfg = default_config()
    cfg = cfg.model_copy(update={"nodes": {k: v.model_copy(update={"model": "openai/gpt-4o-mini"}) for k, v in cfg.nodes.items()}})
    client = LiteLLMClient(cfg, TraceWriter(path), acompletion=ScriptedProvider([too_long, "second time lucky"]),
                           sleep=no_sleep, check_local=lambda m: None)
    with pytest.raises(LLMError) as recorded:
        await client.complete(req("a very long prompt"))
    answer = (await client.complete(req("a very long prompt"))).text
    client.close()
    replay = ReplayClient(path, trace_sink=TraceWriter(tmp_path / "replayed.jsonl"))
    with pytest.raises(LLMError) as replayed:
        await replay.complete(req("a very long prompt"))
    assert type(replayed.value) is type(recorded.value) and str(replayed.value) == str(recorded.value)
    assert "ContextWindowExceededError" in str(replayed.value)
    assert (await replay.complete(req("a very long prompt"))).text == answer
    replay.close()
    copied = list(read_trace(tmp_path / "replayed.jsonl").attempts())
    assert [(a.error_type, a.final) for a in copied] == [("ContextWindowExceededError", False), (None, True)]
    assert replayed.value.trace_seqs == (copied[0].seq,)


async def test_tampered_hash_is_corruption(tmp_path: Path) -> None:
    path = tmp_path / "t.jsonl"
    await record(path, [req("q")], ["A"])
    lines = path.read_text(encoding="utf-8").splitlines()
    rec = json.loads(lines[1])
    rec["request"]["messages"][1]["content"] = "edited by hand"
    lines[1] = json.dumps(rec)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(TraceCorruptError, match="line 2"):
        ReplayClient(path)


async def test_build_llm_port_modes(tmp_path: Path, no_live_calls: None) -> None:
    recorded = tmp_path / "rec.jsonl"
    await record(recorded, [req("q")], ["A"])
    cfg = default_config()
    again = tmp_path / "again.jsonl"
    port = build_llm_port(cfg, record=again, replay=recorded)
    assert isinstance(port, ReplayClient)
    resp = await port.complete(req("q", frame=5))
    assert resp.trace_seq is not None
    port.trace.record_applied([resp.trace_seq], sim_frame=30, step=0, requested_frame=5)
    port.close()
    recs = read_trace(again).records
    kinds = [r.kind for r in recs]
    assert kinds == ["run", "attempt", "applied"]
    att = recs[1]
    assert isinstance(att, AttemptRecord) and att.response_text == "A" and att.request.sim_frame == 5
    assert att.params["replayed_from_seq"] == 1
    with pytest.raises(ConfigError, match="--record"):
        build_llm_port(cfg, record=recorded, replay=recorded)
    live = build_llm_port(cfg, record=tmp_path / "live.jsonl")
    assert isinstance(live, LiteLLMClient)
    live.close()
    assert [r.kind for r in read_trace(tmp_path / "live.jsonl").records] == ["run"]

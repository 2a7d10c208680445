"""Trace durability off the event loop: with ``fsync="always"`` a write never fsyncs in the
caller's thread, ``sync`` / ``durable`` wait until an fsync covered every record written, the LLM
client returns only once its attempt is on disk, the planning graph logs a step's outcome only
once the step's records are, and a failed fsync is raised (naming the file), never lost."""

from __future__ import annotations

import asyncio
import errno
import os
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest

from storyteller.orchestrator.llm.config import FsyncPolicy
from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.llm.traces import read_trace
from tests.support.trace_records import attempt

Fsyncs = list[tuple[int, int, int]]
"""(thread ident, fd, file size at the fsync) of every fsync."""


def watch_fsyncs(monkeypatch: pytest.MonkeyPatch, before: Callable[[], None] | None = None) -> Fsyncs:
    seen: Fsyncs = []
    real = os.fsync

    def fsync(fd: int) -> None:
        if before is not None:
            before()
        seen.append((threading.get_ident(), fd, os.fstat(fd).st_size))
        real(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    return seen


def test_write_never_fsyncs_in_the_callers_thread(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    seen = watch_fsyncs(monkeypatch)
    path = tmp_path / "t.jsonl"
    w = TraceWriter(path, fsync="always")
    for _ in range(20):
        attempt(w)
    w.sync()
    me = threading.get_ident()
    assert seen and all(thread != me for thread, _, _ in seen)
    assert seen[-1][2] == path.stat().st_size  # the last fsync covered every record
    w.close()
    assert len(read_trace(path).records) == 21


def test_durable_lets_the_loop_run_while_the_disk_syncs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The fsync waits for a task on the event loop: ``durable`` blocking the loop would never
    return (the wait gives up after 10 s and the test fails instead of hanging)."""
    loop_ran = threading.Event()
    gate_open = threading.Event()

    def gate() -> None:
        if gate_open.is_set():
            return
        assert loop_ran.wait(10), "the event loop was blocked while the trace synced"
        gate_open.set()

    path = tmp_path / "t.jsonl"
    w = TraceWriter(path, fsync="always")
    w.sync()
    seen = watch_fsyncs(monkeypatch, gate)

    async def main() -> None:
        async def tick() -> None:
            await asyncio.sleep(0)
            loop_ran.set()

        attempt(w)
        task = asyncio.ensure_future(tick())
        await w.durable()
        await task

    asyncio.run(main())
    assert gate_open.is_set() and seen[-1][2] == path.stat().st_size
    w.close()


def test_fsync_policies_close_and_never_leave_writes_alone(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import anyio.to_thread

    def no_thread(*_: object, **__: object) -> None:
        raise AssertionError("durable() left the task although nothing waits for an fsync")

    monkeypatch.setattr(anyio.to_thread, "run_sync", no_thread)
    seen = watch_fsyncs(monkeypatch)
    policies: tuple[tuple[FsyncPolicy, int], ...] = (("close", 1), ("never", 0))
    for policy, fsyncs in policies:
        w = TraceWriter(tmp_path / f"{policy}.jsonl", fsync=policy)
        attempt(w)
        w.sync()
        asyncio.run(w.durable())
        assert not seen
        w.close()
        assert len(seen) == fsyncs
        seen.clear()


def test_a_failed_fsync_is_raised_by_the_next_call(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "t.jsonl"
    w = TraceWriter(path, fsync="always")
    w.sync()

    def broken(fd: int) -> None:
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(os, "fsync", broken)
    attempt(w)
    with pytest.raises(OSError, match="fsync failed") as info:
        w.sync()
    assert info.value.filename == str(path)
    with pytest.raises(OSError, match="fsync failed"):
        attempt(w)
    with pytest.raises(OSError, match="fsync failed"):
        w.close()
    w.close()  # closed: nothing left to raise
    assert len(read_trace(path).records) == 2  # the records written before stay whole


def test_the_client_returns_once_its_attempt_is_on_disk(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import litellm

    from storyteller.agents.llm_port import ChatMessage, LLMRequest
    from storyteller.orchestrator.llm.client import LiteLLMClient
    from storyteller.orchestrator.llm.config import default_config

    async def answer(**_: object) -> litellm.ModelResponse:
        return litellm.ModelResponse(
            choices=[{"index": 0, "finish_reason": "stop", "message": {"role": "assistant", "content": "hello"}}],
            usage={"prompt_tokens": 3, "completion_tokens": 1, "total_tokens": 4},
        )

    path = tmp_path / "t.jsonl"
    client = LiteLLMClient(default_config(), TraceWriter(path, fsync="always"), acompletion=answer)
    seen = watch_fsyncs(monkeypatch)
    request = LLMRequest(node="event_parser", messages=(ChatMessage(role="user", content="write a program"),))
    response = asyncio.run(client.complete(request))
    assert response.text == "hello" and response.trace_seq == 1
    assert seen and seen[-1][2] == path.stat().st_size  # the attempt was fsynced before complete returned
    client.close()


def test_a_steps_outcome_is_logged_off_the_loop_after_its_records_are_on_disk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from langgraph.checkpoint.memory import InMemorySaver

    from storyteller.agents.llm_port import LLMRequest, LLMResponse
    from storyteller.agents.messages import CharacterStatus
    from storyteller.orchestrator.planning.checkpoints import Outcome, StoryLog
    from storyteller.orchestrator.planning.graph import compile_planning_graph, recursion_limit
    from storyteller.orchestrator.planning.state import PlanningState
    from tests.support.planning_script import DESCRIPTION, PROGRAM, make_deps, narration
    from tests.support.scripted_llm import ScriptedLLM

    path = tmp_path / "t.jsonl"
    trace = TraceWriter(path, fsync="always")
    seen = watch_fsyncs(monkeypatch)
    logged: list[tuple[int, bool]] = []  # (step, its records on disk then)

    class WatchedLog(StoryLog):
        def record(self, index: int, outcome: Outcome, trace_seqs: Sequence[int] = ()) -> None:
            assert threading.get_ident() != loop_thread, "the story log was written on the event loop"
            logged.append((index, bool(seen) and seen[-1][2] == path.stat().st_size))
            super().record(index, outcome, trace_seqs)

    class TracedPort(ScriptedLLM):  # answers numbered in the trace, so their parsed records are written
        async def complete(self, request: LLMRequest) -> LLMResponse:
            resp = await super().complete(request)
            return resp.model_copy(update={"trace_seq": trace.next_seq()})

    port = TracedPort({
        "describer": [DESCRIPTION],
        "narrator": [narration(["Ann"], "eat at table_1")],
        "event_parser": [PROGRAM.format(who="Ann")],
    })
    story = WatchedLog(":memory:", "t1")
    start = PlanningState(instruction="Ann eats.", events_target=1, roster=(CharacterStatus(name="Ann"),)).model_dump()

    async def main() -> None:
        await compile_planning_graph(InMemorySaver()).ainvoke(
            start, config={"configurable": {"thread_id": "t1"}, "recursion_limit": recursion_limit(1, 3)},
            context=make_deps(port, story, trace=trace), durability="sync",
        )

    loop_thread = threading.get_ident()  # asyncio.run runs the loop in this thread
    asyncio.run(main())
    trace.close()
    assert logged == [(0, True)]
    parsed = [r for r in read_trace(path).records if r.kind == "parsed"]
    assert [p.node for p in parsed] == ["describer", "narrator", "event_parser"]

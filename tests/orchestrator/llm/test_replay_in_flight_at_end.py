"""A step still in flight when a recorded story ended replays to the same end, exit 0.

When a realtime run's ``--duration`` is reached while a planning step waits for the model, the
trace holds that step's request (its ``requested`` record and a call cut short by the end's
cancellation) and no answer. Its replay makes the same request at the same frame; the replay
port (``unanswered="wait"`` in a story session, ``storyteller.orchestrator.llm.replay``) lets it wait, as
the recorded call did, until the session ends, so the replay writes the recorded story and
exits 0. A request that is not the recorded one (an edited prompt, another frame, the default
``"miss"`` port of ``plan``) is still a replay miss: one error line, exit 2.

Unit tests on :class:`ReplayClient` with a trace recorded by the live client; command-line tests
run ``storyteller run`` in realtime pace against the fake OpenAI server, whose second answer
comes a minute late, so the story's end always finds step 1 in flight.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import anyio
import pytest

from storyteller.agents.llm_port import ChatMessage, LLMRequest, ReplayMissError
from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.orchestrator.llm.client import LiteLLMClient
from storyteller.orchestrator.llm.config import default_config
from storyteller.orchestrator.llm.replay import ReplayClient
from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.llm.traces import read_trace
from tests.support.story_planner import RUN, first_free, write_config


def req(user: str, frame: int) -> LLMRequest:
    return LLMRequest(node="planner", messages=(ChatMessage(role="system", content="You plan a story."),
                                                ChatMessage(role="user", content=user)), sim_frame=frame)


class Provider:
    """Answers ``answers`` in order; ``None`` waits until the call is cancelled."""

    def __init__(self, answers: list[str | None]) -> None:
        self.answers = list(answers)
        self.waiting = anyio.Event()

    async def __call__(self, **kwargs: Any) -> Any:
        answer = self.answers.pop(0)
        if answer is None:
            self.waiting.set()
            await anyio.sleep_forever()
        return SimpleNamespace(choices=[SimpleNamespace(message=SimpleNamespace(content=answer), finish_reason="stop")],
                               usage=SimpleNamespace(prompt_tokens=7, completion_tokens=3))


async def no_sleep(_: float) -> None:
    return None


async def cut_short(client: Any, request: LLMRequest, waiting: anyio.Event) -> None:
    """Ask ``request`` and cancel the call once it waits (the story ended meanwhile)."""
    async with anyio.create_task_group() as tg:
        tg.start_soon(client.complete, request)
        await waiting.wait()
        tg.cancel_scope.cancel()


async def recorded(path: Path, answers: list[str | None], asks: list[LLMRequest]) -> None:
    provider = Provider(answers)
    client = LiteLLMClient(default_config(), TraceWriter(path), acompletion=provider, sleep=no_sleep,
                           check_local=lambda m: None)
    for request, answer in zip(asks, answers, strict=True):
        if answer is None:
            await cut_short(client, request, provider.waiting)
            provider.waiting = anyio.Event()
        else:
            await client.complete(request)
    client.close()


async def test_an_unanswered_call_waits_until_cancelled_and_is_traced_again(tmp_path: Path) -> None:
    path = tmp_path / "t.jsonl"
    await recorded(path, ["step 0", None], [req("step 0", 1), req("step 1", 14)])
    assert [a.error_type for a in read_trace(path).attempts()] == [None, "CancelledError"]
    replay = ReplayClient(path, trace_sink=TraceWriter(tmp_path / "again.jsonl"), unanswered="wait")
    assert replay.remaining() == 1 and replay.unanswered_calls() == 1
    assert (await replay.complete(req("step 0", 1))).text == "step 0"
    with anyio.move_on_after(0.2) as scope:  # the session's end cancels it; here a deadline does
        await replay.complete(req("step 1", 14))
    assert scope.cancelled_caught and replay.unanswered_calls() == 0
    replay.close()
    again = list(read_trace(tmp_path / "again.jsonl").attempts())
    assert [(a.error_type, a.final, a.request.sim_frame) for a in again] == [(None, True, 1), ("CancelledError", False, 14)]
    # the replay's own trace replays alike
    twice = ReplayClient(tmp_path / "again.jsonl", unanswered="wait")
    assert twice.remaining() == 1 and twice.unanswered_calls() == 1


async def test_an_unanswered_call_is_a_miss_elsewhere(tmp_path: Path) -> None:
    path = tmp_path / "t.jsonl"
    await recorded(path, ["step 0", None], [req("step 0", 1), req("step 1", 14)])
    with pytest.raises(ReplayMissError, match=r"cut short and never answered; a replay without a story session"):
        await ReplayClient(path).complete(req("step 1", 14))  # plan's port: no session ends it
    with pytest.raises(ReplayMissError, match=r"never answered; it was asked at frame 14, this request at frame 15"):
        await ReplayClient(path, unanswered="wait").complete(req("step 1", 15))
    with pytest.raises(ReplayMissError) as edited:
        await ReplayClient(path, unanswered="wait").complete(req("step 1 edited", 14))
    assert edited.value.diff is not None and "+step 1 edited" in edited.value.diff


async def test_a_call_cut_by_a_stop_and_asked_again_is_served_its_later_answer(tmp_path: Path) -> None:
    """A stopped and resumed run cut the call, then asked it again: that answer counts."""
    path = tmp_path / "t.jsonl"
    await recorded(path, [None, "answer"], [req("step 0", 1), req("step 0", 1)])
    replay = ReplayClient(path, unanswered="wait")
    assert replay.unanswered_calls() == 0 and (await replay.complete(req("step 0", 1))).text == "answer"


# ----- storyteller run, then replay -----------------------------------------------------------
class LateSecond:
    """The first request is answered at once (Zoe's step); every later one a minute late, so the
    story's end (4 s) finds step 1 waiting. :meth:`FakeOpenAI.stop` cuts the wait short."""

    def __init__(self) -> None:
        self.count = 0

    def __call__(self, body: dict[str, Any]) -> Any:
        self.count += 1
        return first_free(body) if self.count == 1 else ("sleep", 60.0)


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-c", "from storyteller.orchestrator.cli.app import app; app()", *args]


def _env(tmp_path: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL", "STORYTELLER_PLANNER_MODEL")}  # fmt: skip
    env.update(FAKE_PROVIDER_KEY="sk-test-123", STORYTELLER_CACHE_DIR=str(tmp_path / "cache"))
    return env


def _replay(tmp_path: Path, run: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(_cli("replay", str(run), "--out", str(out)), env=_env(tmp_path), capture_output=True,
                          text=True, timeout=600)


OUTPUTS = ("story.json", "story.md", "Zoe.track.npz", "Max.track.npz")


@pytest.fixture(scope="module")
def in_flight_at_end(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A realtime run whose step 1 was still waiting for the model when its story ended."""
    tmp_path = tmp_path_factory.mktemp("in_flight")
    out = tmp_path / "run"
    with FakeOpenAI(responder=LateSecond()) as fake:
        cfg = write_config(tmp_path, fake.base, timeout_s=120.0)
        done = subprocess.run(_cli(*RUN, "-d", "4", "--pace", "realtime", "--config", str(cfg), "--out", str(out)),
                              env=_env(tmp_path), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    trace = read_trace(out / "trace.jsonl")
    assert [r.step for r in trace.requests()] == [0, 1]
    assert [a.error_type for a in trace.attempts()] == [None, "CancelledError"]  # step 1: no answer
    assert [s["index"] for s in json.loads((out / "story.json").read_text(encoding="utf-8"))["steps"]] == [0]
    return out


@pytest.mark.slow
def test_a_step_in_flight_at_the_end_replays_byte_identically(in_flight_at_end: Path, tmp_path: Path) -> None:
    again = tmp_path / "again"
    done = _replay(tmp_path, in_flight_at_end, again)  # the server is gone: the trace serves every call
    assert done.returncode == 0, done.stderr[-3000:]
    for name in OUTPUTS:
        assert (again / name).read_bytes() == (in_flight_at_end / name).read_bytes(), name
    third = tmp_path / "third"  # the replay's own trace holds the cut call too: it replays alike
    done = _replay(tmp_path, again, third)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (third / "story.json").read_bytes() == (in_flight_at_end / "story.json").read_bytes()


@pytest.mark.slow
def test_a_genuine_miss_of_that_step_is_still_a_replay_miss(in_flight_at_end: Path, tmp_path: Path) -> None:
    """The cut call's recorded prompt edited (hash kept consistent): the replay's request for
    step 1 is not the recorded one, so it is a miss, not the end of the recorded story."""
    run = tmp_path / "edited"
    shutil.copytree(in_flight_at_end, run, ignore=shutil.ignore_patterns("runs.sqlite*"))
    lines = (run / "trace.jsonl").read_text(encoding="utf-8").splitlines()
    for i, line in enumerate(lines):
        rec = json.loads(line)
        if rec["kind"] == "attempt" and rec["error_type"] == "CancelledError":
            rec["request"]["messages"][-1]["content"] += "\nSeats in use: sofa_1"
            rec["request_hash"] = LLMRequest.model_validate(rec["request"]).content_hash()
            lines[i] = json.dumps(rec)
    (run / "trace.jsonl").write_text("\n".join(lines) + "\n", encoding="utf-8")
    done = _replay(tmp_path, run, tmp_path / "again")
    # a replay miss is a bad file since 530cc6a: one error line, exit 2 (the diff at --log-level INFO)
    assert done.returncode == 2, done.stderr[-3000:]
    assert "the recorded step does not apply" in done.stderr and "replay miss for node planner" in done.stderr

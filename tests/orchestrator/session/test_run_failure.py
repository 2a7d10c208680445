"""A run whose LLM port raises an unexpected exception mid-story: the session's task group is
cancelled, the trace, the story log and the port are closed, no task is left pending, and
the command prints one error line and exits non-zero."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from storyteller.agents.llm_port import LLMRequest, LLMResponse
from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.llm.traces import read_trace
from storyteller.orchestrator.planning.checkpoints import StoryLog
from tests.support.session_world import ScriptedCompletion


class ExplodingPort:
    """The real client over a scripted provider; call ``explode_at`` (1-based) raises a bug."""

    def __init__(self, trace_path: Path, explode_at: int) -> None:
        from storyteller.orchestrator.llm.client import LiteLLMClient
        from storyteller.orchestrator.llm.config import default_config

        self.writer = TraceWriter(trace_path, fsync="never")
        self.inner = LiteLLMClient(default_config(), self.writer, acompletion=ScriptedCompletion(),
                                   check_local=lambda m: None)
        self.explode_at = explode_at
        self.calls = 0
        self.closed = False

    @property
    def trace(self) -> Any:
        return self.inner.trace

    async def complete(self, request: LLMRequest) -> LLMResponse:
        self.calls += 1
        if self.calls == self.explode_at:
            raise RuntimeError("provider adapter bug\nsecond line")
        return await self.inner.complete(request)

    def close(self) -> None:
        self.closed = True
        self.inner.close()


@pytest.fixture
def exploding(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    seen: dict[str, Any] = {"story_closed": 0}

    def open_port(
        config: Path | None, record: Path | None, replay: Path | None, *, unanswered: str = "miss",
        planner: str = "event",
    ) -> tuple[ExplodingPort, str]:
        assert record is not None
        seen["port"] = ExplodingPort(record, explode_at=4)
        return seen["port"], "scripted"

    original = StoryLog.close

    def close(self: StoryLog) -> None:
        seen["story_closed"] += 1
        original(self)

    monkeypatch.setattr("storyteller.orchestrator.session.port_setup.open_port", open_port)
    monkeypatch.setattr(StoryLog, "close", close)
    return seen


ARGS = ["home", "--names", "Ava,Ben", "-d", "20", "--pace", "lockstep", "--planners", "2", "--in-process-programs",
        "--no-interactive", "--instruction", "Everyone reads."]


def test_a_port_bug_cancels_the_run_closes_its_files_and_prints_one_line(exploding: dict[str, Any], tmp_path: Path) -> None:
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["run", *ARGS, "--out", str(out)])
    assert result.exit_code == 1, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert errors == ["error: the run stopped: RuntimeError: provider adapter bug\\x0asecond line"]
    port = exploding["port"]
    assert port.calls >= 4 and port.closed and exploding["story_closed"] == 1  # (a step beside may have asked)
    contents = read_trace(out / "trace.jsonl")  # flushed and whole: no torn line
    assert contents.torn_tail is None and len(list(contents.attempts())) >= 3
    with pytest.raises(ValueError, match="closed"):
        port.writer.record_instruction("late", 0, source="api")


def test_run_story_leaves_no_task_pending_after_the_error(exploding: dict[str, Any], tmp_path: Path) -> None:
    from storyteller.orchestrator.session.run_job import run_story
    from storyteller.orchestrator.session.run_manifest import RunArguments
    from storyteller.sim.scene.bundled import resolve_scene

    args = RunArguments(scene="home", names=("Ava", "Ben"), duration=20.0, pace="lockstep", planners=2,
                        instruction="Everyone reads.")

    async def main() -> set[asyncio.Task[Any]]:
        with pytest.raises(RuntimeError, match="adapter bug"):
            await run_story(resolve_scene("home"), args, out=tmp_path, trace_path=tmp_path / "trace.jsonl",
                            replay=None, in_process_programs=True)
        return asyncio.all_tasks() - {asyncio.current_task()}

    assert asyncio.run(main()) == set()
    assert exploding["port"].closed and exploding["story_closed"] == 1


def test_run_story_stops_the_program_worker_it_was_given_when_the_run_fails(
    exploding: dict[str, Any], tmp_path: Path
) -> None:
    """The command starts the event-program worker (with the scene) before it imports the job and
    hands it to ``run_story``, which stops it however the run ends."""
    from storyteller.orchestrator.sandbox_worker import WorkerRunner
    from storyteller.orchestrator.session.run_job import run_story
    from storyteller.orchestrator.session.run_manifest import RunArguments
    from storyteller.sim.scene.bundled import resolve_scene

    args = RunArguments(scene="home", names=("Ava", "Ben"), duration=20.0, pace="lockstep", planners=2,
                        instruction="Everyone reads.")
    scene = resolve_scene("home")
    programs = WorkerRunner()
    programs.prestart(scene)
    process = programs.process
    assert process is not None

    async def main() -> None:
        with pytest.raises(RuntimeError, match="adapter bug"):
            await run_story(scene, args, out=tmp_path, trace_path=tmp_path / "trace.jsonl", replay=None,
                            programs=programs)

    asyncio.run(main())
    assert programs.process is None and process.poll() is not None
    assert programs.starts == 1  # the one it was given: run_story started none of its own

"""A run killed after its last checkpoint reached the disk resumes and replays as one story (issue 27).

A kill -9 leaves the trace ahead of ``session.snapshot``: the checkpoint writer lags (one write
in progress, one waiting), and with overlapping steps a request is made at a frame where
nothing was applied, so none is taken there. The records written after the checkpoint (a
viewer's instruction, ``requested`` records of steps, ``applied`` records) are already in
``trace.jsonl`` when ``storyteller resume`` goes on from the checkpoint. The resumed run must
not write a step's request twice (a replay then stopped at "step N was requested at frame F
beside steps [], but the replay is at step N+1"), and must make those requests where the trace
says, so the trace it leaves replays to the same story and the same motion.

The killed run is :func:`run_story` in this process in ``lockstep`` pace with two planners (the
story is the same however fast the machine is), against the fake OpenAI server with the
instruction-following planner (``tests/support/directed_planner.py``), and a viewer's
instruction appended to ``viewer_instructions.jsonl`` when the first event starts (a second one
is appended while the run is down: it must take effect after all the killed run traced). The kill is
played by keeping on disk only the checkpoints taken up to the frame the instruction took effect
at (none, if the writer had not written one by then: resumed from frame 0), and stopping the run
once an event was applied well after it (lockstep applies an event at its request frame, so
that request came after the last checkpoint on disk). Resume and replay are the commands.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.llm.traces import AppliedRecord, RequestedRecord, read_trace
from storyteller.orchestrator.session.session_types import SessionCheckpoint, StoryEvent, TimedInstruction
from storyteller.orchestrator.session.viewer_instructions import send_instruction
from tests.support.directed_planner import TOAST, directed
from tests.support.story_planner import write_config

FPS = 30
SECONDS = 40
THREAD = "directed@unified+object-list"  # run_story(thread_id="directed") with the unified planner
WAVES = "Zoe waves at Max"


@pytest.fixture
def env(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setenv("FAKE_PROVIDER_KEY", "sk-test-123")
    for var in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL", "STORYTELLER_PLANNER_MODEL"):
        monkeypatch.delenv(var, raising=False)
    yield


def _killed_run(out: Path, cfg: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[int, int]:
    """The run up to its "kill"; (frame of the last checkpoint on disk, frame it stopped at)."""
    import storyteller.orchestrator.session.snapshot_file as snapshot_file
    from storyteller.orchestrator.session.run_job import run_story
    from storyteller.orchestrator.session.run_manifest import RunArguments
    from storyteller.sim.scene.bundled import resolve_scene

    args = RunArguments(scene="home", names=("Zoe", "Max"), duration=float(SECONDS), pace="lockstep", planners=2,
                        planner="unified", description="object-list", foot_ik=False, config=str(cfg))
    said: list[int] = []
    typed: list[object] = []
    kept: list[int] = []
    real_write = snapshot_file.write_checkpoint

    def write_until_the_instruction(path: Path, cp: SessionCheckpoint, *rest: Any) -> None:
        if not said or cp.world.frame <= said[0]:  # later ones never reach the disk before the kill
            kept.append(cp.world.frame)
            real_write(path, cp, *rest)

    async def main() -> tuple[int, int]:
        stop = asyncio.Event()

        def on_instruction(timed: TimedInstruction, fps: int) -> None:
            said.append(timed.frame)

        def on_event(event: StoryEvent, fps: int) -> None:
            if not typed:  # the first event started: a viewer types an instruction
                typed.append(send_instruction(out, THREAD, WAVES, sent_unix=1.0))
            if said and event.state == "ongoing" and event.applied_frame > said[0] + 2 * FPS:
                stop.set()  # an event requested 2 s after the instruction or later

        run = await run_story(resolve_scene("home"), args, out=out, trace_path=out / "trace.jsonl", replay=None,
                              thread_id="directed", in_process_programs=True, stop=stop, on_event=on_event,
                              on_instruction=on_instruction)
        assert run.stopped, "the story ended before the kill"
        return max(kept, default=0), run.result.frames  # none kept: resumed from frame 0

    with monkeypatch.context() as mp:
        mp.setattr(snapshot_file, "write_checkpoint", write_until_the_instruction)
        return asyncio.run(main())


@pytest.mark.slow
def test_a_run_killed_past_its_last_checkpoint_resumes_and_replays_as_one_story(
    env: None, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "run"
    with FakeOpenAI(responder=directed) as fake:
        cfg = write_config(tmp_path, fake.base)
        checkpoint_frame, stop_frame = _killed_run(out, cfg, monkeypatch)
        before = read_trace(out / "trace.jsonl")
        (instruction,) = before.instructions()
        assert instruction.source == "viewer" and instruction.text == WAVES
        assert checkpoint_frame <= instruction.sim_frame < stop_frame  # the kill came after the instruction
        late = [r.step for r in before.requests() if r.sim_frame > checkpoint_frame]
        assert late, "no step was requested after the last checkpoint on disk"
        send_instruction(out, THREAD, TOAST, sent_unix=2.0)  # typed while the run was down
        reached = max(r.sim_frame for r in before.records if isinstance(r, AppliedRecord | RequestedRecord))

        resumed = CliRunner().invoke(app, ["resume", str(out), "--no-interactive"])
        assert resumed.exit_code == 0, resumed.stderr
        assert f"resuming at frame {checkpoint_frame} " in resumed.stderr

    trace = read_trace(out / "trace.jsonl")
    steps = [r.step for r in trace.requests()]
    assert len(steps) == len(set(steps)), f"a step's request is in the trace twice: {steps}"
    assert steps == sorted(steps) and steps[: len(before.requests())] == [r.step for r in before.requests()]
    applied = [r.step for r in trace.records if isinstance(r, AppliedRecord)]
    assert len(applied) == len(set(applied)), f"a step was applied twice: {applied}"
    said = [(r.sim_frame, r.source, r.text) for r in trace.instructions()]
    assert said[0] == (instruction.sim_frame, "viewer", WAVES)  # applied once, at its frame
    assert [t for _, _, t in said] == [WAVES, TOAST] and said[1][0] > reached  # after all the killed run traced
    story = json.loads((out / "story.json").read_text(encoding="utf-8"))
    assert story["frames"] == SECONDS * FPS
    assert [(i["frame"], i["text"]) for i in story["instructions"]] == [(f, t) for f, _, t in said]

    again = CliRunner().invoke(app, ["replay", str(out), "--out", str(tmp_path / "again")])
    assert again.exit_code == 0, again.stderr
    for name in ("story.json", "story.md", "Zoe.track.npz", "Max.track.npz"):
        assert (tmp_path / "again" / name).read_bytes() == (out / name).read_bytes(), name

"""Live instructions: the narrator always sees the latest one, the trace records the frame
each took effect at, and a replay applies it there again.

The session tests use a scripted planner on the real world (home scene); the CLI test runs
``storyteller run --instructions FILE`` against the fake OpenAI-compatible server
(``benchmark/support/fake_openai_server.py``) and replays the run folder with no model.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import anyio
import pytest
from typer.testing import CliRunner

from storyteller.agents.instruction_parts import instruction_progress, part_states, split_instruction
from storyteller.agents.messages import HistoryEntry
from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.llm.traces import AttemptRecord, InstructionRecord, RunRecord, read_trace
from storyteller.orchestrator.session.instruction_script import (
    InstructionScriptError,
    ScriptLine,
    parse_instruction_script,
    read_instruction_script,
)
from storyteller.orchestrator.session.runtime import Session
from storyteller.orchestrator.session.session_types import SessionResult, SessionSettings, TimedInstruction
from storyteller.orchestrator.session.stdin_instructions import start_stdin_reader
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.scene.model import Scene
from tests.support.cli_run import RUN, Planner, write_config
from tests.support.session_world import FPS, ScriptedPlanner, make_world

OLD = "Ben walks to the kitchen."
NEW = "Ben leaves the kitchen and waves at Ava."


# ----- the session ------------------------------------------------------------------------
def test_requests_after_the_instruction_frame_carry_it_and_earlier_ones_do_not(
    home: Scene, motion: MotionMatcher
) -> None:
    at = 12 * FPS
    planner = ScriptedPlanner(home)
    said: list[TimedInstruction] = []
    settings = SessionSettings(frames=30 * FPS, pace="lockstep", instruction=OLD,
                               instructions=[TimedInstruction(frame=at, text=NEW)])
    session = Session(make_world(home, motion, ["Ava", "Ben"]), planner, settings, on_instruction=said.append)
    result = anyio.run(session.run)
    before = [r for r in planner.requests if r.frame <= at]
    after = [r for r in planner.requests if r.frame > at]
    assert before and after
    assert all(r.instruction == OLD and r.instruction_since == 0 for r in before)
    first_after = after[0].index
    assert all(r.instruction == NEW and r.instruction_since == first_after for r in after)
    assert said == [TimedInstruction(frame=at, text=NEW)] == result.instructions


@pytest.mark.slow
def test_instruct_from_the_api_takes_effect_at_the_next_frame_and_a_replay_ignores_it(
    home: Scene, motion: MotionMatcher
) -> None:
    planner = ScriptedPlanner(home)
    settings = SessionSettings(frames=20 * FPS, pace="fast", instruction=OLD)
    session = Session(make_world(home, motion, ["Ava", "Ben"]), planner, settings)
    took: list[int | None] = []

    async def main() -> SessionResult:
        async with anyio.create_task_group() as tg:
            out: list[SessionResult] = []

            async def run() -> None:
                out.append(await session.run())

            tg.start_soon(run)
            while session.world.frame < 5 * FPS:
                await anyio.sleep(0)
            took.append(await session.instruct(f"  {NEW}\n"))
        return out[0]

    result = anyio.run(main)
    frame = took[0]
    assert frame is not None and frame >= 5 * FPS
    assert result.instructions == [TimedInstruction(frame=frame, text=NEW, source="api")]
    assert all(r.instruction == (NEW if r.frame > frame else OLD) for r in planner.requests)
    assert any(r.instruction == NEW for r in planner.requests)
    with pytest.raises(ValueError, match="must not be empty"):
        session.instruct_nowait("   ")
    assert anyio.run(session.instruct, "too late") is None  # the story has ended

    # a replay takes only the recorded instructions, at their frames
    replayed = ScriptedPlanner(home)
    settings = SessionSettings(frames=20 * FPS, pace="lockstep", instruction=OLD, live_instructions=False,
                               instructions=result.instructions)
    again = Session(make_world(home, motion, ["Ava", "Ben"]), replayed, settings)
    assert not again.instruct_nowait("typed during a replay")
    assert anyio.run(again.run).instructions == result.instructions


def test_stdin_lines_become_instructions(home: Scene, motion: MotionMatcher, tmp_path: Path) -> None:
    typed = tmp_path / "typed.txt"
    typed.write_text("# a comment\n\nBen sits down\n", encoding="utf-8")
    planner = ScriptedPlanner(home)
    session = Session(make_world(home, motion, ["Ava", "Ben"]), planner, SessionSettings(frames=5 * FPS, pace="fast"))
    with typed.open(encoding="utf-8") as stream:
        start_stdin_reader(session, stream).join(timeout=10)
        result = anyio.run(session.run)
    assert [(i.frame, i.text, i.source) for i in result.instructions] == [(0, "Ben sits down", "stdin")]


@pytest.mark.slow
def test_a_resumed_session_keeps_the_instructions_already_applied(
    home: Scene, motion: MotionMatcher, tmp_path: Path
) -> None:
    from storyteller.orchestrator.session.session_types import SessionCheckpoint
    from storyteller.orchestrator.session.snapshot_file import load_checkpoint, save_checkpoint

    first, second = TimedInstruction(frame=6 * FPS, text=OLD), TimedInstruction(frame=20 * FPS, text=NEW)
    settings = SessionSettings(frames=30 * FPS, pace="lockstep", checkpoint_every_s=4.0, instruction="Ava reads.",
                               instructions=[first, second])
    kept: list[SessionCheckpoint] = []
    whole_world = make_world(home, motion, ["Ava", "Ben"])
    whole = anyio.run(Session(whole_world, ScriptedPlanner(home), settings, on_checkpoint=kept.append).run)
    assert whole.instructions == [first, second]
    middle = next(cp for cp in kept if 10 * FPS < cp.world.frame < 20 * FPS)
    path = tmp_path / "session.snapshot"
    save_checkpoint(path, whole_world, middle)

    fresh = make_world(home, motion, ["Ava", "Ben"])
    planner = ScriptedPlanner(home)
    said: list[TimedInstruction] = []
    # as the run job does on resume: the trace already holds both (the second applied before a kill)
    recorded = [i.model_copy(update={"recorded": True}) for i in (first, second)]
    session = Session(fresh, planner, replace(settings, instructions=recorded), on_instruction=said.append)
    session.resume(load_checkpoint(path, fresh))
    assert session.instruction == OLD
    resumed = anyio.run(session.run)
    assert resumed.instructions == [first, second] and said == []  # applied again at its frame, not traced twice
    assert planner.requests and all(
        r.instruction == (NEW if r.frame > second.frame else OLD) for r in planner.requests
    )
    assert resumed.applied_frames == whole.applied_frames and resumed.outcomes == whole.outcomes


def test_resume_schedules_the_recorded_instructions_and_the_script_lines_not_yet_applied(tmp_path: Path) -> None:
    from storyteller.orchestrator.session.run_manifest import RunArguments
    from storyteller.orchestrator.session.run_setup import instructions_from_trace, scheduled_instructions

    args = RunArguments(scene="home", names=("Ava", "Ben"), duration=60.0, instructions=(
        ScriptLine(time_s=5.0, text="Ava sits"), ScriptLine(time_s=40.0, text="Ben waves")))
    fresh = scheduled_instructions(args, FPS, replay=None, recorded=[])
    assert [(i.frame, i.text, i.recorded) for i in fresh] == [(150, "Ava sits", False), (1200, "Ben waves", False)]
    with TraceWriter(tmp_path / "trace.jsonl") as w:  # the run was killed after these two
        w.record_instruction("Ava sits", 150, source="script")
        w.record_instruction("Ben reads", 300, source="stdin")
    said = instructions_from_trace(tmp_path / "trace.jsonl")
    resumed = scheduled_instructions(args, FPS, replay=None, recorded=said)
    assert [(i.frame, i.text, i.source, i.recorded) for i in resumed] == [
        (150, "Ava sits", "script", True), (300, "Ben reads", "stdin", True), (1200, "Ben waves", "script", False)]
    # a replay takes the trace's, not the script's
    assert scheduled_instructions(args, FPS, replay=tmp_path / "trace.jsonl", recorded=[]) == said


# ----- events planned under the old instruction -------------------------------------------
def test_events_before_the_instruction_changed_mark_none_of_its_parts_done() -> None:
    names = ("Ava", "Ben")
    walked = HistoryEntry(index=0, characters=("Ben",), activity="walk to the kitchen", state="completed")
    parts = split_instruction(NEW, names)
    # the old event shares the stem "kit" with the new part: matched by words alone it would be done
    assert part_states(parts, [walked], names) == ["done"]
    assert part_states(parts, [walked], names, since=1) == ["next"]
    progress = instruction_progress(NEW, names, [walked], names, since=1)
    assert progress.next_part == NEW and progress.next_actors == ("Ben",)
    # an event planned under the new instruction still counts
    left = HistoryEntry(index=1, characters=("Ben",), activity="leave the kitchen, waving", state="completed")
    assert part_states(parts, [walked, left], names, since=1) == ["done"]


# ----- the script -------------------------------------------------------------------------
def test_script_lines_parse_to_sorted_simulated_seconds() -> None:
    text = "# who does what\n01:05.5 Ava sits\n\n00:30 Ben leaves the kitchen and waves at Ava\n1:00:00   Ava  sleeps\n7 Ben waves\n"
    assert parse_instruction_script(text) == (
        ScriptLine(time_s=7.0, text="Ben waves"),
        ScriptLine(time_s=30.0, text="Ben leaves the kitchen and waves at Ava"),
        ScriptLine(time_s=65.5, text="Ava sits"),
        ScriptLine(time_s=3600.0, text="Ava sleeps"),
    )


@pytest.mark.parametrize(("line", "expected"), [
    ("Ben waves", "line 2: expected 'TIME TEXT'"),
    ("00:30", "line 2: expected 'TIME TEXT'"),
    ("-0:30 Ben waves", "line 2: expected 'TIME TEXT'"),
    ("00:75 Ben waves", "line 2: seconds must be below 60 in '00:75'"),
    ("1:75:00 Ben waves", "line 2: minutes must be below 60 in '1:75:00'"),
])
def test_a_bad_script_line_names_the_file_and_the_line(tmp_path: Path, line: str, expected: str) -> None:
    path = tmp_path / "script.txt"
    path.write_text(f"00:10 Ava sits\n{line}\n", encoding="utf-8")
    with pytest.raises(InstructionScriptError, match=f"^{path}: {expected}"):
        read_instruction_script(path)


def test_a_bad_script_is_a_user_error_on_the_command_line(tmp_path: Path) -> None:
    path = tmp_path / "script.txt"
    path.write_text("00:10 Ava sits\nsoon Ben waves\n", encoding="utf-8")
    result = CliRunner().invoke(app, ["run", "home", "--instructions", str(path), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert result.stderr.count("\n") == 1 and f"error: {path}: line 2: expected 'TIME TEXT'" in result.stderr
    missing = CliRunner().invoke(app, ["run", "home", "--instructions", str(tmp_path / "nope.txt")])
    assert missing.exit_code == 2 and "cannot read the instruction script" in missing.stderr


def test_trace_instruction_records_round_trip(tmp_path: Path) -> None:
    with TraceWriter(tmp_path / "t.jsonl") as w:
        w.record_instruction("Ben waves", 150, source="script")
    records = read_trace(tmp_path / "t.jsonl").records
    assert [type(r) for r in records] == [RunRecord, InstructionRecord]
    (rec,) = read_trace(tmp_path / "t.jsonl").instructions()
    assert (rec.text, rec.sim_frame, rec.source) == ("Ben waves", 150, "script")


# ----- the command line: script, trace, replay --------------------------------------------
@pytest.mark.usefixtures("env")
@pytest.mark.slow
def test_run_with_an_instruction_script_records_it_and_the_replay_reproduces_the_story(tmp_path: Path) -> None:
    script = tmp_path / "script.txt"
    script.write_text("# the plot\n00:08 Max makes toast for Zoe\n", encoding="utf-8")
    at = 8 * FPS
    with FakeOpenAI(responder=Planner()) as fake:
        cfg = write_config(tmp_path, fake.base)
        live = CliRunner().invoke(app, [*RUN, "-i", "Zoe makes coffee", "--instructions", str(script),
                                        "--config", str(cfg), "--out", str(tmp_path / "live")], catch_exceptions=False)
        assert live.exit_code == 0, live.stderr
    assert "[    8.0s] instruction (script): Max makes toast for Zoe" in live.stdout
    run_dir = tmp_path / "live"
    trace = read_trace(run_dir / "trace.jsonl")
    (rec,) = trace.instructions()
    assert (rec.text, rec.sim_frame, rec.source) == ("Max makes toast for Zoe", at, "script")
    attempts = list(trace.attempts())
    before = [a for a in attempts if a.request.sim_frame is not None and a.request.sim_frame <= at]
    after = [a for a in attempts if a.request.sim_frame is not None and a.request.sim_frame > at]
    assert before and after

    def says(a: AttemptRecord, text: str) -> bool:
        return any(text in m.content for m in a.request.messages)

    assert all(says(a, "Zoe makes coffee") and not says(a, "Max makes toast for Zoe") for a in before)
    assert all(says(a, "Max makes toast for Zoe") and not says(a, "Zoe makes coffee") for a in after)
    story = json.loads((run_dir / "story.json").read_text(encoding="utf-8"))
    assert story["instructions"] == [{"frame": at, "time_s": 8.0, "source": "script", "text": "Max makes toast for Zoe"}]
    assert json.loads((run_dir / "run.json").read_text(encoding="utf-8"))["arguments"]["instructions"] == [
        {"time_s": 8.0, "text": "Max makes toast for Zoe"}
    ]

    # no model: the replay applies the recorded instruction at its frame (the script file is gone)
    script.unlink()
    again = CliRunner().invoke(app, ["replay", str(run_dir), "--out", str(tmp_path / "again")], catch_exceptions=False)
    assert again.exit_code == 0, again.stderr
    for name in ("story.json", "story.md", "Zoe.track.npz", "Max.smplx.npz"):
        assert (tmp_path / "again" / name).read_bytes() == (run_dir / name).read_bytes(), name
    (replayed,) = read_trace(tmp_path / "again" / "trace.jsonl").instructions()
    assert (replayed.text, replayed.sim_frame) == (rec.text, rec.sim_frame)

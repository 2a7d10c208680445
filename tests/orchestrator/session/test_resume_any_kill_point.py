"""A story session with overlapping steps, killed at any line of its trace, resumes and replays as one story.

Issue 27: a kill leaves ``trace.jsonl`` ahead of the last checkpoint on disk (requests,
instructions and applied steps written after it). The run job's own set-up reads what a resume
and a replay read (:func:`~storyteller.orchestrator.session.run_setup.read_recorded`,
:func:`~storyteller.orchestrator.session.run_setup.session_settings`); the session and the trace writer are
the real ones, in ``fast`` pace with three planners and random wall-clock sleeps in the planner,
so steps land at frames that differ from run to run as in ``realtime``. The planner answers by
request content (as the fake provider does) and from a story log for the steps it finished
before the kill (as :class:`~storyteller.orchestrator.session.step_planner.GraphStepPlanner` does).

For a kill after each line of the trace (the checkpoint on disk then: the last one taken
before that line was written; the story log: the steps finished before it), with an instruction
a viewer sent while the run was down, the resumed session must run to the end with no step
requested or applied twice in its trace and the new instruction after all it traced, and a replay
of that trace must ask every step with the request its answer came from (what a replay port
matches on), and give the same story and bit-identical motion.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from pathlib import Path

import anyio
import numpy as np
import pytest

from storyteller.agents.messages import Event, ParsedEvent, PlannedCharacter
from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.llm.traces import AppliedRecord, InstructionRecord, RequestedRecord, read_trace
from storyteller.orchestrator.planning.state import StepProgress
from storyteller.orchestrator.session.instruction_script import ScriptLine
from storyteller.orchestrator.session.run_manifest import RunArguments
from storyteller.orchestrator.session.run_setup import read_recorded, session_settings
from storyteller.orchestrator.session.runtime import Session
from storyteller.orchestrator.session.session_types import (
    Outcome,
    PlanningRequest,
    SessionCheckpoint,
    SessionResult,
    SessionSettings,
)
from storyteller.orchestrator.session.snapshot_file import load_checkpoint, save_checkpoint
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.step import World
from tests.support.session_world import FPS, free_points, make_world

NAMES = ("Ava", "Ben", "Cleo", "Dan")
ARGS = RunArguments(scene="home", names=NAMES, duration=24.0, pace="fast", planners=3,
                    instructions=(ScriptLine(time_s=5.0, text="Everyone takes a break."),))
TYPED = "Ben and Cleo chat."


class LoggedPlanner:
    """The first one or two free characters do a short action at a free spot (every fifth step
    is a wait); the step names them after a narrator call and answers after a parser call, with
    random wall-clock sleeps. ``log``: step -> outcome finished before a kill, answered at once."""

    def __init__(self, scene: Scene, trace: Path, *, seed: int, log: dict[int, Outcome] | None = None) -> None:
        self.spots = free_points(scene, 12, seed=7)
        self.rng = random.Random(seed)
        self.trace = trace
        self.log = dict(log or {})
        self.asked: dict[int, PlanningRequest] = {}
        """The request of each step asked here (not answered from the log)."""
        self.finished: list[tuple[int, int, Outcome]] = []
        """(bytes of the trace when it finished, step, outcome): the story log's rows in order."""

    async def _nap(self) -> None:
        await anyio.sleep(self.rng.uniform(0.0, 0.004))

    async def plan(self, request: PlanningRequest, progress: StepProgress | None = None) -> Outcome:
        if request.index in self.log:
            return self.log[request.index]
        assert progress is not None
        self.asked[request.index] = request
        await self._nap()
        progress.llm_call("narrator", 1.0)
        free = [c.name for c in request.roster if not c.busy]
        outcome: Outcome = None
        if request.index % 5 != 4 and free:
            who = free[: 2 if len(free) > 2 and request.index % 2 else 1]
            progress.claim(who, f"step {request.index}")
            await self._nap()
            progress.llm_call("event_parser", 2.0)
            plans = []
            for k, name in enumerate(who):
                x, y = self.spots[(request.index * 3 + k) % len(self.spots)]
                plans.append(PlannedCharacter(character=name, action="use_smartphone" if k == 0 else "drink",
                                              area="a free spot", position=(x, y), facing=(1.0, 0.0)))
            outcome = ParsedEvent(index=request.index, plans=tuple(plans),
                                  event=Event(characters=tuple(who), activity=f"step {request.index}"))
        self.finished.append((self.trace.stat().st_size, request.index, outcome))
        return outcome


def _play(world: World, planner: LoggedPlanner, settings: SessionSettings, trace: Path,
          checkpoint: SessionCheckpoint | None = None, keep: Callable[[SessionCheckpoint], None] | None = None,
          typed: str | None = None) -> tuple[SessionResult, World]:
    """The session as the run job wires it to its trace (requests, instructions, applied steps);
    ``typed``: an instruction sent before it starts (a viewer's line sent while the run was down)."""
    with TraceWriter(trace, fsync="never") as writer:

        async def main() -> tuple[SessionResult, World]:
            session = Session(
                world, planner, settings, trace=writer, on_checkpoint=keep,
                on_request=lambda r: writer.record_requested(r.step, r.frame, phase=r.phase, after_steps=r.after),
                on_instruction=lambda i: writer.record_instruction(i.text, i.frame, source=i.source),
            )
            if checkpoint is not None:
                session.resume(checkpoint)
            if typed is not None:
                session.instruct_nowait(typed, "viewer")
            return await session.run(), session.world

        return anyio.run(main)


def _story(result: SessionResult) -> list[object]:
    return [result.frames, result.outcomes, result.applied_frames,
            [(e.event_id, e.state, e.applied_frame, e.finished_frame) for e in result.events],
            [(i.frame, i.text, i.source) for i in result.instructions]]


@pytest.mark.slow
def test_a_session_killed_at_any_line_of_its_trace_resumes_and_replays_the_same(
    home: Scene, motion: MotionMatcher, tmp_path: Path
) -> None:
    killed_trace = tmp_path / "killed.jsonl"
    kept: list[tuple[int, SessionCheckpoint]] = []  # (bytes of the trace when taken, checkpoint)
    killed = LoggedPlanner(home, killed_trace, seed=1)
    first = make_world(home, motion, list(NAMES))
    settings = session_settings(ARGS, FPS, read_recorded(ARGS, FPS, trace_path=None, replay=None, resume=False),
                                live=True)
    _play(first, killed, settings, killed_trace, keep=lambda cp: kept.append((killed_trace.stat().st_size, cp)))
    whole = killed_trace.read_bytes()
    ends = [i + 1 for i, byte in enumerate(whole) if byte == ord("\n")]
    records = read_trace(killed_trace).records
    assert len(records) == len(ends)
    # kills just after a request that no checkpoint followed at once (what this issue is about)
    taken = {size for size, _ in kept}
    late = [end for end, record in zip(ends, records, strict=True)
            if isinstance(record, RequestedRecord) and end not in taken]
    assert len(late) >= 3, "no request was traced after the last checkpoint"

    for n, end in enumerate(ends):  # killed just after line n
        folder = tmp_path / f"kill{n}"
        folder.mkdir()
        trace = folder / "trace.jsonl"
        trace.write_bytes(whole[:end])
        reached = max((r.sim_frame for r in read_trace(trace).records
                       if isinstance(r, AppliedRecord | RequestedRecord | InstructionRecord)), default=-1)
        on_disk = [cp for size, cp in kept if size <= end]
        checkpoint = None
        fresh = make_world(home, motion, list(NAMES))
        if on_disk:
            save_checkpoint(folder / "session.snapshot", first, on_disk[-1])
            checkpoint = load_checkpoint(folder / "session.snapshot", fresh)
        log = {step: outcome for size, step, outcome in killed.finished if size <= end}
        resumed = LoggedPlanner(home, trace, seed=100 + n, log=log)
        again = session_settings(ARGS, FPS, read_recorded(ARGS, FPS, trace_path=trace, replay=None, resume=True),
                                 live=True)
        result, world = _play(fresh, resumed, again, trace, checkpoint, typed=TYPED)
        assert result.frames == round(ARGS.duration * FPS)
        contents = read_trace(trace)
        requested = [r.step for r in contents.requests()]
        assert len(requested) == len(set(requested)), f"kill {n}: a step requested twice: {requested}"
        applied = [r.step for r in contents.records if isinstance(r, AppliedRecord)]
        assert len(applied) == len(set(applied)), f"kill {n}: a step applied twice: {applied}"
        # the typed line takes effect at the first frame after all the trace shows (none left: never)
        due = max(reached + 1, checkpoint.world.frame if checkpoint is not None else 0)
        typed = [i.frame for i in result.instructions if i.text == TYPED]
        assert typed == ([due] if due < result.frames else []), f"kill {n}"

        replayer = LoggedPlanner(home, folder / "replay.jsonl", seed=200 + n)
        replay = session_settings(ARGS, FPS, read_recorded(ARGS, FPS, trace_path=None, replay=trace, resume=False),
                                  live=False)
        replayed, replay_world = _play(make_world(home, motion, list(NAMES)), replayer, replay, folder / "replay.jsonl")
        assert _story(replayed) == _story(result), f"kill {n}"
        expected = {**killed.asked, **resumed.asked}
        for step, request in replayer.asked.items():
            assert request == expected[step], f"kill {n}: step {step} was asked otherwise in the replay"
        a, b = world.tracks(), replay_world.tracks()
        for name in NAMES:
            assert np.array_equal(a[name].root_positions, b[name].root_positions), (n, name)
            assert np.array_equal(a[name].local_rotations, b[name].local_rotations), (n, name)

"""The story session: simulation and planner concurrently, replayable frame by frame.

A scripted planner stands in for the LLM graph (the graph has its own tests); the world,
paths and motion matching are the real ones on the bundled home scene.
"""

from __future__ import annotations

import itertools
from collections.abc import Awaitable, Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, cast

import anyio
import numpy as np
import pytest

from storyteller.agents.llm_port import LLMError, LLMPort
from storyteller.agents.messages import Event, ParsedEvent, PlannedCharacter, PlanningFailure
from storyteller.orchestrator.planning.state import StepProgress
from storyteller.orchestrator.session.frame_profile import PARTS
from storyteller.orchestrator.session.pace import Pace
from storyteller.orchestrator.session.runtime import Session
from storyteller.orchestrator.session.session_types import (
    Outcome,
    PlanningRequest,
    SessionError,
    SessionResult,
    SessionSettings,
    StepPlanner,
)
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.step import World
from tests.support.session_world import (
    FPS,
    ScriptedCompletion,
    ScriptedPlanner,
    free_points,
    make_world,
)

if TYPE_CHECKING:

    from storyteller.orchestrator.llm.trace_writer import TraceSink
    from storyteller.orchestrator.llm.traces import AppliedRecord

def _run(world: World, planner: StepPlanner, settings: SessionSettings) -> SessionResult:
    async def main() -> SessionResult:
        return await Session(world, planner, settings).run()

    return anyio.run(main)


def test_lockstep_session_plans_and_completes_events(home: Scene, motion: MotionMatcher) -> None:
    world = make_world(home, motion, ["Ava", "Ben"])
    planner = ScriptedPlanner(home)
    result = _run(world, planner, SessionSettings(frames=40 * FPS, pace="lockstep", max_steps=6))
    assert result.frames == 40 * FPS
    waits = sum(o is None for _, o in result.outcomes)
    assert waits == 1 and result.steps == 6 + waits  # a step that comes back as a wait does not count
    # lockstep: every result is applied at the frame its request was made
    assert [r.frame for r in planner.requests] == result.applied_frames
    kinds = [type(o).__name__ for _, o in result.outcomes]
    assert "NoneType" in kinds and "PlanningFailure" in kinds and "ParsedEvent" in kinds
    assert any(e.state == "completed" for e in result.events)
    # requests only name characters who were free at that frame, and busy ones are marked busy
    for req in planner.requests:
        assert any(not c.busy for c in req.roster)
    tracks = world.tracks()
    assert set(tracks) == {"Ava", "Ben"}
    assert all(t.root_positions.shape == (40 * FPS, 3) for t in tracks.values())


def test_live_run_replays_to_identical_events_and_motion(home: Scene, motion: MotionMatcher) -> None:
    live_world = make_world(home, motion, ["Ava", "Ben", "Cleo"])
    live = _run(live_world, ScriptedPlanner(home, delays=True), SessionSettings(frames=30 * FPS, pace="fast", max_steps=8))
    assert live.steps >= 3
    replay_world = make_world(home, motion, ["Ava", "Ben", "Cleo"])
    replayed = _run(
        replay_world,
        ScriptedPlanner(home),
        SessionSettings(frames=30 * FPS, pace="fast", applied_frames=live.applied_frames),
    )
    assert replayed.applied_frames == live.applied_frames
    assert [(e.event_id, e.state, e.applied_frame, e.finished_frame) for e in replayed.events] == [
        (e.event_id, e.state, e.applied_frame, e.finished_frame) for e in live.events
    ]
    a, b = live_world.tracks(), replay_world.tracks()
    for name in a:
        assert np.array_equal(a[name].root_positions, b[name].root_positions)
        assert np.array_equal(a[name].local_rotations, b[name].local_rotations)


def test_a_session_resumed_from_a_saved_checkpoint_ends_as_the_uninterrupted_one(
    home: Scene, motion: MotionMatcher, tmp_path: Path
) -> None:
    from storyteller.orchestrator.session.session_types import SessionCheckpoint
    from storyteller.orchestrator.session.snapshot_file import load_checkpoint, save_checkpoint

    names = ["Ava", "Ben", "Cleo"]
    settings = SessionSettings(frames=30 * FPS, pace="lockstep", max_steps=8, checkpoint_every_s=4.0)
    kept: list[SessionCheckpoint] = []
    whole_world = make_world(home, motion, names)

    async def whole_run() -> tuple[SessionResult, World]:
        session = Session(whole_world, ScriptedPlanner(home), settings, on_checkpoint=kept.append)
        return await session.run(), session.world

    whole, whole_end = anyio.run(whole_run)
    # one checkpoint after every applied step, and at least one every 4 simulated seconds
    assert len(kept) >= whole.steps and all(b.world.frame - a.world.frame <= 4 * FPS for a, b in itertools.pairwise(kept))
    middle = next(cp for cp in kept if cp.world.frame > 8 * FPS)
    assert 0 < len(middle.outcomes) < whole.steps
    path = tmp_path / "session.snapshot"
    save_checkpoint(path, whole_world, middle)
    assert path.stat().st_size < 20_000_000  # the motion layer and the grids are stored by name only

    fresh = make_world(home, motion, names)
    planner = ScriptedPlanner(home)

    async def resumed_run() -> tuple[SessionResult, World]:
        session = Session(fresh, planner, settings)
        session.resume(load_checkpoint(path, fresh))
        assert session.world.frame == middle.world.frame
        return await session.run(), session.world

    resumed, resumed_end = anyio.run(resumed_run)
    # nothing applied before the checkpoint is asked again (a step in flight then is)
    first = middle.in_flight.index if middle.in_flight is not None else middle.steps
    assert [r.index for r in planner.requests] == list(range(first, whole.steps))
    assert resumed.applied_frames == whole.applied_frames and resumed.outcomes == whole.outcomes
    assert [(e.event_id, e.state, e.applied_frame, e.finished_frame) for e in resumed.events] == [
        (e.event_id, e.state, e.applied_frame, e.finished_frame) for e in whole.events
    ]
    a, b = whole_end.tracks(), resumed_end.tracks()
    for name in names:
        assert np.array_equal(a[name].root_positions, b[name].root_positions)
        assert np.array_equal(a[name].local_rotations, b[name].local_rotations)


def test_replay_with_frames_that_cannot_fit_is_an_error(home: Scene, motion: MotionMatcher) -> None:
    world = make_world(home, motion, ["Ava"])
    with pytest.raises(SessionError, match="replay"):
        _run(world, ScriptedPlanner(home), SessionSettings(frames=5 * FPS, applied_frames=[10, 0]))


def test_planner_crash_stops_planning_but_not_the_simulation(home: Scene, motion: MotionMatcher) -> None:
    world = make_world(home, motion, ["Ava", "Ben"])
    result = _run(world, ScriptedPlanner(home, fail_at=1), SessionSettings(frames=10 * FPS, pace="lockstep"))
    assert result.frames == 10 * FPS
    assert isinstance(result.planner_error, LLMError)
    assert result.steps == 1


def test_settings_are_checked(home: Scene, motion: MotionMatcher) -> None:
    world = make_world(home, motion, ["Ava"])
    with pytest.raises(SessionError):
        Session(world, ScriptedPlanner(home), SessionSettings(frames=10, pace=cast(Pace, "sometimes")))  # not a Pace on purpose
    with pytest.raises(SessionError):
        Session(world, ScriptedPlanner(home), SessionSettings(frames=10, speed=0.0))


async def _graph_session(
    scene: Scene, motion: MotionMatcher, port: LLMPort, trace: TraceSink, tmp_path: Path, settings: SessionSettings,
    thread: str,
) -> SessionResult:
    from langgraph.checkpoint.memory import InMemorySaver

    from storyteller.agents.event_parser import scene_action_labels
    from storyteller.orchestrator.planning.checkpoints import StoryLog
    from storyteller.orchestrator.planning.graph import compile_planning_graph
    from storyteller.orchestrator.planning.state import PlanningDeps
    from storyteller.orchestrator.session.roster import RosterWorld
    from storyteller.orchestrator.session.step_planner import GraphStepPlanner

    story = StoryLog(tmp_path / "runs.sqlite", thread)
    deps = PlanningDeps(port=port, scene=scene, world=RosterWorld(), story=story,
                        action_labels=scene_action_labels(scene), seed=0)
    planner = GraphStepPlanner(compile_planning_graph(InMemorySaver()), deps, thread)
    world = make_world(scene, motion, ["Ava", "Ben"])
    try:
        return await Session(world, planner, replace(settings, instruction="Everyone reads."), trace=trace).run()
    finally:
        story.close()


def _check_frames_and_parsed(path: Path) -> list[AppliedRecord]:
    """Every narrator / parser attempt carries its step's request frame, is named by exactly
    one applied record and has one parsed record; no seq is skipped. Returns the applied records."""
    from storyteller.orchestrator.llm.traces import AppliedRecord, AttemptRecord, read_trace

    contents = read_trace(path)
    assert [r.seq for r in contents.records] == list(range(len(contents.records)))  # no wasted seq
    attempts = {r.seq: r for r in contents.records if isinstance(r, AttemptRecord)}
    applied = [r for r in contents.records if isinstance(r, AppliedRecord)]
    assert [a.step for a in applied] == list(range(len(applied)))
    named = [s for a in applied for s in a.ref_seqs]
    step_attempts = sorted(s for s, r in attempts.items() if r.node in ("narrator", "event_parser"))
    assert sorted(named) == step_attempts and len(set(named)) == len(named)
    for a in applied:
        assert a.ref_seqs, "every step of this story made LLM calls"
        for seq in a.ref_seqs:
            assert attempts[seq].request.sim_frame == a.requested_frame
    describer = [r for r in attempts.values() if r.node == "describer"]
    assert len(describer) == 1 and describer[0].request.sim_frame == applied[0].requested_frame
    parsed = contents.parsed_by_seq()
    assert sorted(parsed) == sorted(attempts)  # one parsed record per attempt, describer included
    for seq, (p,) in parsed.items():
        assert p.node == attempts[seq].node
        if attempts[seq].node == "event_parser" and p.ok:
            for plan in p.parsed_output["plans"]:
                assert {"character", "action", "area", "position", "facing"} <= set(plan)
                assert plan["action"] == "read_book" and len(plan["position"]) == 2
    return applied


def test_graph_session_traces_request_and_applied_frames_and_replays(home: Scene, motion: MotionMatcher, tmp_path: Path) -> None:
    from storyteller.orchestrator.llm.client import LiteLLMClient
    from storyteller.orchestrator.llm.config import default_config
    from storyteller.orchestrator.llm.replay import ReplayClient
    from storyteller.orchestrator.llm.trace_writer import TraceWriter
    from storyteller.orchestrator.llm.traces import read_trace

    live_path = tmp_path / "live.jsonl"
    client = LiteLLMClient(default_config(), TraceWriter(live_path, fsync="never"),
                           acompletion=ScriptedCompletion(), check_local=lambda m: None)
    settings = SessionSettings(frames=25 * FPS, pace="lockstep", max_steps=3, retry_after_s=1.0)
    live = anyio.run(_graph_session, home, motion, client, client.trace, tmp_path, settings, "live")
    client.close()
    assert live.steps == 3 and all(isinstance(o, ParsedEvent) for _, o in live.outcomes)
    applied = _check_frames_and_parsed(live_path)
    assert [a.sim_frame for a in applied] == live.applied_frames
    assert [a.requested_frame for a in applied] == live.applied_frames  # lockstep
    assert len(applied[0].ref_seqs) == 3  # narrator + rejected parser reply + accepted one
    assert len(set(live.applied_frames)) == 3  # the steps were planned at different frames
    rejected = [p for ps in read_trace(live_path).parsed_by_seq().values() for p in ps if not p.ok]
    assert [(p.node, p.error_type) for p in rejected] == [("event_parser", "NoCodeError")]

    # replay (as `storyteller run --replay T --record T2`): same frames, a consistent new trace
    replay_path = tmp_path / "replay.jsonl"
    port = ReplayClient(live_path, trace_sink=TraceWriter(replay_path, fsync="never"))
    replayed = anyio.run(_graph_session, home, motion, port, port.trace, tmp_path,
                         SessionSettings(frames=25 * FPS, pace="fast", applied_frames=live.applied_frames), "replay")
    port.close()
    assert replayed.applied_frames == live.applied_frames
    assert [o for _, o in replayed.outcomes] == [o for _, o in live.outcomes]
    assert port.remaining() == 0
    again = _check_frames_and_parsed(replay_path)
    assert [(a.step, a.sim_frame, a.requested_frame, len(a.ref_seqs)) for a in again] == [
        (a.step, a.sim_frame, a.requested_frame, len(a.ref_seqs)) for a in applied
    ]


def test_an_event_the_motion_library_cannot_play_is_skipped_and_logged(home: Scene, motion: MotionMatcher) -> None:
    from structlog.testing import capture_logs

    seat = next(o for o in home.objects if o.is_seat)

    class SeatedCoffee(ScriptedPlanner):
        async def plan(self, request: PlanningRequest, progress: StepProgress | None = None) -> Outcome:
            self.requests.append(request)
            if request.index > 0:
                return None
            plan = PlannedCharacter(character="Ava", action="use_coffee_maker", area=f"sit on {seat.name}",
                                    position=(float(seat.center[0]), float(seat.center[1])), facing=(1.0, 0.0),
                                    seat=seat.name)
            return ParsedEvent(index=0, event=Event(characters=("Ava",), activity="coffee"), plans=(plan,))

    world = make_world(home, motion, ["Ava"])
    with capture_logs() as logs:
        result = _run(world, SeatedCoffee(home), SessionSettings(frames=3 * FPS, pace="lockstep", max_steps=2))
    assert result.frames == 3 * FPS and result.planner_error is None
    rejected = [e for e in logs if e["event"] == "event_rejected"]
    assert rejected and rejected[0]["event_id"] and "use_coffee_maker" in rejected[0]["error"]


class WaitingPlanner:
    """Ava reads (a looping action, so she is free again at once); every later step waits."""

    def __init__(self, scene: Scene) -> None:
        self.spot = free_points(scene, 1, seed=7)[0]
        self.requests: list[PlanningRequest] = []

    async def plan(self, request: PlanningRequest, progress: StepProgress | None = None) -> Outcome:
        self.requests.append(request)
        if request.index > 0:
            return None
        plan = PlannedCharacter(character="Ava", action="use_smartphone", area="a free spot", position=self.spot,
                                facing=(1.0, 0.0))
        return ParsedEvent(index=0, event=Event(characters=("Ava",), activity="read"), plans=(plan,))


def test_after_a_wait_the_planner_is_asked_again_only_when_something_changed(home: Scene, motion: MotionMatcher) -> None:
    world = make_world(home, motion, ["Ava", "Ben"])
    planner = WaitingPlanner(home)
    settings = SessionSettings(frames=40 * FPS, pace="lockstep", retry_after_s=1.0, recheck_after_s=15.0)
    result = _run(world, planner, settings)
    frames = [r.frame for r in planner.requests]
    looping = next(e for e in result.events if e.index == 0)
    assert looping.state == "looping"
    # step 1 (Ben free, Ava walking) waits; when Ava's event loops she is free: the free
    # characters changed, so the planner is asked at once (not 1 s after each wait)
    free_at = [tuple(c.name for c in r.roster if not c.busy) for r in planner.requests]
    assert free_at[0] == ("Ava", "Ben") and free_at[1] == ("Ben",)
    assert ("Ava", "Ben") in free_at[2:]
    # with nothing changing any more, the waits come 15 s apart, not every second
    later = [b - a for a, b in itertools.pairwise(frames[2:])]
    assert later and all(gap == 15 * FPS for gap in later)
    assert len(frames) <= 2 + 1 + 40 // 15


class _VirtualTime:
    """A session clock that moves only when the session sleeps (by what it asked for) and, once
    the world reaches ``stall_frame``, jumps by ``stall_s`` (a frame that ran that much late)."""

    def __init__(self, stall_frame: int, stall_s: float) -> None:
        self.t = 0.0
        self.stall_frame = stall_frame
        self.stall_s = stall_s
        self.session: Session | None = None

    def __call__(self) -> float:
        assert self.session is not None
        return self.t + (self.stall_s if self.session.world.frame >= self.stall_frame else 0.0)


@pytest.mark.parametrize("stall_s", [0.5, 0.05])
def test_realtime_pace_slips_after_a_stall_instead_of_bursting_catch_up_frames(
    home: Scene, motion: MotionMatcher, monkeypatch: pytest.MonkeyPatch, stall_s: float
) -> None:
    """A frame that takes 0.5 s (15 frame periods): the next frames come one period apart, the
    schedule slips instead. A frame that takes 50 ms (less than a period late): the next frame
    catches up, no slip."""
    clock = _VirtualTime(stall_frame=10, stall_s=stall_s)
    real_sleep = anyio.sleep

    async def virtual_sleep(delay: float) -> None:
        clock.t += delay
        await real_sleep(0)

    monkeypatch.setattr(anyio, "sleep", virtual_sleep)
    world = make_world(home, motion, ["Ava", "Ben"])

    async def main() -> SessionResult:
        session = Session(world, ScriptedPlanner(home), SessionSettings(frames=40, pace="realtime", max_steps=2),
                          clock=clock)
        clock.session = session
        return await session.run()

    result = _run_async(main)
    period = 1.0 / FPS
    intervals = list(result.frame_intervals_s)
    assert len(intervals) == len(result.frame_profile) == 40
    assert intervals[:9] == pytest.approx([period] * 9)
    assert intervals[9] == pytest.approx(stall_s)  # the frame that steps into frame 10 stalls
    if stall_s > 2 * period:
        assert result.slipped_s == pytest.approx(stall_s - period)
        assert intervals[10:] == pytest.approx([period] * 30)  # no burst of catch-up frames
    else:
        assert result.slipped_s == 0.0
        assert intervals[10] == pytest.approx(2 * period - stall_s)  # the next frame catches up
        assert intervals[11:] == pytest.approx([period] * 29)
    # the profile splits every interval into its parts
    parts = [sum(result.frame_profile.part(p)[k] for p in PARTS) for k in range(40)]
    assert parts == pytest.approx(intervals, abs=1e-5)


def _run_async(main: Callable[[], Awaitable[SessionResult]]) -> SessionResult:
    return anyio.run(main)


def test_the_history_shows_unplaced_events_as_failed_with_their_part() -> None:
    from storyteller.agents.messages import HistoryEntry
    from storyteller.orchestrator.session.session_types import StoryEvent
    from storyteller.orchestrator.session.story_history import story_history

    done = StoryEvent(index=0, event_id="event-0000", characters=("Ava",), activity="make coffee",
                      requested_frame=1, applied_frame=1, state="completed", part="Ava makes coffee.")
    broken = StoryEvent(index=2, event_id="event-0002", characters=("Ava",), activity="sit",
                        requested_frame=5, applied_frame=5, state="failed", part="Then Ava sits.")
    unplaced = PlanningFailure(index=1, node="event_parser", attempts=4, feedback="no free floor",
                               event=Event(characters=("Ben",), activity="dance by tv_1"), part="Ben dances.")
    narrator_gave_up = PlanningFailure(index=3, node="narrator", attempts=4, feedback="bad JSON")
    history = story_history({e.event_id: e for e in (done, broken)}, [(1, unplaced), (3, narrator_gave_up)])
    assert history == (
        HistoryEntry(index=0, characters=("Ava",), activity="make coffee", state="completed", part="Ava makes coffee."),
        HistoryEntry(index=1, characters=("Ben",), activity="dance by tv_1", state="failed", part="Ben dances."),
        HistoryEntry(index=2, characters=("Ava",), activity="sit", state="failed", part="Then Ava sits."),
    )

"""Overlapping planning steps, the ``offline`` pace, and a failing task cancelling the session.

A scripted planner stands in for the graph: it names its characters (``progress.claim``) after
a "narrator" call and answers after a "parser" call, each reported with a fixed latency, and
takes a random wall-clock time (so the order things happen in differs from run to run). The
world is the real one on the bundled home scene.
"""

from __future__ import annotations

import itertools
import random
from collections.abc import Sequence
from pathlib import Path

import anyio
import pytest

from storyteller.agents.llm_port import LLMError
from storyteller.agents.messages import Event, ParsedEvent, PlannedCharacter
from storyteller.orchestrator.planning.state import StepProgress
from storyteller.orchestrator.session.runtime import Session
from storyteller.orchestrator.session.session_types import (
    Outcome,
    PlanningRequest,
    RecordedRequest,
    SessionError,
    SessionResult,
    SessionSettings,
)
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.step import World
from tests.support.session_world import FPS, free_points, make_world

NAMES = ["Ava", "Ben", "Cleo", "Dan"]


class ClaimingPlanner:
    """Every step: a narrator call (``narrate_s``), a claim of the first one or two free
    characters, a parser call (``parse_s``), then a short action at a free spot; every
    sixth step is a wait (no claim). ``jitter``: random wall-clock sleeps in between."""

    def __init__(self, scene: Scene, *, jitter: int | None = None, narrate_s: float = 1.0, parse_s: float = 2.0,
                 explode_at: int | None = None) -> None:
        self.spots = free_points(scene, 12, seed=7)
        self.rng = random.Random(jitter) if jitter is not None else None
        self.narrate_s = narrate_s
        self.parse_s = parse_s
        self.explode_at = explode_at
        self.requests: list[PlanningRequest] = []
        self.running = 0
        self.most_running = 0
        self.cancelled: list[int] = []

    async def _nap(self) -> None:
        if self.rng is not None:
            await anyio.sleep(self.rng.uniform(0.0, 0.01))
        else:
            await anyio.sleep(0)

    async def plan(self, request: PlanningRequest, progress: StepProgress | None = None) -> Outcome:
        self.requests.append(request)
        self.running += 1
        self.most_running = max(self.most_running, self.running)
        try:
            return await self._plan(request, progress)
        except anyio.get_cancelled_exc_class():
            self.cancelled.append(request.index)
            raise
        finally:
            self.running -= 1

    async def _plan(self, request: PlanningRequest, progress: StepProgress | None) -> Outcome:
        assert progress is not None
        await self._nap()
        progress.llm_call("narrator", self.narrate_s)
        free = [c.name for c in request.roster if not c.busy]
        if request.index % 6 == 5:
            return None
        who = free[: 2 if len(free) > 2 and request.index % 2 else 1]
        progress.claim(who, f"step {request.index}")
        if self.explode_at is not None and request.index == self.explode_at:
            raise RuntimeError("the port broke")
        await self._nap()
        await self._nap()
        progress.llm_call("event_parser", self.parse_s)
        plans = []
        for k, name in enumerate(who):
            x, y = self.spots[(request.index * 3 + k) % len(self.spots)]
            plans.append(PlannedCharacter(character=name, action="use_smartphone" if k == 0 else "drink",
                                          area="a free spot", position=(x, y), facing=(1.0, 0.0)))
        return ParsedEvent(index=request.index, event=Event(characters=tuple(who), activity=f"step {request.index}"),
                           plans=tuple(plans))


def _run(world: World, planner: ClaimingPlanner, settings: SessionSettings,
         requested: list[RecordedRequest] | None = None) -> SessionResult:
    async def main() -> SessionResult:
        session = Session(world, planner, settings,
                          on_request=None if requested is None else requested.append)
        return await session.run()

    return anyio.run(main)


def _story(result: SessionResult) -> list[tuple[int, Outcome, int]]:
    return [(i, o, f) for (i, o), f in zip(result.outcomes, result.applied_frames, strict=True)]


def _no_character_in_two_events(requests: Sequence[PlanningRequest], result: SessionResult) -> None:
    """Each event's characters were free in its own request, and two events whose planning
    overlapped (one requested before the other was applied) share no character."""
    asked = {r.index: r for r in requests}
    applied = {i: f for (i, _), f in zip(result.outcomes, result.applied_frames, strict=True)}
    who = {i: set(o.event.characters) for i, o in result.outcomes if isinstance(o, ParsedEvent)}
    for i, names in who.items():
        assert names <= {c.name for c in asked[i].roster if not c.busy}
        for j, other in who.items():
            if i < j and asked[j].frame <= applied[i]:
                assert not names & other, (i, j, names, other)


def test_lockstep_with_two_planners_overlaps_steps_and_stays_deterministic(home: Scene, motion: MotionMatcher) -> None:
    settings = SessionSettings(frames=40 * FPS, pace="lockstep", max_steps=14, planners=2)
    runs = []
    for jitter in (1, 2):
        planner = ClaimingPlanner(home, jitter=jitter)
        result = _run(make_world(home, motion, NAMES), planner, settings)
        _no_character_in_two_events(planner.requests, result)
        runs.append((planner, result))
    (p1, r1), (p2, r2) = runs
    asked = {r.index: r.frame for r in p1.requests}
    landed = {i: f for i, _, f in _story(r1)}
    assert any(asked[i + 1] <= landed[i] for i in landed if i + 1 in asked)  # asked before the one before landed
    assert any(any(h.state == "ongoing" and h.index not in {e.index for e in r1.events if e.applied_frame < r.frame}
                   for h in r.history) for r in p1.requests)  # a claimed event shows as ongoing
    assert _story(r1) == _story(r2)
    assert sorted(p1.requests, key=lambda r: r.index) == sorted(p2.requests, key=lambda r: r.index)
    # lockstep: every outcome lands at the frame its request was made
    frames = {r.index: r.frame for r in p1.requests}
    assert all(frames[i] == f for i, _, f in _story(r1))


def test_one_planner_never_has_two_steps_in_flight(home: Scene, motion: MotionMatcher) -> None:
    planner = ClaimingPlanner(home, jitter=3)
    requested: list[RecordedRequest] = []
    result = _run(make_world(home, motion, NAMES), planner,
                  SessionSettings(frames=20 * FPS, pace="fast", max_steps=8), requested)
    assert planner.most_running == 1 and result.steps >= 4
    assert requested == []  # the trace of a one-at-a-time run is what it always was


def test_a_concurrent_fast_run_replays_from_its_recorded_requests(home: Scene, motion: MotionMatcher) -> None:
    settings = SessionSettings(frames=30 * FPS, pace="fast", max_steps=12, planners=3)
    requested: list[RecordedRequest] = []
    live_planner = ClaimingPlanner(home, jitter=4)
    live = _run(make_world(home, motion, NAMES), live_planner, settings, requested)
    _no_character_in_two_events(live_planner.requests, live)
    assert live_planner.most_running >= 2
    assert [r.step for r in requested] == sorted(r.index for r in live_planner.requests)
    assert any(r.phase == "frame_start" and r.after for r in requested)
    for jitter in (5, 6):
        planner = ClaimingPlanner(home, jitter=jitter)
        by_step = dict(zip([i for i, _ in live.outcomes], live.applied_frames, strict=True))
        frames = [by_step.get(i) for i in range(max(by_step) + 1)]  # overlapping steps land out of order
        replay = SessionSettings(frames=30 * FPS, pace="fast", planners=3, applied_frames=frames,
                                 schedule=requested, live_instructions=False)
        replayed = _run(make_world(home, motion, NAMES), planner, replay)
        assert _story(replayed) == _story(live)
        assert sorted(planner.requests, key=lambda r: r.index) == sorted(live_planner.requests, key=lambda r: r.index)


def test_a_replay_whose_requests_do_not_fit_is_an_error(home: Scene, motion: MotionMatcher) -> None:
    bad = [RecordedRequest(step=0, frame=1, phase="frame_end"), RecordedRequest(step=1, frame=1, phase="frame_start", after=(7,))]
    settings = SessionSettings(frames=5 * FPS, pace="fast", planners=2, applied_frames=[40, 40], schedule=bad)
    with pytest.raises(SessionError, match="replay"):
        _run(make_world(home, motion, NAMES), ClaimingPlanner(home), settings)


def test_offline_pace_lands_each_outcome_after_its_calls_latency(home: Scene, motion: MotionMatcher) -> None:
    for planners in (1, 2):
        runs = []
        for jitter in (7, 8):
            planner = ClaimingPlanner(home, jitter=jitter, narrate_s=1.0, parse_s=2.0)
            settings = SessionSettings(frames=40 * FPS, pace="offline", max_steps=10, planners=planners)
            result = _run(make_world(home, motion, NAMES), planner, settings)
            _no_character_in_two_events(planner.requests, result)
            runs.append((planner, result))
        (p1, r1), (_, r2) = runs
        assert _story(r1) == _story(r2), planners  # whatever the wall clock did
        frames = {r.index: r.frame for r in p1.requests}
        for i, outcome, applied in _story(r1):
            latency = 1.0 if outcome is None else 3.0  # a wait makes only the narrator call
            assert applied == frames[i] + round(latency * FPS)
        if planners == 2:  # in simulated time: a step asked before the one before it landed
            landed = {i: f for i, _, f in _story(r1)}
            assert any(frames[i + 1] < landed[i] for i in landed if i + 1 in frames)
            # the next step is asked when a claim is known: one narrator call after the request
            starts = sorted(frames.values())
            assert any(b - a == 1.0 * FPS for a, b in itertools.pairwise(starts))


def test_offline_latency_setting_replaces_each_calls_own(home: Scene, motion: MotionMatcher) -> None:
    planner = ClaimingPlanner(home, jitter=9)
    settings = SessionSettings(frames=20 * FPS, pace="offline", max_steps=5, offline_latency_s=0.5)
    result = _run(make_world(home, motion, NAMES), planner, settings)
    frames = {r.index: r.frame for r in planner.requests}
    for i, outcome, applied in _story(result):
        calls = 1 if outcome is None else 2
        assert applied == frames[i] + round(calls * 0.5 * FPS)


def test_an_unexpected_error_in_a_step_cancels_the_session(home: Scene, motion: MotionMatcher) -> None:
    planner = ClaimingPlanner(home, jitter=10, explode_at=3)

    async def main() -> None:
        settings = SessionSettings(frames=60 * FPS, pace="fast", max_steps=20, planners=3)
        with pytest.raises(RuntimeError, match="the port broke"):
            await Session(make_world(home, motion, NAMES), planner, settings).run()
        import asyncio

        assert asyncio.all_tasks() == {asyncio.current_task()}  # nothing left pending

    anyio.run(main)
    assert planner.running == 0  # every other step in flight was cancelled, none orphaned


def test_an_llm_error_stops_planning_but_the_story_goes_on(home: Scene, motion: MotionMatcher) -> None:
    class Unavailable(ClaimingPlanner):
        async def _plan(self, request: PlanningRequest, progress: StepProgress | None) -> Outcome:
            if request.index == 2:
                raise LLMError("no model answers")
            return await super()._plan(request, progress)

    planner = Unavailable(home, jitter=11)
    result = _run(make_world(home, motion, NAMES), planner, SessionSettings(frames=15 * FPS, pace="fast", planners=2))
    assert result.frames == 15 * FPS and isinstance(result.planner_error, LLMError)
    assert 2 not in [i for i, _ in result.outcomes]


def test_settings_for_planners_and_offline_latency_are_checked(home: Scene, motion: MotionMatcher) -> None:
    world = make_world(home, motion, ["Ava"])
    with pytest.raises(SessionError, match="planners"):
        Session(world, ClaimingPlanner(home), SessionSettings(frames=10, planners=0))
    with pytest.raises(SessionError, match="offline latency"):
        Session(world, ClaimingPlanner(home), SessionSettings(frames=10, pace="offline", offline_latency_s=-1.0))


def test_the_planning_graph_runs_two_steps_at_once_on_two_lanes(home: Scene, motion: MotionMatcher, tmp_path: Path) -> None:
    from langgraph.checkpoint.memory import InMemorySaver

    from storyteller.agents.event_parser import scene_action_labels
    from storyteller.orchestrator.llm.client import LiteLLMClient
    from storyteller.orchestrator.llm.config import default_config
    from storyteller.orchestrator.llm.trace_writer import TraceWriter
    from storyteller.orchestrator.llm.traces import AttemptRecord, read_trace
    from storyteller.orchestrator.planning.checkpoints import StoryLog
    from storyteller.orchestrator.planning.graph import compile_planning_graph
    from storyteller.orchestrator.planning.state import PlanningDeps
    from storyteller.orchestrator.session.roster import RosterWorld
    from storyteller.orchestrator.session.step_planner import GraphStepPlanner
    from tests.support.session_world import ScriptedCompletion

    path = tmp_path / "trace.jsonl"
    client = LiteLLMClient(default_config(), TraceWriter(path, fsync="never"), acompletion=ScriptedCompletion(),
                           check_local=lambda m: None)
    story = StoryLog(tmp_path / "runs.sqlite", "lanes")
    deps = PlanningDeps(port=client, scene=home, world=RosterWorld(), story=story,
                        action_labels=scene_action_labels(home), seed=0)
    planner = GraphStepPlanner(compile_planning_graph(InMemorySaver()), deps, "lanes", lanes=2)
    settings = SessionSettings(frames=20 * FPS, pace="lockstep", max_steps=4, planners=2, instruction="Everyone reads.")

    async def main() -> SessionResult:
        try:
            return await Session(make_world(home, motion, ["Ava", "Ben", "Cleo"]), planner, settings,
                                 trace=client.trace).run()
        finally:
            story.close()
            client.close()

    result = anyio.run(main)
    assert result.steps == 4 and all(isinstance(o, ParsedEvent) for _, o in result.outcomes)
    attempts = [r for r in read_trace(path).records if isinstance(r, AttemptRecord)]
    assert [r.node for r in attempts].count("describer") == 1  # lane 1 starts from lane 0's description
    narrated = [r.request.sim_frame for r in attempts if r.node == "narrator"]
    assert len(narrated) > len(set(narrated))  # two steps asked at one frame: the second beside the first
    who = [set(o.event.characters) for _, o in result.outcomes if isinstance(o, ParsedEvent)]
    frames = result.applied_frames
    for i in range(len(who)):
        for j in range(i + 1, len(who)):
            if frames[i] == frames[j]:
                assert not who[i] & who[j]

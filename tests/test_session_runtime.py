"""The story session: simulation and planner concurrently, replayable frame by frame.

A scripted planner stands in for the LLM graph (the graph has its own tests); the world,
paths and motion matching are the real ones on the bundled home scene.
"""

from __future__ import annotations

import random

import anyio
import numpy as np
import pytest

from agents.messages import Event, ParsedEvent, PlannedCharacter, PlanningFailure
from orchestrator.session_runtime import (
    Outcome,
    PlanningRequest,
    Session,
    SessionError,
    SessionSettings,
)
from sim.bundled_scenes import resolve_scene
from sim.motion_database import load_databases
from sim.motion_matching import MotionMatcher
from sim.nav_grid import build_nav_grid
from sim.world import World

FPS = 30


@pytest.fixture(scope="module")
def motion() -> MotionMatcher:
    return MotionMatcher(load_databases())


@pytest.fixture(scope="module")
def home():  # type: ignore[no-untyped-def]
    return resolve_scene("home")


def _free_points(scene, n: int, seed: int) -> list[tuple[float, float]]:  # type: ignore[no-untyped-def]
    grid = build_nav_grid(scene)
    cells = np.argwhere(grid.free)
    rng = np.random.default_rng(seed)
    out: list[tuple[float, float]] = []
    for k in rng.permutation(len(cells)):
        p = grid.center_of(*cells[k])
        if all(np.hypot(*(p - q)) > 1.2 for q in out):
            out.append((float(p[0]), float(p[1])))
        if len(out) == n:
            return out
    raise AssertionError("not enough free points")


def _world(scene, motion: MotionMatcher, names: list[str]) -> World:  # type: ignore[no-untyped-def]
    starts = _free_points(scene, len(names), seed=1)
    return World(scene, {n: (p, 0.0) for n, p in zip(names, starts, strict=True)}, motion)


class ScriptedPlanner:
    """Gives every free character a short standing action at a free spot, deterministically
    from the request; optionally takes a random (wall-clock) time to answer."""

    def __init__(self, scene, delays: bool = False, fail_at: int | None = None) -> None:  # type: ignore[no-untyped-def]
        self.spots = _free_points(scene, 12, seed=7)
        self.delays = random.Random(5) if delays else None
        self.fail_at = fail_at
        self.requests: list[PlanningRequest] = []

    async def plan(self, request: PlanningRequest) -> Outcome:
        self.requests.append(request)
        if self.delays is not None:
            await anyio.sleep(self.delays.uniform(0.0, 0.02))
        if self.fail_at is not None and request.index == self.fail_at:
            raise ConnectionError("provider unreachable")
        free = [c.name for c in request.roster if not c.busy]
        if request.index % 4 == 3:
            return None  # the narrator waits
        if request.index % 5 == 4:
            return PlanningFailure(index=request.index, node="event_parser", attempts=4, feedback="gave up")
        who = free[: 2 if len(free) > 1 and request.index % 2 else 1]
        plans = []
        for k, name in enumerate(who):
            x, y = self.spots[(request.index * 3 + k) % len(self.spots)]
            plans.append(PlannedCharacter(character=name, action="use_smartphone" if k == 0 else "drink",
                                          area="near a free spot", position=(x, y), facing=(1.0, 0.0)))
        return ParsedEvent(index=request.index, event=Event(characters=tuple(who), activity="take a break"),
                           plans=tuple(plans))


def _run(world: World, planner: ScriptedPlanner, settings: SessionSettings):  # type: ignore[no-untyped-def]
    async def main():  # type: ignore[no-untyped-def]
        return await Session(world, planner, settings).run()

    return anyio.run(main)


def test_lockstep_session_plans_and_completes_events(home, motion) -> None:  # type: ignore[no-untyped-def]
    world = _world(home, motion, ["Ava", "Ben"])
    planner = ScriptedPlanner(home)
    result = _run(world, planner, SessionSettings(frames=40 * FPS, pace="lockstep", max_steps=6))
    assert result.frames == 40 * FPS
    assert result.steps == 6
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


def test_live_run_replays_to_identical_events_and_motion(home, motion) -> None:  # type: ignore[no-untyped-def]
    live_world = _world(home, motion, ["Ava", "Ben", "Cleo"])
    live = _run(live_world, ScriptedPlanner(home, delays=True), SessionSettings(frames=30 * FPS, pace="fast", max_steps=8))
    assert live.steps >= 3
    replay_world = _world(home, motion, ["Ava", "Ben", "Cleo"])
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


def test_replay_with_frames_that_cannot_fit_is_an_error(home, motion) -> None:  # type: ignore[no-untyped-def]
    world = _world(home, motion, ["Ava"])
    with pytest.raises(SessionError, match="replay"):
        _run(world, ScriptedPlanner(home), SessionSettings(frames=5 * FPS, applied_frames=[10, 0]))


def test_planner_crash_stops_planning_but_not_the_simulation(home, motion) -> None:  # type: ignore[no-untyped-def]
    world = _world(home, motion, ["Ava", "Ben"])
    result = _run(world, ScriptedPlanner(home, fail_at=1), SessionSettings(frames=10 * FPS, pace="lockstep"))
    assert result.frames == 10 * FPS
    assert isinstance(result.planner_error, ConnectionError)
    assert result.steps == 1


def test_settings_are_checked(home, motion) -> None:  # type: ignore[no-untyped-def]
    world = _world(home, motion, ["Ava"])
    with pytest.raises(SessionError):
        Session(world, ScriptedPlanner(home), SessionSettings(frames=10, pace="sometimes"))  # type: ignore[arg-type]
    with pytest.raises(SessionError):
        Session(world, ScriptedPlanner(home), SessionSettings(frames=10, speed=0.0))

"""The world step (storyteller.sim.world.step): phases, group events, failures, determinism, snapshots.

These tests use a stand-in motion layer (rest pose on the world's root) so that they check the
world's own logic quickly; the full motion matcher runs in tests/sim/motion/test_crowd_motion.py and in
one smoke test here.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pytest

from storyteller.orchestrator.cache_paths import motion_cache_dir
from storyteller.sim.body.skeleton import NUM_JOINTS, REST_OFFSETS, heading_to_root
from storyteller.sim.motion.matching import MotionQuery, Pose
from storyteller.sim.paths.cooperative_astar import PathPlanner
from storyteller.sim.paths.nav_grid import NavGrid, build_nav_grid
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.events import AssignEvent, Assignment, ReleaseCharacters, StepOutput
from storyteller.sim.world.step import World, WorldConfig, WorldError, run, step
from tests.support.reference import OFFICE, reference_or_skip


class StandInMotion:
    """Test placeholder: rest pose, pelvis lowered when seated; records every query."""

    def __init__(self) -> None:
        self.queries: list[MotionQuery] = []

    def initial_state(
        self, label: str, root_xy: Sequence[float] | np.ndarray, heading: float, seated: bool = False
    ) -> int:
        return 0

    def step(self, state: int, query: MotionQuery, dt: float) -> tuple[int, Pose]:
        self.queries.append(query)
        rot = np.tile(np.eye(3), (NUM_JOINTS, 1, 1))
        rot[0] = heading_to_root(float(query.heading or 0.0))
        sitting = query.seated or query.label in ("sit_down", "stand_up")
        z = 0.55 if sitting else float(REST_OFFSETS[0, 1])
        root = np.asarray(query.root_xy, dtype=float)
        return state + 1, Pose(np.array([*root, z]), rot, root, float(query.heading or 0.0), np.zeros(2, dtype=bool))


Office = tuple[Scene, NavGrid, PathPlanner]


@pytest.fixture(scope="module")
def office() -> Office:
    reference_or_skip()
    scene = load_scene(OFFICE)
    grid = build_nav_grid(scene)
    return scene, grid, PathPlanner(grid)


def _world(
    office: Office, chars: dict[str, tuple[tuple[float, float], float]], config: WorldConfig | None = None
) -> World:
    scene, grid, planner = office
    return World(scene, chars, StandInMotion(), grid=grid, planner=planner, config=config)


def _cell_xy(office: Office, i: int, j: int) -> tuple[float, float]:
    _, grid, _ = office
    assert grid.is_free(i, j)
    c = grid.center_of(i, j)
    return (float(c[0]), float(c[1]))


def _free_cells(office: Office) -> np.ndarray:
    _, grid, _ = office
    return np.argwhere(grid.component == grid.main_component)


def _go(name: str, xy: tuple[float, float], action: str = "idle", facing: tuple[float, float] = (1.0, 0.0),
        **kw: object) -> Assignment:
    return Assignment(character=name, action=action, target_xy=xy, facing_xy=facing, **kw)


def _labels(world: World, name: str) -> tuple[str, ...]:
    """The action label of every frame of ``name``'s track (the world always records them)."""
    labels = world.tracks()[name].action_labels
    assert labels is not None
    return labels


def _until(
    world: World, pred: Callable[[StepOutput], object], limit: int = 2000, commands: Sequence[AssignEvent | ReleaseCharacters] = ()
) -> list[StepOutput]:
    outs = []
    first = list(commands)
    for _ in range(limit):
        _, out = step(world, first, world.dt)
        first = []
        outs.append(out)
        if pred(out):
            return outs
    raise AssertionError("condition not reached")


def test_a_walker_reaches_its_target_turns_and_loops(office: Office) -> None:
    cells = _free_cells(office)
    start, goal = _cell_xy(office, *cells[0]), _cell_xy(office, *cells[40])
    w = _world(office, {"ann": (start, 0.0)})
    assert w.available() == ("ann",)
    outs = _until(w, lambda o: o.looping_events, commands=[AssignEvent(event_id="e1", assignments=(_go("ann", goal, facing=(0.0, -1.0)),))])
    ann = w.characters["ann"]
    assert ann.phase == "interacting"
    assert np.allclose(ann.xy, goal) and math.isclose(ann.heading, -math.pi / 2)
    assert outs[-1].available == ("ann",)  # looping: free for the narrator
    labels = _labels(w, "ann")
    assert labels[0] == "idle" and "walk" in labels
    # The recorded pelvis is the world's root, frame by frame.
    assert np.allclose(w.tracks()["ann"].root_positions[-1, :2], goal)


def test_root_stays_on_the_navigator_path_while_walking(office: Office) -> None:
    cells = _free_cells(office)
    w = _world(office, {"ann": (_cell_xy(office, *cells[0]), 0.0)})
    run(w, 120, {0: [AssignEvent(event_id="e", assignments=(_go("ann", _cell_xy(office, *cells[60])),))]})
    xy = w.tracks()["ann"].root_positions[:, :2]
    step_len = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    # at most one diagonal cell (0.42 m) per 9-frame step, i.e. <= sqrt(2) m/s
    assert step_len.max() <= math.sqrt(2) / 30 + 1e-9
    assert step_len.sum() > 1.0


def test_group_members_wait_for_each_other_then_start_together(office: Office) -> None:
    _scene, _grid, _ = office
    cells = _free_cells(office)
    near, far = cells[100], cells[0]
    meet_a, meet_b = cells[104], cells[110]
    w = _world(office, {"ann": (_cell_xy(office, *near), 0.0), "bob": (_cell_xy(office, *far), 0.0)})
    ev = AssignEvent(event_id="talk", assignments=(
        _go("ann", _cell_xy(office, *meet_a), "chat", partners=("bob",)),
        _go("bob", _cell_xy(office, *meet_b), "chat", partners=("ann",)),
    ))
    outs = _until(w, lambda o: o.started_events == ("talk",), commands=[ev])
    ann_track = w.tracks()["ann"].root_positions[:, :2]
    arrived = int(np.flatnonzero(np.all(np.isclose(ann_track, _cell_xy(office, *meet_a)), axis=1))[0])
    assert len(outs) - arrived > 30  # ann waited at least a second for bob
    labels = _labels(w, "ann")
    assert set(labels[arrived:]) <= {"idle", "walk"}  # waiting (stepping aside for bob if needed)
    assert np.allclose(ann_track[-1], _cell_xy(office, *meet_a))  # on her cell when the event starts
    assert np.allclose(w.characters["bob"].xy, _cell_xy(office, *meet_b))
    assert w.characters["ann"].phase == w.characters["bob"].phase == "transition_in"
    assert outs[-2].available == ()  # both busy while the event is ongoing
    outs = _until(w, lambda o: bool(o.looping_events))
    assert outs[-1].looping_events == ("talk",)
    assert set(outs[-1].available) == {"ann", "bob"}
    # The partner action's motion target is the partner.
    assert isinstance(w.motion, StandInMotion)
    q = w.motion.queries[-1]
    assert q.label == "chat" and q.target_xy is not None and np.allclose(q.target_xy, w.characters["ann"].xy)


def test_completing_action_completes_the_event(office: Office) -> None:
    cells = _free_cells(office)
    w = _world(office, {"ann": (_cell_xy(office, *cells[5]), 0.0)})
    outs = _until(w, lambda o: bool(o.completed_events),
                  commands=[AssignEvent(event_id="sip", assignments=(_go("ann", _cell_xy(office, *cells[5]), "drink"),))])
    assert outs[-1].completed_events == ("sip",)
    labels = _labels(w, "ann")
    assert labels.count("drink") == 120  # ActionSpec duration 4 s at 30 fps
    assert outs[-1].available == ("ann",) and w.characters["ann"].phase == "idle"


def test_sitting_walks_to_the_approach_cell_sits_acts_and_stands_up_for_the_next_event(office: Office) -> None:
    scene, grid, _ = office
    chair = scene.get("chair_1")
    approach = grid.approach_cell(chair)
    cells = _free_cells(office)
    start = min(cells, key=lambda c: abs(int(c[0]) - approach[0]) + abs(int(c[1]) - approach[1]) if max(abs(int(c[0]) - approach[0]), abs(int(c[1]) - approach[1])) >= 4 else 1e9)
    w = _world(office, {"ann": (_cell_xy(office, *start), 0.0)})
    sit = AssignEvent(event_id="sit", assignments=(Assignment(
        character="ann", action="drink", target_xy=tuple(chair.seat_point()), facing_xy=chair.facing, seat="chair_1"),))
    _until(w, lambda o: bool(o.completed_events), commands=[sit])
    ann = w.characters["ann"]
    assert ann.seated and ann.phase == "idle" and np.allclose(ann.xy, chair.seat_point())
    labels = _labels(w, "ann")
    assert labels.count("sit_down") == 60 and labels.count("drink@seated") == 120
    # the pelvis sat down: lower than when standing
    z = w.tracks()["ann"].root_positions[:, 2]
    assert z[-1] < z[0] - 0.2
    run(w, 5)
    assert _labels(w, "ann")[-1] == "sit_idle"
    go = AssignEvent(event_id="go", assignments=(_go("ann", _cell_xy(office, *start)),))
    _until(w, lambda o: bool(o.looping_events), commands=[go])
    labels = _labels(w, "ann")
    assert labels.count("stand_up") == 54
    first_stand = labels.index("stand_up")
    assert "walk" in labels[first_stand:]
    assert np.allclose(w.characters["ann"].xy, _cell_xy(office, *start))


def test_looping_event_completes_when_its_members_are_interrupted_or_released(office: Office) -> None:
    cells = _free_cells(office)
    a, b = cells[200], cells[204]
    w = _world(office, {"ann": (_cell_xy(office, *a), 0.0), "bob": (_cell_xy(office, *b), math.pi)})
    chat = AssignEvent(event_id="chat", assignments=(
        _go("ann", _cell_xy(office, *a), "chat", partners=("bob",)),
        _go("bob", _cell_xy(office, *b), "chat", partners=("ann",))))
    _until(w, lambda o: bool(o.looping_events), commands=[chat])
    # a new event interrupts ann's looping chat via her transition out
    wave = AssignEvent(event_id="wave", assignments=(_go("ann", _cell_xy(office, *cells[150]), "wave"),))
    _, out = step(w, [wave], w.dt)
    assert out.failures == () and w.characters["ann"].phase == "transition_out"
    assert out.completed_events == ()  # bob still chats: the event stays looping
    _, out = step(w, [ReleaseCharacters(characters=("bob",))], w.dt)
    assert out.completed_events == ("chat",)
    outs = _until(w, lambda o: "wave" in o.completed_events)
    assert all(f == () for f in (o.failures for o in outs))


def test_bad_assignments_fail_with_typed_reasons_and_nobody_moves(office: Office) -> None:
    scene, _grid, _ = office
    cells = _free_cells(office)
    w = _world(office, {"ann": (_cell_xy(office, *cells[0]), 0.0), "bob": (_cell_xy(office, *cells[50]), 0.0)})
    far_outside = (scene.bounds_max[0] + 5.0, scene.bounds_max[1] + 5.0)
    cmds = [
        AssignEvent(event_id="e1", assignments=(_go("ann", far_outside),)),
        AssignEvent(event_id="e2", assignments=(_go("zed", _cell_xy(office, *cells[3])),)),
        AssignEvent(event_id="e3", assignments=(_go("bob", _cell_xy(office, *cells[3]), "drink", seat="chair_999"),)),
    ]
    _, out = step(w, cmds, w.dt)
    reasons = {(f.event_id, f.character): f.reason for f in out.failures}
    assert reasons == {("e1", "ann"): "no_path", ("e2", "zed"): "unknown_character", ("e3", "bob"): "unknown_seat"}
    assert "nearest reachable floor" in out.failures[0].message
    assert w.characters["ann"].phase == "idle" and set(out.available) == {"ann", "bob"}
    # busy: bob is walking for an ongoing event
    _, out = step(w, [AssignEvent(event_id="e4", assignments=(_go("bob", _cell_xy(office, *cells[300]), "drink"),))], w.dt)
    assert out.failures == ()
    _, out = step(w, [AssignEvent(event_id="e5", assignments=(_go("bob", _cell_xy(office, *cells[3])),))], w.dt)
    assert [f.reason for f in out.failures] == ["busy"]
    with pytest.raises(WorldError, match="already running"):
        step(w, [AssignEvent(event_id="e4", assignments=(_go("ann", _cell_xy(office, *cells[3])),))], w.dt)
    with pytest.raises(WorldError, match="dt must be"):
        step(w, [], 0.04)


def test_a_blocked_walker_fails_as_stuck_instead_of_hanging() -> None:
    # A corridor one cell wide: bob stands in the middle, ann cannot get past him.
    scene = Scene(name="corridor", bounds_min=(0.0, 0.0), bounds_max=(3.0, 0.9), objects=())
    w = World(scene, {"ann": ((0.45, 0.45), 0.0), "bob": ((1.65, 0.45), 0.0)}, StandInMotion(),
              config=WorldConfig(stuck_after_s=3.0))
    hold = AssignEvent(event_id="hold", assignments=(_go("bob", (1.65, 0.45)),))
    _until(w, lambda o: bool(o.looping_events), commands=[hold])
    cross = AssignEvent(event_id="cross", assignments=(_go("ann", (2.55, 0.45)),))
    outs = _until(w, lambda o: bool(o.failures), limit=400, commands=[cross])
    (f,) = outs[-1].failures
    assert (f.event_id, f.character, f.reason) == ("cross", "ann", "stuck")
    assert w.characters["ann"].phase == "idle" and "ann" in outs[-1].available


def test_same_seed_same_frames_and_snapshots_replay_exactly(office: Office) -> None:
    cells = _free_cells(office)
    chars = {f"c{k}": (_cell_xy(office, *cells[k * 37]), 0.1 * k) for k in range(6)}
    _, grid, _ = office

    def target(k: int) -> tuple[float, float]:  # exact off-grid points where a body fits
        p = np.asarray(_cell_xy(office, *cells[(k * 37 + 180) % len(cells)])) + np.array([0.08, -0.05])
        return (float(p[0]), float(p[1])) if grid.is_free_xy(p) else _cell_xy(office, *cells[(k * 37 + 180) % len(cells)])

    cmds = {0: [AssignEvent(event_id=f"e{k}", assignments=(_go(f"c{k}", target(k)),)) for k in range(6)]}

    def make() -> World:
        return _world(office, chars, WorldConfig(seed=3, initial_capacity=8))

    w1, w2 = make(), make()
    run(w1, 150, cmds)
    run(w2, 150, cmds)
    t1, t2 = w1.tracks(), w2.tracks()
    for n in chars:
        assert np.array_equal(t1[n].root_positions, t2[n].root_positions)
        assert t1[n].action_labels == t2[n].action_labels
    snap = w1.snapshot()
    later = {80: [ReleaseCharacters(characters=("c0",))]}
    run(w1, 100, {w1.frame + k: v for k, v in later.items()})
    again = w1.restore(snap)
    assert again.frame == 150
    run(again, 100, {again.frame + k: v for k, v in later.items()})
    a, b = w1.tracks(), again.tracks()
    for n in chars:
        assert a[n].num_frames == b[n].num_frames == 250
        assert np.array_equal(a[n].root_positions, b[n].root_positions)
        assert np.array_equal(a[n].local_rotations, b[n].local_rotations)


def test_setup_errors_are_typed(office: Office) -> None:
    cells = _free_cells(office)
    xy = _cell_xy(office, *cells[0])
    with pytest.raises(WorldError, match="same cell"):
        _world(office, {"ann": (xy, 0.0), "bob": (xy, 0.0)})
    with pytest.raises(WorldError, match="finite"):
        _world(office, {"ann": ((math.nan, 1.0), 0.0)})
    with pytest.raises(WorldError, match="at least one"):
        _world(office, {})


def test_real_motion_matcher_drives_the_bodies_and_tracks_export(office: Office, tmp_path: Path) -> None:
    from storyteller.sim.export.bundle import export_run
    from storyteller.sim.motion.database import load_databases
    from storyteller.sim.motion.matching import MotionMatcher

    scene, grid, planner = office
    cells = _free_cells(office)
    w = World(scene, {"ann": (_cell_xy(office, *cells[0]), 0.0)}, MotionMatcher(load_databases(["idle", "walk"], cache_dir=motion_cache_dir())),
              grid=grid, planner=planner)
    run(w, 90, {0: [AssignEvent(event_id="e", assignments=(_go("ann", _cell_xy(office, *cells[80])),))]})
    t = w.tracks()["ann"]
    assert t.num_frames == 90 and "walk" in _labels(w, "ann")
    assert np.any(np.abs(t.local_rotations[:, 4:] - np.eye(3)) > 1e-3)  # the legs move
    assert np.all(np.isfinite(t.root_positions))
    assert w.foot_contacts()["ann"].shape == (90, 2)
    assert w.foot_contacts()["ann"].any()
    files = export_run(tmp_path, scene, list(w.tracks().values()))
    assert files.glb.exists() and files.bvh["ann"].exists() and files.smplx["ann"].exists()


def _off_grid_point(office: Office, k: int, d: tuple[float, float] = (0.11, -0.07)) -> tuple[float, float]:
    _, grid, _ = office
    p = np.asarray(_cell_xy(office, *_free_cells(office)[k])) + np.asarray(d)
    assert grid.is_free_xy(p)
    return (float(p[0]), float(p[1]))


def test_a_standing_action_ends_on_the_exact_off_grid_target(office: Office) -> None:
    cells = _free_cells(office)
    target = _off_grid_point(office, 40)
    w = _world(office, {"ann": (_cell_xy(office, *cells[0]), 0.0)})
    outs = _until(w, lambda o: bool(o.started_events),
                  commands=[AssignEvent(event_id="e", assignments=(_go("ann", target, "wave"),))])
    ann = w.characters["ann"]
    assert ann.target is not None and ann.target.off_grid and ann.target.fallback is None
    pelvis = w.tracks()["ann"].root_positions[:, :2]
    # the event starts (arrival reported) only once the walker stands on the point
    assert np.linalg.norm(pelvis[-1] - target) < 0.02
    assert np.linalg.norm(pelvis[-2] - target) < 0.02
    _until(w, lambda o: bool(o.completed_events))
    assert np.linalg.norm(w.tracks()["ann"].root_positions[-1, :2] - target) < 0.02
    # the next walk leaves the exact point without a jump
    run(w, 60, {w.frame: [AssignEvent(event_id="f", assignments=(_go("ann", _cell_xy(office, *cells[0])),))]})
    step_len = np.linalg.norm(np.diff(w.tracks()["ann"].root_positions[:, :2], axis=0), axis=1)
    assert step_len.max() <= math.sqrt(2) / 30 + 1e-9
    assert len(outs) > 1


def test_a_blocked_target_falls_back_to_the_nearest_cell_with_a_typed_reason(office: Office) -> None:
    _scene, grid, _ = office
    shelf = next(o for o in grid.obstacles if o.name.startswith("bookshelf"))
    inside = shelf.center_xy + np.asarray(shelf.facing) * (shelf.depth / 2.0 - 0.02)
    assert not grid.is_free_xy(inside)
    cells = _free_cells(office)
    w = _world(office, {"ann": (_cell_xy(office, *cells[300]), 0.0)})
    _until(w, lambda o: bool(o.started_events), commands=[AssignEvent(event_id="e", assignments=(
        _go("ann", (float(inside[0]), float(inside[1])), "wave"),))])
    ann = w.characters["ann"]
    assert ann.target is not None and ann.target.fallback == "target_blocked" and not ann.target.off_grid
    assert "cannot stand" in ann.target.message
    assert np.allclose(ann.xy, grid.center_of(*ann.target.cell))


def test_sitting_uses_the_seats_exact_approach_point(office: Office) -> None:
    scene, grid, _ = office
    chair = scene.get("chair_1")
    ap = grid.approach_point(chair, component=grid.main_component)
    cells = _free_cells(office)
    w = _world(office, {"ann": (_cell_xy(office, *cells[0]), 0.0)})
    sit = AssignEvent(event_id="sit", assignments=(Assignment(
        character="ann", action="drink", target_xy=tuple(chair.seat_point()), facing_xy=chair.facing, seat="chair_1"),))
    _until(w, lambda o: bool(o.started_events), commands=[sit])
    assert np.linalg.norm(w.characters["ann"].xy - np.asarray(ap.xy)) < 0.02
    _until(w, lambda o: bool(o.completed_events))
    _until(w, lambda o: bool(o.looping_events), commands=[AssignEvent(event_id="up", assignments=(
        _go("ann", _cell_xy(office, *cells[0])),))])
    xy = w.tracks()["ann"].root_positions[:, :2]
    labels = _labels(w, "ann")
    last_stand = len(labels) - 1 - labels[::-1].index("stand_up")
    assert np.linalg.norm(xy[last_stand] - np.asarray(ap.xy)) < 0.05  # stood up onto the approach point
    assert np.all(np.linalg.norm(np.diff(xy, axis=0), axis=1) <= math.sqrt(2) / 30 + 0.05)


def test_an_exact_target_crowded_by_a_standing_body_settles_for_the_cell_centre(office: Office) -> None:
    _, grid, _ = office
    cells = _free_cells(office)
    free = {(int(i), int(j)) for i, j in cells}
    i, j = next((int(i), int(j)) for i, j in cells[150:] if all((i + k, j + m) in free for k in range(6) for m in (-1, 0, 1)))
    bob_xy, goal = _cell_xy(office, i, j), grid.center_of(i + 2, j)
    target = goal + 0.14 * (np.asarray(bob_xy) - goal) / np.linalg.norm(np.asarray(bob_xy) - goal)
    assert grid.entry_cell(target) == (i + 2, j) and np.linalg.norm(target - bob_xy) < 0.5  # too close to bob
    w = _world(office, {"bob": (bob_xy, 0.0), "ann": (_cell_xy(office, i + 5, j), 0.0)}, WorldConfig(exact_patience_s=1.0))
    _until(w, lambda o: bool(o.looping_events), commands=[AssignEvent(event_id="hold", assignments=(_go("bob", bob_xy),))])
    outs = _until(w, lambda o: bool(o.looping_events), commands=[AssignEvent(event_id="go", assignments=(
        _go("ann", (float(target[0]), float(target[1]))),))])
    ann = w.characters["ann"]
    assert all(o.failures == () for o in outs)
    assert ann.target is not None and ann.target.fallback == "target_occupied" and "too close" in ann.target.message
    assert np.allclose(ann.xy, goal)
    assert np.linalg.norm(w.positions()[0] - w.positions()[1]) >= 0.5 - 1e-9


def test_a_goal_cell_crowded_by_a_still_body_lets_the_walker_stop_beside_it(office: Office) -> None:
    """The exact target is clear but its goal cell's centre is within two body radii of a body
    standing still on an exact point: the walker stops on the neighbouring cell it reached
    instead of waiting there until the event fails as stuck."""
    _, grid, _ = office
    cells = _free_cells(office)
    free = {(int(i), int(j)) for i, j in cells}
    i, j = next((int(i), int(j)) for i, j in cells[150:] if all((i + k, j + m) in free for k in range(7) for m in (-1, 0, 1)))
    bob_xy = grid.center_of(i, j) + np.array([0.14, 0.0])
    goal = grid.center_of(i + 2, j)
    target = goal + np.array([0.06, -0.1])
    assert grid.entry_cell(target) == (i + 2, j)
    assert np.linalg.norm(goal - bob_xy) < 0.5 <= np.linalg.norm(target - bob_xy)  # cell crowded, point clear
    w = _world(office, {"bob": (_cell_xy(office, i, j), 0.0), "ann": (_cell_xy(office, i + 6, j), 0.0)},
               WorldConfig(exact_patience_s=1.0, stuck_after_s=8.0))
    _until(w, lambda o: bool(o.looping_events), commands=[AssignEvent(event_id="hold", assignments=(
        _go("bob", (float(bob_xy[0]), float(bob_xy[1]))),))])
    outs = _until(w, lambda o: bool(o.looping_events or any(o.failures)), commands=[AssignEvent(
        event_id="go", assignments=(_go("ann", (float(target[0]), float(target[1]))),))])
    ann = w.characters["ann"]
    assert [f for o in outs for f in o.failures] == []
    assert ann.target is not None and ann.target.fallback == "goal_cell_taken"
    stop = ann.target.cell
    assert max(abs(stop[0] - (i + 2)), abs(stop[1] - j)) == 1 and np.allclose(ann.xy, grid.center_of(*stop))
    assert np.linalg.norm(w.positions()[0] - w.positions()[1]) >= 0.5 - 1e-9


def test_a_walker_kept_a_little_short_of_its_target_acts_where_it_stands(office: Office) -> None:
    """Someone stands still right on the target: the walker gets within a metre, no closer, and
    after ``near_patience_s`` acts there (``stopped_near``) instead of failing as stuck."""
    cells = _free_cells(office)
    free = {(int(i), int(j)) for i, j in cells}
    i, j = next((int(i), int(j)) for i, j in cells[150:]
                if all((i + k, j + m) in free for k in range(-3, 7) for m in (-1, 0, 1)))
    target = _cell_xy(office, i, j)
    w = _world(office, {"bob": (_cell_xy(office, i - 3, j), 0.0), "ann": (_cell_xy(office, i + 6, j), 0.0)},
               WorldConfig(exact_patience_s=1.0, near_patience_s=3.0, stuck_after_s=12.0))
    _until(w, lambda o: bool(o.looping_events), commands=[AssignEvent(event_id="hold", assignments=(_go("bob", target),))])
    outs = _until(w, lambda o: bool(o.looping_events or any(o.failures)), commands=[AssignEvent(
        event_id="go", assignments=(_go("ann", target, action="use_smartphone"),))])
    ann = w.characters["ann"]
    assert [f for o in outs for f in o.failures] == []
    assert ann.target is not None and ann.target.fallback == "stopped_near" and "no closer than" in ann.target.message
    gap = float(np.linalg.norm(ann.xy - np.asarray(target)))
    assert 0.5 - 1e-9 <= gap <= 1.0


def test_leg_ik_pins_feet_changes_only_legs_and_survives_snapshots(office: Office) -> None:
    from storyteller.sim.body.foot_ik import LEG_JOINTS
    from storyteller.sim.body.skeleton import forward_kinematics
    from storyteller.sim.motion.clips import foot_sliding
    from storyteller.sim.motion.database import load_databases
    from storyteller.sim.motion.matching import MotionMatcher

    scene, grid, planner = office
    cells = _free_cells(office)
    matcher = MotionMatcher(load_databases(["idle", "walk"], cache_dir=motion_cache_dir()))
    chars = {"ann": (_cell_xy(office, *cells[0]), 0.0), "bob": (_cell_xy(office, *cells[60]), 1.0)}
    cmds = {0: [AssignEvent(event_id="a", assignments=(_go("ann", _cell_xy(office, *cells[200])),)),
                AssignEvent(event_id="b", assignments=(_go("bob", _cell_xy(office, *cells[5])),))]}

    def make(ik: bool) -> World:
        return World(scene, chars, matcher, grid=grid, planner=planner, config=WorldConfig(foot_ik=ik))

    raw, ik = make(False), make(True)
    run(raw, 150, cmds)
    run(ik, 70, cmds)
    snap = ik.snapshot()  # mid-walk: feet locked
    assert ik.feet is not None and ik.feet.locked.any()
    run(ik, 80, {})
    again = ik.restore(snap)
    run(again, 80, {})
    legs = list(LEG_JOINTS)
    others = [j for j in range(NUM_JOINTS) if j not in legs]
    slide = {}
    for name in chars:
        r, k, a = raw.tracks()[name], ik.tracks()[name], again.tracks()[name]
        assert np.array_equal(r.root_positions, k.root_positions)  # the pelvis stays on the path
        assert np.array_equal(r.local_rotations[:, others], k.local_rotations[:, others])
        assert not np.allclose(r.local_rotations[:, legs], k.local_rotations[:, legs])
        assert np.array_equal(k.local_rotations, a.local_rotations)  # the foot state is in the snapshot
        contacts = raw.foot_contacts()[name]
        slide[name] = [foot_sliding(forward_kinematics(t.local_rotations, t.root_positions)[0], contacts)
                       for t in (r, k)]
    assert all(after < before for before, after in slide.values()), slide


def test_many_short_events_and_a_reused_event_id_start_and_leave_no_queue_behind(office: Office) -> None:
    # A story of hours creates thousands of events: the group start only looks at the ones that
    # have not started yet, and an id used again (after its event ended) starts like a new one.
    cells = _free_cells(office)
    here = _cell_xy(office, *cells[5])
    w = _world(office, {"ann": (here, 0.0)})
    for k in range(6):
        eid = "again" if k % 2 else f"e{k}"
        outs = _until(w, lambda o: bool(o.completed_events),
                      commands=[AssignEvent(event_id=eid, assignments=(_go("ann", here, "wave"),))])
        assert outs[-1].completed_events == (eid,)
        assert any(o.started_events == (eid,) for o in outs)
        assert w.start_queue == {}
    assert set(w.events) == {"e0", "again", "e2", "e4"} and all(e.status == "completed" for e in w.events.values())
    # an assigned, not yet started event survives a snapshot round trip in the queue
    far = _cell_xy(office, *cells[80])
    step(w, [AssignEvent(event_id="walk", assignments=(_go("ann", far),))], w.dt)
    back = w.restore(w.snapshot())
    assert back.start_queue == w.start_queue == {"walk": None}
    _until(back, lambda o: o.started_events == ("walk",))
    assert back.start_queue == {} and w.start_queue == {"walk": None}

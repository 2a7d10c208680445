"""Walkers blocked by a stationary body go around it instead of waiting until they count as stuck.

The ring room: a long table leaves a one-cell corridor above it and a two-cell one below; the
way round is longer than the planner's window (20 steps), so a windowed search guided by the
static distance alone never leaves the corridor when a body stands in it.
"""

from __future__ import annotations

import numpy as np

from storyteller.sim.paths.cooperative_astar import PathPlanner
from storyteller.sim.paths.nav_grid import build_nav_grid
from storyteller.sim.scene.bundled import resolve_scene
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.world.events import AssignEvent, Assignment, StepOutput
from storyteller.sim.world.partners import spaced
from storyteller.sim.world.step import World, WorldConfig, step
from tests.support.stand_in_motion import RestPoseMotion

RING = Scene(
    name="ring", bounds_min=(0.0, 0.0), bounds_max=(8.4, 2.4),
    objects=(SceneObject(name="table_1", label="table", idx=1, center=(4.2, 1.425, 0.4), size=(6.6, 0.45, 0.8)),),
)


def _run_until_started_or_failed(world: World, event: AssignEvent, limit: int) -> StepOutput:
    out = None
    for _ in range(limit):
        _, out = step(world, [event] if world.frame == 0 else (), world.dt)
        if out.failures or out.started_events:
            return out
    raise AssertionError(f"neither started nor failed in {limit} frames")


def test_detour_distances_go_around_stationary_bodies_and_equal_the_static_ones_without() -> None:
    grid = build_nav_grid(RING)
    planner = PathPlanner(grid)
    start, goal = grid.cell_of((0.45, 1.95)), grid.cell_of((6.6, 1.95))
    no_bodies = planner.statics.static_allow_of([], [])
    assert np.array_equal(planner.detour_distances(goal, no_bodies), planner.heuristic_array(goal))
    blocked = planner.statics.static_allow_of([np.array([4.23, 1.97])], [])
    around = planner.detour_distances(goal, blocked)[planner.cell_id(start)]
    assert round(planner.distance(start, goal) / grid.cell_size) == 21  # straight along the corridor
    assert planner.window < around < np.inf  # round the table: longer than one window
    result = planner.plan({"bob": start}, {"bob": goal}, [np.array([4.23, 1.97])], detour=["bob"])
    assert result.detour["bob"] == around
    path = result.paths["bob"]
    assert path[-1][1] < start[1]  # heading down the side column, not into the corridor
    plain = planner.plan({"bob": start}, {"bob": goal}, [np.array([4.23, 1.97])])
    assert plain.detour == {} and plain.paths["bob"][-1][1] == start[1]


def test_a_walker_goes_round_a_member_waiting_in_a_one_cell_corridor() -> None:
    # ann arrives first and waits on her exact target in the top corridor; bob's target is past her
    world = World(RING, {"ann": ((4.35, 1.95), 0.0), "bob": ((0.45, 1.95), 0.0)}, RestPoseMotion(record=True))
    meet = AssignEvent(event_id="meet", assignments=(
        Assignment(character="ann", action="chat", target_xy=(4.23, 1.97), facing_xy=(1.0, 0.0), partners=("bob",)),
        Assignment(character="bob", action="chat", target_xy=(6.6, 1.95), facing_xy=(-1.0, 0.0), partners=("ann",)),
    ))
    # a chatting pair is spaced at talking distance about its midpoint (sim.world.partners):
    # bob's spot is still past ann's in the corridor
    spots = {a.character: a.target_xy for a in spaced(world.grid, meet).assignments}
    assert spots["bob"][0] > spots["ann"][0] + 0.8
    out = _run_until_started_or_failed(world, meet, 900)
    assert out.failures == () and out.started_events == ("meet",)
    assert np.allclose(world.characters["bob"].xy, spots["bob"], atol=0.05)


def test_a_walker_with_no_way_round_still_fails_as_stuck() -> None:
    # the same, but the corridor below is closed: the detour distance is infinite
    closed = Scene(name="closed", bounds_min=(0.0, 0.0), bounds_max=(8.4, 2.4), objects=(
        *RING.objects,
        SceneObject(name="box_1", label="box", idx=1, center=(6.0, 0.6, 0.4), size=(0.3, 1.2, 0.8)),
    ))
    world = World(closed, {"ann": ((4.35, 1.95), 0.0), "bob": ((0.45, 1.95), 0.0)}, RestPoseMotion(record=True),
                  config=WorldConfig(stuck_after_s=6.0))
    meet = AssignEvent(event_id="meet", assignments=(
        Assignment(character="ann", action="chat", target_xy=(4.23, 1.97), facing_xy=(1.0, 0.0), partners=("bob",)),
        Assignment(character="bob", action="chat", target_xy=(6.6, 1.95), facing_xy=(-1.0, 0.0), partners=("ann",)),
    ))
    out = _run_until_started_or_failed(world, meet, 900)
    assert [(f.character, f.reason) for f in out.failures] == [("bob", "stuck")]


def test_office_meeting_members_reach_targets_behind_a_waiting_member() -> None:
    # office_meeting_four (story suite): Ben and Cleo wait in the one-cell gap between the
    # conference table and the whiteboard; Ava's target lies past them
    scene = resolve_scene("office")
    starts = {"Ava": (6.552, 5.836), "Ben": (9.26, 0.269), "Cleo": (9.322, 4.332), "Dan": (7.404, 5.204)}
    world = World(scene, {n: (p, 0.0) for n, p in starts.items()}, RestPoseMotion(record=True), config=WorldConfig(foot_ik=False))
    targets = {"Ava": ((9.582, 1.763), (-0.954, 0.301)), "Ben": ((9.644, 2.528), (-0.975, -0.221)),
               "Cleo": ((9.404, 2.97), (-0.842, -0.539)), "Dan": ((6.845, 2.843), (0.903, -0.429))}
    meeting = AssignEvent(event_id="meeting", assignments=tuple(
        Assignment(character=n, action="attend_meeting", target_xy=p, facing_xy=f) for n, (p, f) in targets.items()))
    out = _run_until_started_or_failed(world, meeting, 900)
    assert out.failures == () and out.started_events == ("meeting",)

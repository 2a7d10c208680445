"""Walkers that cross keep their legs apart (issue 25: body-body overlap 0 frames).

A walking body is not its standing disc: its swinging foot reaches about 0.4 m ahead of the
pelvis. With the clearance of two standing discs (0.5 m between centres), two characters
crossing at right angles passed 0.6 m apart and touched thigh against thigh and foot against
foot (the scripted home story's frames 2364-2373). The planner now keeps two agents that both
move in a step with their legs apart (``storyteller.sim.paths.move_tables.striding_safe``: a segment along
each one's direction of travel, ``LEG_REACH_M`` ahead and ``LEG_TRAIL_M`` behind, of radius
``LEG_RADIUS_M``).

The scenario: an empty 5 m x 5 m room, two characters whose straight paths cross at the room's
centre at the same time. Checked on the planner's positions (the rule) and through the full world
step with motion matching (the bodies: the sphere model of ``storyteller.benchmark.motion_metrics.bodies``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from storyteller.sim.paths.cooperative_astar import PathPlanner, segment_distance
from storyteller.sim.paths.following import CrowdNavigator
from storyteller.sim.paths.move_tables import LEG_RADIUS_M, LEG_REACH_M, LEG_TRAIL_M
from storyteller.sim.paths.nav_grid import build_nav_grid
from storyteller.sim.scene.model import Scene

ROOM = Scene(name="room", bounds_min=(0.0, 0.0), bounds_max=(5.1, 5.1), objects=())
# (start, goal) per walker: one walks +x, the other +y; both pass the centre at the same time
CROSSING = {"a": ((0.75, 2.55), (4.35, 2.55)), "b": ((2.55, 0.75), (2.55, 4.35))}


def _walk(nav: CrowdNavigator, frames: int) -> np.ndarray:
    out = []
    for _ in range(frames):
        pos = nav.tick()
        out.append([pos[a] for a in sorted(CROSSING)])
    return np.asarray(out)


def test_crossing_walkers_keep_their_legs_apart_on_the_planned_paths() -> None:
    grid = build_nav_grid(ROOM)
    planner = PathPlanner(grid, seed=0)
    nav = CrowdNavigator(grid, planner, seed=0)
    for agent, (start, goal) in CROSSING.items():
        nav.add_walker(agent, grid.cell_of(np.asarray(start)), goal=grid.cell_of(np.asarray(goal)))
    xy = _walk(nav, 300)  # (F, 2 walkers, 2)
    assert {a for _, a in nav.arrivals} == set(CROSSING)
    step = np.diff(xy, axis=0)  # (F - 1, 2, 2)
    speed = np.linalg.norm(step, axis=-1)
    both = np.flatnonzero((speed[:, 0] > 1e-9) & (speed[:, 1] > 1e-9))
    assert len(both)
    # each walker's legs: a segment through its centre along its direction of travel
    ahead = step[both] / speed[both][..., None]
    centre = xy[1:][both]
    back, front = centre - LEG_TRAIL_M * ahead, centre + LEG_REACH_M * ahead
    apart = segment_distance(back[:, 0], front[:, 0], back[:, 1], front[:, 1])
    assert float(apart.min()) >= 2.0 * LEG_RADIUS_M - 1e-6
    assert float(np.linalg.norm(xy[:, 0] - xy[:, 1], axis=-1).min()) >= planner.min_distance - 1e-6


@pytest.mark.slow
def test_crossing_bodies_do_not_overlap_through_the_world_step() -> None:
    from storyteller.benchmark.motion_metrics.bodies import body_overlap, sphere_body
    from storyteller.orchestrator.cache_paths import motion_cache_dir
    from storyteller.sim.body.skeleton import forward_kinematics
    from storyteller.sim.motion.database import load_databases
    from storyteller.sim.motion.matching import MotionMatcher
    from storyteller.sim.world.events import AssignEvent, Assignment
    from storyteller.sim.world.step import World, WorldConfig, step

    grid = build_nav_grid(ROOM)
    starts = {a: (tuple(grid.center_of(*grid.cell_of(np.asarray(s)))), math.atan2(g[1] - s[1], g[0] - s[0]))
              for a, (s, g) in CROSSING.items()}
    world = World(ROOM, starts, MotionMatcher(load_databases(cache_dir=motion_cache_dir())), grid=grid,
                  config=WorldConfig(seed=0, initial_capacity=240))
    commands = [AssignEvent(event_id=f"go-{a}", assignments=(Assignment(
        character=a, action="idle", target_xy=tuple(grid.center_of(*grid.cell_of(np.asarray(g)))),
        facing_xy=(1.0, 0.0)),)) for a, (_, g) in CROSSING.items()]
    for _ in range(240):
        step(world, commands, world.dt)
        commands = []
    tracks = world.tracks()
    body = sphere_body()
    centres = [body.centres(forward_kinematics(tracks[a].local_rotations, tracks[a].root_positions)[0])
               for a in sorted(CROSSING)]
    for a in CROSSING:  # both crossed the room
        end = tracks[a].root_positions[-1, :2]
        assert float(np.linalg.norm(end - np.asarray(CROSSING[a][1]))) < 0.3
    depth = body_overlap(centres[0], centres[1], body)
    assert int(np.sum(depth > 0.0)) == 0, f"{int(np.sum(depth > 0.0))} frames overlap, deepest {depth.max():.3f} m"

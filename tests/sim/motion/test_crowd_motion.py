"""The issue's crowd measure, on synthesized motion (issue 4, "Measured by").

50 characters walk between random targets in the reference Office scene for 60 s of simulated
time (1800 frames at 30 fps) through the full world step: cooperative paths, character phases
(each target is an ``idle`` event: walk, turn to a random facing, stand, get the next target;
``python tests/sim/motion/test_crowd_motion.py`` also runs targets up to 0.12 m off the cell centres)
and motion matching. Checked on every frame of the output tracks (forward kinematics of what
the exporters would write):

- body overlaps: pelvis xy centres of every pair >= 2 x 0.25 m;
- furniture penetrations, body model: the pelvis is a disc of radius 0.25 m that must not touch
  the footprint of any object a walking body can hit (bottom below 1.9 m: the nav grid's
  obstacles), strict; the feet (ankle and toe joints) are points that must not lie inside the
  footprint (oriented bounding box) of any object standing on the floor (bottom within
  0.10 m of it), strict too. A stride reaches ~0.4 m past the pelvis while the root stays
  exactly on the planner's path; the world's leg IK (``storyteller.sim.body.foot_ik``, on by default) moves a
  foot that would enter a footprint out of it (the deepest graze without it was 8 cm here,
  12 cm with off-grid targets);
- foot sliding: mean horizontal toe speed (m/s) over frames where the motion layer
  marks that foot in contact in two consecutive frames (``storyteller.sim.motion.clips.foot_sliding``'s
  rule, pooled over characters): about 0.30 m/s with the leg IK pinning planted feet, 0.60
  without; targets reached (reported).

Run ``python tests/sim/motion/test_crowd_motion.py`` to print the figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from storyteller.orchestrator.cache_paths import motion_cache_dir
from storyteller.sim.body.skeleton import forward_kinematics
from storyteller.sim.motion.clips import ANKLE_JOINTS, FOOT_JOINTS
from storyteller.sim.paths.nav_grid import body_clearance
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.events import AssignEvent, Assignment
from storyteller.sim.world.motion_layer import MotionLayer
from storyteller.sim.world.step import World, WorldConfig, step
from tests.support.reference import OFFICE, reference_or_skip

BODY_RADIUS = 0.25
FLOOR_SUPPORT = 0.10


@dataclass
class CrowdReport:
    frames: int
    characters: int
    min_pair_distance: float
    overlap_frames: int
    pelvis_min_clearance: float
    pelvis_penetrations: int
    feet_in_boxes: int
    feet_max_depth: float
    feet_penetrations: int
    in_progress: int
    foot_sliding: float
    contact_fraction: float
    targets_given: int
    targets_reached: int
    failures: int

    def lines(self) -> str:
        return "\n".join(f"{k}: {v}" for k, v in self.__dict__.items())


def _spread_cells(cells: np.ndarray, count: int, rng: np.random.Generator, taken: list[np.ndarray]) -> list[np.ndarray]:
    """Pick ``count`` cells >= 2 cells apart (Chebyshev) from each other and from ``taken``."""
    out: list[np.ndarray] = []
    for k in rng.permutation(len(cells)):
        c = cells[k]
        if all(np.max(np.abs(c - o)) >= 2 for o in taken + out):
            out.append(c)
            if len(out) == count:
                return out
    raise AssertionError(f"only {len(out)} spread cells available")


def simulate_crowd(scene: Scene, n: int, frames: int, seed: int, motion: MotionLayer, off_grid: float = 0.0,
                   foot_ik: bool = True) -> tuple[World, CrowdReport]:
    """Run the crowd; returns the world and the measured report.

    ``off_grid`` (metres): targets are random cell centres moved by up to this much along x
    and y (kept where a body fits), so walkers end on exact points off the grid."""
    from storyteller.sim.paths.nav_grid import build_nav_grid

    grid = build_nav_grid(scene)
    cells = np.argwhere(grid.component == grid.main_component)
    rng = np.random.default_rng(seed)
    jitter = np.random.default_rng(seed + 1)  # off-grid offsets: their own stream, same cells as without
    starts = _spread_cells(cells, n, rng, [])
    names = [f"p{i:02d}" for i in range(n)]
    world = World(
        scene,
        {name: (tuple(grid.center_of(*c)), float(rng.uniform(-math.pi, math.pi))) for name, c in zip(names, starts, strict=True)},
        motion,
        grid=grid,
        config=WorldConfig(seed=seed, initial_capacity=frames, foot_ik=foot_ik),
    )
    targets: dict[str, np.ndarray] = {name: c for name, c in zip(names, starts, strict=True)}
    counter = dict.fromkeys(names, 0)
    given = reached = failures = 0
    pending_new = set(names)
    for _ in range(frames):
        commands = []
        for name in sorted(pending_new):
            others = [targets[o] for o in names if o != name]
            cell = _spread_cells(cells, 1, rng, others)[0]
            targets[name] = cell
            theta = float(rng.uniform(-math.pi, math.pi))
            xy = grid.center_of(*cell) + (jitter.uniform(-off_grid, off_grid, 2) if off_grid > 0 else 0.0)
            if not grid.is_free_xy(xy):
                xy = grid.center_of(*cell)
            counter[name] += 1
            given += 1
            commands.append(AssignEvent(event_id=f"{name}-{counter[name]}", assignments=(Assignment(
                character=name, action="idle", target_xy=(float(xy[0]), float(xy[1])),
                facing_xy=(math.cos(theta), math.sin(theta))),)))
        pending_new = set()
        _, out = step(world, commands, world.dt)
        for eid in out.looping_events:
            reached += 1
            pending_new.add(eid.rsplit("-", 1)[0])
        for f in out.failures:
            failures += 1
            pending_new.add(f.character)
    return world, measure(world, scene, given, reached, failures)


def measure(world: World, scene: Scene, given: int, reached: int, failures: int) -> CrowdReport:
    tracks = world.tracks()
    names = list(tracks)
    pelvis = np.stack([tracks[n].root_positions for n in names], axis=1)  # (F, N, 3)
    frames, n = pelvis.shape[:2]
    xy = pelvis[..., :2]
    d = np.linalg.norm(xy[:, :, None] - xy[:, None, :], axis=-1)
    d[:, np.arange(n), np.arange(n)] = np.inf
    min_pair = float(d.min())
    overlap_frames = int(np.sum(np.any(d < 2 * BODY_RADIUS - 1e-6, axis=(1, 2))))

    blocking = world.grid.obstacles
    flat = xy.reshape(-1, 2)
    clearance = body_clearance(blocking, flat, flat)
    pelvis_pen = int(np.sum(clearance < BODY_RADIUS - 1e-6))

    floor_objs = [o for o in scene.objects if o.z_min - scene.floor_z < FLOOR_SUPPORT]
    contacts = world.foot_contacts()
    feet_in = 0
    feet_depth = 0.0
    feet_pen = 0
    slides: list[np.ndarray] = []
    contact_frames = 0
    for name in names:
        t = tracks[name]
        joints = forward_kinematics(t.local_rotations, t.root_positions)[0]
        feet = joints[:, list(FOOT_JOINTS) + list(ANKLE_JOINTS), :2].reshape(-1, 2)
        depth = np.full(len(feet), -np.inf)
        for o in floor_objs:
            loc = o.to_local(feet)
            d = np.minimum(o.width / 2 - np.abs(loc[:, 0]), o.depth / 2 - np.abs(loc[:, 1]))
            depth = np.maximum(depth, d)
        feet_in += int(np.sum(depth >= 0.0))
        feet_depth = max(feet_depth, float(depth.max()))
        feet_pen += int(np.sum(depth > 0.0))
        toes = joints[:, FOOT_JOINTS, :2]
        contact = contacts[name]
        both = contact[1:] & contact[:-1]
        speed = np.linalg.norm(np.diff(toes, axis=0), axis=-1) * world.config.fps
        slides.append(speed[both])
        contact_frames += int(contact.sum())
    allslide = np.concatenate(slides)
    return CrowdReport(
        frames=frames,
        characters=n,
        min_pair_distance=min_pair,
        overlap_frames=overlap_frames,
        pelvis_min_clearance=float(clearance.min()),
        pelvis_penetrations=pelvis_pen,
        feet_in_boxes=feet_in,
        feet_max_depth=max(feet_depth, 0.0),
        feet_penetrations=feet_pen,
        in_progress=sum(1 for c in world.characters.values()
                        if c.event_id is not None and world.events[c.event_id].status == "ongoing"),
        foot_sliding=float(allslide.mean()) if len(allslide) else 0.0,
        contact_fraction=contact_frames / (frames * n * 2),
        targets_given=given,
        targets_reached=reached,
        failures=failures,
    )


@pytest.fixture(scope="module")
def crowd() -> tuple[World, CrowdReport]:
    reference_or_skip()
    from storyteller.sim.motion.database import load_databases
    from storyteller.sim.motion.matching import MotionMatcher

    scene = load_scene(OFFICE)
    return simulate_crowd(scene, n=50, frames=1800, seed=7, motion=MotionMatcher(load_databases(cache_dir=motion_cache_dir())), off_grid=0.0)


@pytest.mark.slow
def test_fifty_walkers_never_overlap(crowd: tuple[World, CrowdReport]) -> None:
    _, report = crowd
    print(report.lines())
    assert report.frames == 1800 and report.characters == 50
    assert report.overlap_frames == 0, report.lines()
    assert report.min_pair_distance >= 2 * BODY_RADIUS - 1e-6


@pytest.mark.slow
def test_fifty_walkers_never_enter_furniture(crowd: tuple[World, CrowdReport]) -> None:
    _, report = crowd
    assert report.pelvis_penetrations == 0, report.lines()
    assert report.feet_penetrations == 0 and report.feet_in_boxes == 0, report.lines()


@pytest.mark.slow
def test_off_grid_targets_keep_feet_out_of_furniture() -> None:
    # Targets up to 0.12 m off the cell centres bring bodies closer to furniture edges (without
    # the leg IK two foot joints went over 10 cm deep here).
    reference_or_skip()
    from storyteller.sim.motion.database import load_databases
    from storyteller.sim.motion.matching import MotionMatcher

    _, report = simulate_crowd(load_scene(OFFICE), n=20, frames=600, seed=3, motion=MotionMatcher(load_databases(cache_dir=motion_cache_dir())),
                               off_grid=0.12)
    assert report.overlap_frames == 0 and report.pelvis_penetrations == 0, report.lines()
    assert report.feet_in_boxes == 0, report.lines()


@pytest.mark.slow
def test_every_target_is_reached_failed_or_under_way(crowd: tuple[World, CrowdReport]) -> None:
    _, report = crowd
    # No target is lost: each one was reached, failed with a typed reason, or is still being
    # walked to at the end (one per character at most). Corridors of the Office jam with 50
    # people going both ways; the planner's quality decides how many targets are reached.
    assert report.targets_given == report.targets_reached + report.failures + report.in_progress, report.lines()
    assert report.targets_reached >= 10, report.lines()


@pytest.mark.slow
def test_feet_slide_less_than_a_skating_body(crowd: tuple[World, CrowdReport]) -> None:
    _, report = crowd
    # The leg IK pins planted feet: about 0.30 m/s here against 0.60 m/s without it, so the
    # bound catches both a body that skates along its path and pinning that stopped working.
    assert 0.0 < report.foot_sliding < 0.45, report.lines()
    assert report.contact_fraction > 0.3, report.lines()


if __name__ == "__main__":
    import time

    from storyteller.sim.motion.database import load_databases
    from storyteller.sim.motion.matching import MotionMatcher

    t0 = time.perf_counter()
    for off in (0.0, 0.12):
        _, rep = simulate_crowd(load_scene(OFFICE), 50, 1800, 7, MotionMatcher(load_databases(cache_dir=motion_cache_dir())), off_grid=off)
        print(f"off_grid {off} m\n{rep.lines()}")
    print(f"wall time {time.perf_counter() - t0:.1f} s")

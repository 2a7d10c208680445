"""The crowd scenario of issue 4's measure: walkers between random targets in a scene, and the
figures read off their tracks (body overlaps, pelvis and feet inside furniture, foot sliding).

Used by ``tests/sim/motion/test_crowd_motion.py`` (which states the rules and checks them on the
reference Office scene) and by ``python -m storyteller.benchmark.foot_ik_effect``. On the
benchmark floor: imports ``sim`` and ``orchestrator``, never ``tests``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from storyteller.sim.body.skeleton import forward_kinematics
from storyteller.sim.motion.clips import ANKLE_JOINTS, FOOT_JOINTS
from storyteller.sim.paths.nav_grid import body_clearance
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.events import AssignEvent, Assignment
from storyteller.sim.world.motion_layer import MotionLayer
from storyteller.sim.world.step import World, WorldConfig, step

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

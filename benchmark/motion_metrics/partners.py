"""Partners: two characters sent to do a partner action together (chat, handshake, hug) from
points a planner might give them, measured where they start it.

``partner_pairs(count, seed)`` runs ``count`` pairs in the bundled home scene (no reference
data, no LLM), one fresh two-character world per pair with the procedural motion databases:
the two points are free points of the main floor ``PLANNED_GAP_M`` apart (uniform, seeded), the
action cycles through ``ACTIONS``. For each pair, the frame both are acting: the distance
between their pelvises, each one's facing error (root forward against the direction to the
other, degrees), and for a handshake the gap between their right wrists at the middle of the
shake (metres). A pair that does not start within ``LIMIT_S`` counts as not started.

``python -m storyteller.benchmark.motion_metrics.partners [--pairs N] [--seed S]`` prints the table.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

ACTIONS = ("chat", "handshake", "hug")
PLANNED_GAP_M = (0.6, 2.4)
LIMIT_S = 30.0


@dataclass(frozen=True)
class PairResult:
    action: str
    planned_gap: float
    started: bool
    distance: float = math.nan  # metres between the pelvises when both act
    facing_deg: float = math.nan  # the worse of the two facing errors
    hands_gap: float = math.nan  # handshake: right wrists apart at the middle of the shake, metres


def _facing_error(root_rot: np.ndarray, own: np.ndarray, other: np.ndarray) -> float:
    from storyteller.sim.world.motion_layer import root_yaw

    want = math.atan2(float(other[1] - own[1]), float(other[0] - own[0]))
    return abs(math.degrees(math.remainder(float(root_yaw(root_rot)) - want, 2 * math.pi)))


def partner_pairs(count: int, seed: int = 0) -> list[PairResult]:
    """Run ``count`` pairs (see the module docstring)."""
    from storyteller.orchestrator.cache_paths import motion_cache_dir
    from storyteller.sim.body.skeleton import JOINT_INDEX, forward_kinematics
    from storyteller.sim.motion.action_labels import action_spec
    from storyteller.sim.motion.database import load_databases
    from storyteller.sim.motion.matching import MotionMatcher
    from storyteller.sim.paths.nav_grid import build_nav_grid
    from storyteller.sim.scene.bundled import load_bundled_scene
    from storyteller.sim.world.events import AssignEvent, Assignment
    from storyteller.sim.world.step import World, WorldConfig, step

    scene = load_bundled_scene("home")
    grid = build_nav_grid(scene)
    matcher = MotionMatcher(load_databases(["idle", "walk", *ACTIONS], cache_dir=motion_cache_dir()))
    rng = np.random.default_rng(seed)
    cells = np.argwhere(grid.component == grid.main_component)
    right = JOINT_INDEX["right_wrist"]
    out: list[PairResult] = []
    for k in range(count):
        action = ACTIONS[k % len(ACTIONS)]
        for _ in range(1000):  # two free points of the main floor the planned gap apart
            a = grid.center_of(*cells[rng.integers(len(cells))]) + rng.uniform(-0.1, 0.1, 2)
            gap = float(rng.uniform(*PLANNED_GAP_M))
            ang = float(rng.uniform(-math.pi, math.pi))
            b = a + gap * np.array([math.cos(ang), math.sin(ang)])
            if grid.is_free_xy(a) and grid.is_free_xy(b) and grid.entry_cell(a) is not None \
                    and grid.entry_cell(b) is not None:
                break
        else:
            raise RuntimeError("no room for a pair in the home scene")
        start = {"ann": ((float(a[0]), float(a[1])), ang), "bob": ((float(b[0]), float(b[1])), ang + math.pi)}
        world = World(scene, start, matcher, grid=grid, config=WorldConfig(seed=seed))
        face = (math.cos(ang), math.sin(ang))
        cmd = AssignEvent(event_id=f"pair-{k}", assignments=(
            Assignment(character="ann", action=action, target_xy=start["ann"][0], facing_xy=face, partners=("bob",)),
            Assignment(character="bob", action=action, target_xy=start["bob"][0], facing_xy=(-face[0], -face[1]),
                       partners=("ann",))))
        first = [cmd]
        started = False
        for _ in range(round(LIMIT_S * 30)):
            _, o = step(world, first, world.dt)
            first = []
            if o.failures:
                break
            if all(world.characters[n].phase == "interacting" for n in ("ann", "bob")):
                started = True
                break
        if not started:
            out.append(PairResult(action, gap, False))
            continue
        tracks = world.tracks()
        rot = {n: tracks[n].local_rotations[-1] for n in ("ann", "bob")}
        pel = {n: tracks[n].root_positions[-1] for n in ("ann", "bob")}
        dist = float(np.linalg.norm(pel["ann"][:2] - pel["bob"][:2]))
        facing = max(_facing_error(rot["ann"][0], pel["ann"], pel["bob"]), _facing_error(rot["bob"][0], pel["bob"], pel["ann"]))
        hands = math.nan
        if action == "handshake":
            for _ in range(round(action_spec(action).duration_s * 30 / 2) - 1):
                step(world, [], world.dt)
            tracks = world.tracks()
            w = [forward_kinematics(tracks[n].local_rotations[-1], tracks[n].root_positions[-1])[0][right]
                 for n in ("ann", "bob")]
            hands = float(np.linalg.norm(w[0] - w[1]))
        out.append(PairResult(action, gap, True, dist, facing, hands))
    return out


def partner_table(results: Sequence[PairResult]) -> tuple[list[str], list[list[str]]]:
    """Per action: pairs, started, planned gap range, distance med/min/max (m), facing error
    med/max (deg), handshake hands gap med/max (cm)."""
    head = ["action", "pairs", "started", "planned m min/max", "distance m med/min/max", "facing deg med/max",
            "hands gap cm med/max"]
    rows = []
    for action in ACTIONS:
        rs = [r for r in results if r.action == action]
        if not rs:
            continue
        ok = [r for r in rs if r.started]
        d = np.array([r.distance for r in ok])
        f = np.array([r.facing_deg for r in ok])
        h = np.array([r.hands_gap for r in ok if math.isfinite(r.hands_gap)]) * 100
        planned = [r.planned_gap for r in rs]
        rows.append([
            action, str(len(rs)), str(len(ok)), f"{min(planned):.2f}/{max(planned):.2f}",
            f"{np.median(d):.2f}/{d.min():.2f}/{d.max():.2f}" if len(d) else "-",
            f"{np.median(f):.1f}/{f.max():.1f}" if len(f) else "-",
            f"{np.median(h):.1f}/{h.max():.1f}" if len(h) else "-",
        ])
    return head, rows


def main(argv: Sequence[str] | None = None) -> int:
    from storyteller.benchmark.motion_metrics.report import as_text

    p = argparse.ArgumentParser(prog="python -m storyteller.benchmark.motion_metrics.partners", description=__doc__.splitlines()[0])
    p.add_argument("--pairs", type=int, default=12)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    if args.pairs < 1:
        print("error: --pairs must be >= 1")
        return 2
    print(as_text(partner_table(partner_pairs(args.pairs, args.seed))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

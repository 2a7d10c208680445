"""Motion quality of the generated clips against real mocap, of the synthesized motion, and facing.

Two comparisons, each printed as ``procedural / real`` ratios measured in the same run, and a
facing table (3. below):

1. **Clips.** For every action label that ``benchmark/mocap_shared.toml`` covers with real
   clips (walk, wave, dance), the project's procedural clips and the imported real clips (on
   our skeleton at 30 fps) are measured with the same metrics.
2. **Synthesized motion.** A few characters walk between random targets in the reference
   Office scene through the full world step, once with the procedural databases and once with
   databases built from the real clips; the output tracks are measured.

Metrics (all on the 22-joint skeleton, metres and seconds):

- ``slide``: mean horizontal toe speed (m/s) over frames where that foot is in contact in the
  frame and the next (lower is better; 0 is perfectly planted);
- ``jerk``: median magnitude of the third time derivative of joint positions (m/s^3) over
  every joint and frame, a smoothness measure (mocap noise makes real data non-zero);
- ``speed``: mean horizontal root speed (m/s);
- ``cadence``: foot contact onsets per minute (steps/min; walking only);
- ``bob``: standard deviation of pelvis height (m);
- ``floor``: lowest toe height (m; negative means the foot sinks into the floor).

3. **Facing at interaction start** (``storyteller.benchmark.motion_facing``): facing error when a standing
   interaction starts and while it lasts (root forward against the direction to the object's
   nearest footprint point, or to the partners) and the distance to the object, for a scripted
   story through the world step (and the same without the world's facing, as before it), and
   for any run folders given with ``--facing-runs``.

Run ``python -m storyteller.benchmark.motion_quality`` from the project root (``--help`` for options).
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from storyteller.benchmark.motion_facing import report as facing_report
from storyteller.orchestrator.cache_paths import motion_cache_dir
from storyteller.orchestrator.reference_data import locate_mocap, locate_reference
from storyteller.sim.body.skeleton import forward_kinematics
from storyteller.sim.motion.clips import FOOT_JOINTS, MotionClip, foot_sliding
from storyteller.sim.motion.config import (
    MotionConfig,
    build_databases_from_config,
    import_entry,
    load_motion_config,
)
from storyteller.sim.motion.database import load_databases
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.motion.sources.procedural_library import procedural_clips

HERE = Path(__file__).resolve().parent
DEFAULT_CONFIG = HERE / "mocap_shared.toml"
REFERENCE = locate_reference()
OFFICE = REFERENCE.path / "configs" / "scenes" / "Office"
MOCAP = locate_mocap()
FPS = 30.0
METRICS = ("slide", "jerk", "speed", "cadence", "bob", "floor")


@dataclass(frozen=True)
class MotionStats:
    """Quality figures of one or more motions pooled (see the module docstring)."""

    frames: int
    slide: float
    jerk: float
    speed: float
    cadence: float
    bob: float
    floor: float

    def row(self) -> list[float]:
        return [getattr(self, m) for m in METRICS]


def shipped_config() -> MotionConfig:
    """``mocap_shared.toml`` reading its clips from the located mocap folder (``$STORYTELLER_MOCAP``,
    else ``../shared/mocap``, which is the TOML's own ``root`` for a checkout beside ``shared/``)."""
    config = load_motion_config(DEFAULT_CONFIG)
    return config.model_copy(update={"root": str(MOCAP.path)}) if MOCAP.found else config


def motion_stats(joints: np.ndarray, root_xy: np.ndarray, contacts: np.ndarray, fps: float = FPS) -> MotionStats:
    """Figures of one motion: joints (F,22,3), root_xy (F,2), contacts (F,2) bool."""
    joints = np.asarray(joints, dtype=float)
    contacts = np.asarray(contacts, dtype=bool)
    n = len(joints)
    if n < 4:
        raise ValueError(f"a motion needs at least 4 frames to be measured, got {n}")
    jerk = np.linalg.norm(np.diff(joints, n=3, axis=0), axis=-1) * fps**3
    speed = np.linalg.norm(np.diff(root_xy, axis=0), axis=-1).mean() * fps
    onsets = int(np.sum(contacts[1:] & ~contacts[:-1]))
    minutes = (n - 1) / fps / 60.0
    return MotionStats(
        frames=n,
        slide=foot_sliding(joints, contacts, fps),
        jerk=float(np.median(jerk)),
        speed=float(speed),
        cadence=onsets / minutes,
        bob=float(np.std(joints[:, 0, 2])),
        floor=float(joints[:, list(FOOT_JOINTS), 2].min()),
    )


def pooled(stats: Sequence[MotionStats]) -> MotionStats:
    """Frame-weighted mean of several motions' figures (the lowest ``floor``)."""
    if not stats:
        raise ValueError("nothing to pool")
    w = np.array([s.frames for s in stats], dtype=float)
    mean = {m: float(np.average([getattr(s, m) for s in stats], weights=w)) for m in METRICS if m != "floor"}
    return MotionStats(frames=int(w.sum()), floor=min(s.floor for s in stats), **mean)


def clip_stats(clip: MotionClip) -> MotionStats:
    return motion_stats(clip.joint_positions(), clip.root_xy, clip.contacts, clip.fps)


def real_clips(config: MotionConfig, labels: Iterable[str] | None = None) -> dict[str, list[MotionClip]]:
    """The config's clips imported on our skeleton, by database key."""
    wanted = None if labels is None else set(labels)
    out: dict[str, list[MotionClip]] = {}
    for entry in config.clips:
        if wanted is None or entry.key in wanted:
            out.setdefault(entry.key, []).append(import_entry(config, entry, motion_cache_dir()))
    return out


def compare_clips(config: MotionConfig, labels: Iterable[str] | None = None) -> dict[str, tuple[MotionStats, MotionStats]]:
    """(procedural, real) figures per database key the config covers."""
    return {
        key: (pooled([clip_stats(c) for c in procedural_clips(key)]), pooled([clip_stats(c) for c in clips]))
        for key, clips in sorted(real_clips(config, labels).items())
    }


def simulate_walkers(motion: MotionMatcher, n: int, seconds: float, seed: int, scene_dir: Path = OFFICE) -> MotionStats:
    """``n`` characters walk between random free cells of a scene; figures of their tracks."""
    from storyteller.sim.paths.nav_grid import build_nav_grid
    from storyteller.sim.scene.files import load_scene
    from storyteller.sim.world.events import AssignEvent, Assignment
    from storyteller.sim.world.step import World, WorldConfig, step

    scene = load_scene(scene_dir)
    grid = build_nav_grid(scene)
    cells = np.argwhere(grid.component == grid.main_component)
    rng = np.random.default_rng(seed)
    frames = round(seconds * FPS)
    picks = cells[rng.choice(len(cells), size=4 * n, replace=False)]
    starts = [c for i, c in enumerate(picks) if all(np.max(np.abs(c - o)) >= 3 for o in picks[:i])][:n]
    if len(starts) < n:
        raise ValueError(f"could not place {n} walkers apart in {scene.name}")
    names = [f"w{i}" for i in range(n)]
    world = World(
        scene,
        {name: (tuple(grid.center_of(*c)), float(rng.uniform(-math.pi, math.pi))) for name, c in zip(names, starts, strict=True)},
        motion,
        grid=grid,
        config=WorldConfig(seed=seed, initial_capacity=frames),
    )
    pending, count = set(names), 0
    for _ in range(frames):
        commands = []
        for name in sorted(pending):
            cell = cells[rng.integers(len(cells))]
            xy = grid.center_of(*cell)
            count += 1
            commands.append(AssignEvent(event_id=f"{name}-{count}", assignments=(Assignment(
                character=name, action="idle", target_xy=(float(xy[0]), float(xy[1])), facing_xy=(1.0, 0.0)),)))
        pending = set()
        _, out = step(world, commands, world.dt)
        pending.update(eid.rsplit("-", 1)[0] for eid in out.looping_events)
        pending.update(f.character for f in out.failures)
    tracks, contacts = world.tracks(), world.foot_contacts()
    stats = []
    for name in names:
        t = tracks[name]
        joints = forward_kinematics(t.local_rotations, t.root_positions)[0]
        stats.append(motion_stats(joints, t.root_positions[:, :2], contacts[name]))
    return pooled(stats)


def _ratio(a: float, b: float) -> str:
    return "n/a" if abs(b) < 1e-12 else f"{a / b:.2f}"


def format_table(rows: Sequence[tuple[str, MotionStats, MotionStats]]) -> str:
    """One line per label and metric: procedural, real, and their ratio."""
    lines = [f"{'label':10s}{'metric':>9s}{'procedural':>12s}{'real':>12s}{'proc/real':>11s}"]
    for label, proc, real in rows:
        for m, p, r in zip(METRICS, proc.row(), real.row(), strict=True):
            lines.append(f"{label:10s}{m:>9s}{p:12.4g}{r:12.4g}{_ratio(p, r):>11s}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG, help="motion config with the real clips")
    parser.add_argument("--walkers", type=int, default=4, help="characters in the synthesized comparison (0: skip)")
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated seconds of the synthesized comparison")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--facing-runs", type=Path, nargs="*", default=[], metavar="RUN_DIR",
                        help="run folders whose interactions' facing is measured besides the scripted story")
    parser.add_argument("--facing-seconds", type=float, default=150.0, help="simulated seconds of the facing story (0: skip)")
    args = parser.parse_args(argv)

    config = shipped_config() if args.config == DEFAULT_CONFIG else load_motion_config(args.config)
    t0 = time.perf_counter()
    clips = compare_clips(config)
    print(f"clips (procedural vs real mocap from {args.config.name}; {time.perf_counter() - t0:.1f} s)")
    print(format_table([(k, p, r) for k, (p, r) in clips.items()]))
    if args.walkers > 0:
        if not REFERENCE.found:
            print(f"synthesized comparison skipped: {REFERENCE.reason}")
            return 0
        t0 = time.perf_counter()
        proc = simulate_walkers(MotionMatcher(load_databases(cache_dir=motion_cache_dir())), args.walkers, args.seconds, args.seed)
        real = simulate_walkers(MotionMatcher(build_databases_from_config(config, cache_dir=motion_cache_dir())), args.walkers, args.seconds, args.seed)
        print(f"\nsynthesized: {args.walkers} walkers, {args.seconds:g} s in Office, procedural vs real-mocap "
              f"databases ({time.perf_counter() - t0:.1f} s)")
        print(format_table([("walkers", proc, real)]))
    if args.facing_seconds > 0:
        dbs = load_databases(cache_dir=motion_cache_dir())
        print("\n" + facing_report(lambda: MotionMatcher(dbs), args.facing_runs, args.facing_seconds))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Effect of the foot IK filter (``storyteller.sim.body.foot_ik``) on the crowd measure of issue 4.

Runs the crowd scenario of ``tests/sim/motion/test_crowd_motion.py`` (its ``simulate_crowd`` and
``measure``, from ``storyteller.benchmark.support.crowd_walkers``) with a smaller crowd and the world's own leg IK turned
off (``WorldConfig(foot_ik=False)``), then applies ``FootSolver`` frame by frame to the
recorded buffers (pelvis, local rotations, contact flags: what the world step hands the
filter) and measures the filtered tracks the same way. Prints, before / after:
feet in boxes (ankle and toe joint-frames inside a floor-standing footprint), the deepest foot
graze (m), foot sliding (mean toe speed in contact,
m/s), the largest change of any pelvis position (must be 0) and of the upper body's local
rotations (must be 0), legs at full stretch (the IK's clamp),
the legs' joint speeds (p99, max: pops would show there), and the filter's cost per character-frame next to the world step's.

Usage: ``python -m storyteller.benchmark.foot_ik_effect [--walkers 20] [--seconds 20] [--seed 7]
[--off-grid 0.0] [--margin 0.03] [--max-drift 0.25] [--max-reach 0.99] [--release-frames 6]``.
"""

from __future__ import annotations

import argparse
import copy
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from storyteller.benchmark.support.crowd_walkers import measure, simulate_crowd
from storyteller.orchestrator.reference_data import locate_reference
from storyteller.sim.body.foot_ik import LEG_JOINTS, FootSolver
from storyteller.sim.body.leg_ik import SHIN_LENGTH, THIGH_LENGTH, leg_chain
from storyteller.sim.scene.files import load_scene


def _office() -> Path:
    """The reference Office scene (``STORYTELLER_REFERENCE``; see orchestrator/reference_data.py)."""
    reference = locate_reference()
    if not reference.found:
        raise SystemExit(reference.reason)
    return reference.path / "configs" / "scenes" / "Office"


def _stretched(pelvis: np.ndarray, rotations: np.ndarray, length: int) -> int:
    """Leg-frames (of the first ``length`` frames) with the ankle at the bones' full reach (the IK clamps there)."""
    chain = leg_chain(pelvis[:length].reshape(-1, 3), rotations[:length].reshape(-1, *rotations.shape[2:]))
    span = np.linalg.norm(chain.ankle - chain.hip, axis=-1)
    return int(np.sum(span > THIGH_LENGTH + SHIN_LENGTH - 1e-4))


def _joint_speed(rotations: NDArray[np.floating[Any]], length: int) -> NDArray[np.float64]:
    """Angular speeds (rad/s) of the hips', knees' and ankles' local rotations, frame to frame
    (the first ``length`` frames)."""
    legs = rotations[:length, :, list(LEG_JOINTS)].astype(float)
    rel = np.einsum("fnjba,fnjbc->fnjac", legs[:-1], legs[1:])
    speeds: NDArray[np.float64] = np.linalg.norm(Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_rotvec(), axis=-1) * 30.0
    return speeds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--walkers", type=int, default=20)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--off-grid", type=float, default=0.0)
    ap.add_argument("--margin", type=float, default=0.03)
    ap.add_argument("--max-drift", type=float, default=0.25)
    ap.add_argument("--max-reach", type=float, default=0.99)
    ap.add_argument("--release-frames", type=int, default=6)
    args = ap.parse_args()

    office = _office()
    from storyteller.orchestrator.cache_paths import motion_cache_dir
    from storyteller.sim.motion.database import load_databases
    from storyteller.sim.motion.matching import MotionMatcher

    if not office.exists():
        raise SystemExit(f"reference scene not found at {office}")
    scene = load_scene(office)
    frames = round(args.seconds * 30)
    t0 = time.perf_counter()
    world, before = simulate_crowd(scene, args.walkers, frames, args.seed,
                                         MotionMatcher(load_databases(cache_dir=motion_cache_dir())), off_grid=args.off_grid, foot_ik=False)
    t_world = time.perf_counter() - t0

    b = world.buffers.trimmed()
    solver = FootSolver.from_scene(scene, margin=args.margin, max_drift=args.max_drift,
                                  max_reach=args.max_reach,                                   release_frames=args.release_frames)
    state = solver.initial_state(len(world.names))
    filtered = b.rotations.copy()
    solver.apply(b.pelvis[0], b.rotations[0].astype(float), b.contacts[0], state)  # compiled kernels: load
    t0 = time.perf_counter()
    for f in range(b.length):
        rots, state = solver.apply(b.pelvis[f], b.rotations[f].astype(float), b.contacts[f], state)
        filtered[f] = rots
    t_ik = time.perf_counter() - t0

    after_world = copy.copy(world)
    after_buffers = b.trimmed()
    after_buffers.rotations = filtered
    after_world.buffers = after_buffers
    after = measure(after_world, scene, before.targets_given, before.targets_reached, before.failures)

    speed_before, speed_after = _joint_speed(b.rotations, b.length), _joint_speed(filtered, b.length)
    others = [j for j in range(filtered.shape[2]) if j not in LEG_JOINTS]
    pelvis_change = float(np.abs(after_buffers.pelvis[: b.length] - b.pelvis[: b.length]).max())
    upper_change = float(np.abs(filtered[: b.length, :, others] - b.rotations[: b.length, :, others]).max())

    print(f"crowd: {args.walkers} walkers, {frames} frames ({args.seconds:g} s), seed {args.seed}, "
          f"off-grid {args.off_grid} m; footprint margin {args.margin} m, max drift {args.max_drift} m, "
          f"max reach {args.max_reach}, "
          f"release {args.release_frames} frames; "
          f"{len(solver.footprints)} floor-standing footprints")
    print(f"{'measure':<34}{'before':>12}{'after':>12}")
    rows = [
        ("feet in boxes (joint-frames)", before.feet_in_boxes, after.feet_in_boxes, "d"),
        ("deepest foot graze (m)", before.feet_max_depth, after.feet_max_depth, ".4f"),
        ("foot sliding (m/s)", before.foot_sliding, after.foot_sliding, ".3f"),
        ("pelvis penetrations", before.pelvis_penetrations, after.pelvis_penetrations, "d"),
        ("legs at full stretch (leg-frames)", _stretched(b.pelvis, b.rotations, b.length),
         _stretched(b.pelvis, filtered, b.length), "d"),
        ("leg joint speed p99 (rad/s)", np.percentile(speed_before, 99), np.percentile(speed_after, 99), ".2f"),
        ("leg joint speed max (rad/s)", speed_before.max(), speed_after.max(), ".2f"),
        ("contact fraction", before.contact_fraction, after.contact_fraction, ".3f"),
    ]
    for name, x, y, fmt in rows:
        print(f"{name:<34}{x:>12{fmt}}{y:>12{fmt}}")
    print(f"max pelvis change (m): {pelvis_change:.3g}")
    print(f"max upper-body local rotation change: {upper_change:.3g}")
    cf = b.length * len(world.names)
    print(f"filter {1e6 * t_ik / cf:.1f} us per character-frame vs world step {1e6 * t_world / cf:.1f} us "
          f"(ratio {t_ik / t_world:.3f}; same run)")


if __name__ == "__main__":
    main()

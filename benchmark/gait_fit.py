"""``python -m storyteller.benchmark.gait_fit [--write | --with-bandai]``: fit the procedural walk to the real CMU walks.

Reads the CMU walks (``STORYTELLER_MOCAP``, else ``../shared/mocap``; never copied), imported on
our skeleton as every real clip is, and measures each walking window with the benchmark's own
measures (``storyteller.benchmark.motion_metrics.gait``: step length, bob, sway, arm swing, jerk) plus these:
bob oscillation (the pelvis height's standard deviation about its one-second moving average:
the benchmark's bob is the plain standard deviation, which in the real walks is mostly a slow
drift of 1-3 cm over a window, not the step's rise and fall), trunk twist (half the 5-95 % range
of the chest's yaw against the hips'), pelvis yaw (half that range of the hips' yaw against the
walking direction), foot lift (the ball of the foot's 5-95 % height range) and turn lean (the
trunk's sideways roll against ``atan(lateral acceleration / g)``, a least-squares gain).

The fit leaves out the walks of ``HELD_OUT`` and prints the generated walk against them (each
window against a walk generated at its speed), and against the Bandai Namco walks, which are a
check only: they are CC BY-NC 4.0, and nothing fitted on them may ship (issue 25);
``--with-bandai`` shows what a fit on them too would give and refuses ``--write``.

The targets: step length as a power law of speed (a straight line in log-log, Theil-Sen, so one
odd walk does not tilt it); arm swing, bob oscillation and trunk twist as straight lines against
speed (``SPEED_LINES``: the benchmark's least-squares line, so a walker at any speed the planner
asks for swings, bobs and twists as the real walkers do at that speed); the rest as means over
the windows (what that line gives at their mean speed: they do not grow with speed over
0.9-1.2 m/s beyond their scatter). Turn lean is printed per clip but not fitted: the
CMU walks turn too gently (lateral acceleration under 0.1 g) and their gains scatter on both
sides of zero, so the generator keeps the balance lean (gain 1: the body tilts so that gravity
and the turn's acceleration together point through the feet). Then the generator's parameters
(``storyteller.sim.motion.sources.gait_params.GaitParams``) are calibrated: walks and arcs are generated at
the real speeds, measured the same way, each amplitude scaled by target / measured and each
line's amplitude and slope moved by what the generated line misses, a few rounds (the step
length is set, not calibrated: the generator steps exactly as long as it is told, and the
measured one moves in whole frames of the step interval). Prints the targets, the fitted
parameters and the generated / real ratios before (the parameters the module holds now) and
after; ``--write`` stores the fitted parameters in ``sim/motion/sources/gait_params.py``
(between its FITTED markers). Deterministic; exit 2 when the real clips are absent.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.stats import theilslopes

from storyteller.benchmark.motion_metrics.gait import SpeedFit, fit_speed, gait_window, walking_windows
from storyteller.sim.body.skeleton import JOINT_INDEX
from storyteller.sim.motion.sources.gait_params import FITTED_GAIT, GaitParams
from storyteller.sim.motion.sources.procedural_locomotion import GRAVITY, locomotion_clip

CMU_WALKS = (
    ("cmu/daz/05_01.bvh", 1), ("cmu/daz/07_03.bvh", 1), ("cmu/daz/07_06.bvh", 1), ("cmu/daz/08_08.bvh", 1),
    ("cmu/daz/16_15.bvh", 1), ("cmu/daz/16_31.bvh", 1), ("cmu/max/131_01.bvh", 0), ("cmu/max/131_02.bvh", 0),
    ("cmu/mb_motionedit/16_11.bvh", 0),
)  # fmt: skip
"""(file under the mocap folder, first frame) of every CMU walk (16_11 veers left 40 degrees)."""
HELD_OUT = ("cmu/mb_motionedit/16_11.bvh",)
"""CMU walks left out of the fit, to check that it carries over: 16_11 is the one walk of another
conversion (the MotionBuilder skeleton) and the one that curves. Chosen before any fit was run."""
SPEED_LINES = {"arm_swing": "arm_swing", "bob_oscillation": "bob_dip", "trunk_twist": "trunk_twist"}
"""Measures fitted as a straight line against speed (least squares over the fitting windows), by
the generator parameter (``<name>_1ms`` or ``trunk_twist``, and ``<name>_speed_slope``) they set."""
DIP_STD = 0.36
"""Standard deviation of the pelvis height per metre of ``bob_dip`` (the squared raised cosine's
0.364, in phase with the legs' own rise and fall): the additive step of the dip's calibration."""
PARAMS_FILE = Path(__file__).resolve().parents[1] / "sim" / "motion" / "sources" / "gait_params.py"
FPS = 30.0
ROUNDS = 6
J = JOINT_INDEX
MEASURES = ("step_length", "cadence", "bob", "bob_oscillation", "sway", "arm_swing", "trunk_twist", "pelvis_yaw", "foot_lift", "jerk")
CALIBRATED = {  # generator parameter -> the measure it is scaled by (the SPEED_LINES are apart)
    "sway_amplitude": "sway", "pelvis_yaw": "pelvis_yaw", "foot_clearance": "foot_lift",
}  # fmt: skip


def _yaw(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    d = a[:, :2] - b[:, :2]
    return np.asarray(np.arctan2(d[:, 1], d[:, 0]))


def _half_range(x: NDArray[np.float64]) -> float:
    return float(np.percentile(x, 95) - np.percentile(x, 5)) / 2.0


def _wrap(x: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray((x + np.pi) % (2 * np.pi) - np.pi)


def _moving_average(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """One-second moving average (edges padded) of ``x`` (F, ...)."""
    k = int(FPS) | 1
    pad = np.pad(x, ((k // 2, k // 2),) + ((0, 0),) * (x.ndim - 1), mode="edge")
    flat = pad.reshape(len(pad), -1)
    out = np.stack([np.convolve(flat[:, i], np.ones(k) / k, mode="valid") for i in range(flat.shape[1])], axis=-1)
    return np.asarray(out.reshape((len(x), *x.shape[1:])))


def _travel(j: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Walking direction (F,) rad and speed (F,) m/s of the pelvis's one-second moving average."""
    d = np.gradient(_moving_average(j[:, 0, :2]), axis=0) * FPS
    return np.unwrap(np.arctan2(d[:, 1], d[:, 0])), np.linalg.norm(d, axis=-1)


def window_measures(j: NDArray[np.float64]) -> dict[str, float]:
    """Every measure of ``MEASURES`` (and speed) of one walking window of joints (F, 22, 3)."""
    w = gait_window(j, FPS)
    hips = _yaw(j[:, J["left_hip"]], j[:, J["right_hip"]])
    chest = _yaw(j[:, J["left_shoulder"]], j[:, J["right_shoulder"]])
    direction, _ = _travel(j)
    feet = j[:, [J["left_foot"], J["right_foot"]], 2]
    return {
        "speed": w.speed, "step_length": w.step_length, "cadence": w.cadence, "bob": w.bob,
        "bob_oscillation": float(np.std(j[:, 0, 2] - _moving_average(j[:, 0, 2]))), "sway": w.sway,
        "arm_swing": w.arm_swing, "jerk": w.jerk,
        "trunk_twist": _half_range(_wrap(chest - hips)),
        "pelvis_yaw": _half_range(_wrap(hips - direction - np.pi / 2)),
        "foot_lift": float(np.mean(np.percentile(feet, 95, axis=0) - np.percentile(feet, 5, axis=0))),
    }  # fmt: skip


def lean_samples(j: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(atan(lateral acceleration / g), trunk roll into the turn) per frame, both rad."""
    direction, speed = _travel(j)
    turn = np.gradient(direction) * FPS
    trunk = j[:, J["neck"]] - j[:, 0]
    side = np.stack([-np.sin(direction), np.cos(direction)], axis=-1)  # left of the walking direction
    roll = np.arctan2(np.sum(trunk[:, :2] * side, axis=-1), trunk[:, 2])
    return np.arctan(speed * turn / GRAVITY), roll


@dataclass(frozen=True)
class Walks:
    """The measured windows (one dict each) and the lean samples of a set of walks."""

    windows: tuple[dict[str, float], ...]
    accel: NDArray[np.float64]
    roll: NDArray[np.float64]

    def lean_gain(self) -> float:
        """Least-squares gain of roll on atan(a / g) (0 when nothing turns)."""
        den = float(np.sum(self.accel**2))
        return float(np.sum(self.accel * self.roll) / den) if den > 0 else 0.0


def measure_walks(motions: Sequence[NDArray[np.float64]]) -> Walks:
    windows, acc, roll = [], [], []
    for j in motions:
        for a, b in walking_windows(("walk",) * len(j), j[:, 0, :2], FPS):
            windows.append(window_measures(j[a:b]))
            x, y = lean_samples(j[a:b])
            acc.append(x)
            roll.append(y)
    return Walks(tuple(windows), _joined(acc), _joined(roll))


def _joined(parts: list[NDArray[np.float64]]) -> NDArray[np.float64]:
    return np.concatenate(parts) if parts else np.zeros(0)


def real_walks() -> tuple[list[NDArray[np.float64]], list[str]]:
    """World joints (F, 22, 3) of every CMU walk on our floor, and their names (held-out ones too)."""
    from storyteller.benchmark.motion_metrics.sources import on_floor
    from storyteller.benchmark.motion_quality import MOCAP
    from storyteller.orchestrator.cache_paths import motion_cache_dir
    from storyteller.sim.motion.config import ClipEntry, MotionConfig, import_entry

    if not MOCAP.found:
        raise FileNotFoundError(f"real clips: {MOCAP.reason}")
    config = MotionConfig(root=str(MOCAP.path), clips=tuple(ClipEntry(file=f, label="walk", start=s) for f, s in CMU_WALKS))
    clips = [import_entry(config, e, motion_cache_dir()) for e in config.clips]
    return [on_floor(c.joint_positions()) for c in clips], [Path(e.file).stem for e in config.clips]


def bandai_walks() -> Walks:
    """The Bandai Namco walks (``storyteller.benchmark.motion_metrics.sources``; empty when absent), measured."""
    from storyteller.benchmark.motion_metrics.sources import real_clips as benchmark_clips

    run, _ = benchmark_clips()
    return measure_walks([c.joints for c in run.characters if c.name.startswith("dataset-")])


@dataclass(frozen=True)
class Targets:
    """What the generated walk should measure: step length ``scale * v ** exponent``, the rest
    one value each, and the turn lean gain (the balance lean, not fitted: see the module doc)."""

    step_scale: float
    step_exponent: float
    values: dict[str, float]
    lean_gain: float
    speeds: tuple[float, ...]
    lines: dict[str, SpeedFit]
    """The ``SPEED_LINES`` measures against speed (the benchmark's least-squares line)."""


def fit_targets(real: Walks) -> Targets:
    speeds = np.array([w["speed"] for w in real.windows])
    steps = np.array([w["step_length"] for w in real.windows])
    ok = np.isfinite(steps) & (steps > 0)
    slope, _, _, _ = theilslopes(np.log(steps[ok]), np.log(speeds[ok]))
    exponent = float(np.clip(slope, 0.2, 0.9))  # a stride that grows with speed, not faster than it
    scale = float(np.exp(np.median(np.log(steps[ok]) - exponent * np.log(speeds[ok]))))
    values = {m: float(np.nanmean([w[m] for w in real.windows])) for m in MEASURES}
    speed_set = tuple(float(s) for s in np.percentile(speeds, [10, 50, 90]))
    return Targets(scale, exponent, values, 1.0, speed_set, speed_lines(real))


def speed_lines(walks: Walks) -> dict[str, SpeedFit]:
    """The least-squares line against speed of each ``SPEED_LINES`` measure over ``walks``' windows."""
    speeds = [w["speed"] for w in walks.windows]
    return {m: fit_speed(speeds, [w[m] for w in walks.windows]) for m in SPEED_LINES}


def _line_update(p: GaitParams, got: dict[str, SpeedFit], want: dict[str, SpeedFit]) -> dict[str, float]:
    """New values of the ``SPEED_LINES`` parameters: amplitude (the line at 1 m/s) and slope each
    moved by what the measured line misses, through the measured gain of the amplitude (the dip of
    the bob through ``DIP_STD``)."""
    out: dict[str, float] = {}
    for m, name in SPEED_LINES.items():
        g, t = got[m], want[m]
        at, slope = (name + "_1ms", name + "_speed_slope") if name != "trunk_twist" else (name, name + "_speed_slope")
        g1, t1 = g.intercept + g.slope, t.intercept + t.slope
        if name == "bob_dip":
            out[at] = getattr(p, at) + (t1 - g1) / DIP_STD
            out[slope] = getattr(p, slope) + (t.slope - g.slope) / DIP_STD
            continue
        if g1 > 0 and getattr(p, at) > 0:  # moved by what is missing, through the gain g1 / amplitude
            gain = g1 / getattr(p, at)
            out[at] = getattr(p, at) + (t1 - g1) / gain
            out[slope] = getattr(p, slope) + (t.slope - g.slope) / gain
    return out


def generated_walks(params: GaitParams, speeds: Sequence[float]) -> Walks:
    """Straight walks at ``speeds`` and arcs (radius 3 m and 1.5 m at the middle speed),
    generated with ``params``, world joints measured like the real ones."""
    from storyteller.sim.motion.sources.procedural_locomotion import _const

    def joints(v: float, turn: float) -> NDArray[np.float64]:
        clip = locomotion_clip("fit", _const(v), _const(turn), 6.0, params=params)
        return np.asarray(clip.joint_positions())

    straight = measure_walks([joints(v, 0.0) for v in speeds])
    v = float(np.median(speeds))
    arcs = measure_walks([joints(v, sign * v / r) for r in (3.0, 1.5) for sign in (1.0, -1.0)])
    return Walks(straight.windows, arcs.accel, arcs.roll)


def generated_values(walks: Walks) -> dict[str, float]:
    return {m: float(np.nanmedian([w[m] for w in walks.windows])) for m in MEASURES}


def calibrate(start: GaitParams, targets: Targets) -> GaitParams:
    """Scale each amplitude by target / measured, ``ROUNDS`` times (lean gain by its own ratio)."""
    p = dataclasses.replace(start, step_length_exponent=round(targets.step_exponent, 4),
                            step_length_1ms=round(targets.step_scale, 4))
    for _ in range(ROUNDS):
        walks = generated_walks(p, targets.speeds)
        got = generated_values(walks)
        update = {name: getattr(p, name) * targets.values[m] / got[m]
                  for name, m in CALIBRATED.items() if np.isfinite(got[m]) and got[m] > 0}
        gain = walks.lean_gain()
        if gain > 0:
            update["turn_lean_gain"] = p.turn_lean_gain * targets.lean_gain / gain
        update.update(_line_update(p, speed_lines(walks), targets.lines))
        p = dataclasses.replace(p, **{k: round(float(v), 4) for k, v in update.items()})
    return p


def ratio_rows(params: GaitParams, targets: Targets) -> dict[str, float]:
    walks = generated_walks(params, targets.speeds)
    got = generated_values(walks)
    out = {m: got[m] / targets.values[m] for m in MEASURES}
    out["turn_lean"] = walks.lean_gain() / targets.lean_gain if targets.lean_gain > 0 else float("nan")
    lines = speed_lines(walks)
    for m, line in targets.lines.items():
        out[f"{m}_slope"] = lines[m].slope / line.slope if line.slope else float("nan")
    return out


def held_out_rows(params: GaitParams, held: Walks) -> dict[str, float]:
    """Per measure, the median over ``held``'s windows of generated / real, each window against a
    straight walk generated at its own speed."""
    from storyteller.sim.motion.sources.procedural_locomotion import _const

    gen = []
    for w in held.windows:
        j = np.asarray(locomotion_clip("held", _const(w["speed"]), _const(0.0), 6.0, params=params).joint_positions())
        gen.append(measure_walks([j]).windows[0])
    return {m: float(np.nanmedian([g[m] / r[m] for g, r in zip(gen, held.windows, strict=True) if r[m] > 0]))
            for m in ("cadence", "step_length", "bob", "bob_oscillation", "arm_swing", "trunk_twist", "jerk")}


def write_params(params: GaitParams, path: Path = PARAMS_FILE) -> None:
    """Replace the FITTED block of ``gait_params.py`` with ``params``."""
    text = path.read_text(encoding="utf-8")
    fields = "".join(f"    {f.name}={getattr(params, f.name)!r},\n" for f in dataclasses.fields(params))
    block = f"FITTED_GAIT = GaitParams(\n{fields})\n"
    begin = text.find("# BEGIN FITTED")
    line_end = text.find("\n", begin) if begin >= 0 else -1
    end = text.find("# END FITTED", line_end) if line_end >= 0 else -1
    if end < 0 or text.count("# BEGIN FITTED") != 1:
        raise ValueError(f"{path}: no FITTED block to replace")
    path.write_text(text[: line_end + 1] + block + text[end:], encoding="utf-8")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m storyteller.benchmark.gait_fit", description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="store the fitted parameters in gait_params.py")
    parser.add_argument("--with-bandai", action="store_true",
                        help="fit on the Bandai Namco walks too, to see what that would give (CC BY-NC 4.0: nothing"
                             " fitted on them may ship, so --write is refused with it)")
    args = parser.parse_args(argv)
    if args.write and args.with_bandai:
        print("error: --with-bandai fits on CC BY-NC clips, whose fitted parameters may not ship; drop --write",
              file=sys.stderr)
        return 2
    try:
        motions, names = real_walks()
    except FileNotFoundError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    held_names = {Path(f).stem for f in HELD_OUT}
    fit_set = [(j, n) for j, n in zip(motions, names, strict=True) if n not in held_names]
    bandai = bandai_walks()
    real = measure_walks([j for j, _ in fit_set])
    if args.with_bandai:
        real = Walks(real.windows + bandai.windows, real.accel, real.roll)
    held = measure_walks([j for j, n in zip(motions, names, strict=True) if n in held_names])
    targets = fit_targets(real)
    gains = [f"{name} {measure_walks([j]).lean_gain():+.2f}" for j, name in fit_set if measure_walks([j]).windows]
    print(f"real walks: {len(fit_set)} CMU clips ({', '.join(n for _, n in fit_set)})"
          f"{' and the Bandai Namco walks' if args.with_bandai else ''}, {len(real.windows)} walking windows, "
          f"speeds {min(w['speed'] for w in real.windows):.2f}-{max(w['speed'] for w in real.windows):.2f} m/s")
    print(f"targets: step length {targets.step_scale:.3f} m * v^{targets.step_exponent:.2f} (cadence "
          f"{60 / targets.step_scale:.1f} steps/min * v^{1 - targets.step_exponent:.2f}); turn lean gain "
          f"{targets.lean_gain:.2f} (balance lean; the real walks' own: {', '.join(gains)}); measured at {', '.join(f'{s:.2f}' for s in targets.speeds)} m/s")
    for m in MEASURES:
        print(f"  {m:12s} {targets.values[m]:8.4f}")
    for m, line in targets.lines.items():
        print(f"  {m + ' line':12s} {line.intercept + line.slope:8.4f} at 1 m/s, {line.slope:+.4f} per m/s")
    before = FITTED_GAIT
    after = calibrate(before, targets)
    print("\nfitted parameters (before -> after)")
    for f in dataclasses.fields(after):
        print(f"  {f.name:22s} {getattr(before, f.name):8.4f} -> {getattr(after, f.name):8.4f}")
    rb, ra = ratio_rows(before, targets), ratio_rows(after, targets)
    print("\ngenerated / real        before    after")
    for m in rb:
        print(f"  {m:20s} {rb[m]:7.2f}x {ra[m]:7.2f}x")
    checks = [(f"held out ({', '.join(sorted(held_names))}, {len(held.windows)} windows)", held)]
    if not args.with_bandai:
        checks.append((f"Bandai Namco walks (CC BY-NC: a check only, never fitted; {len(bandai.windows)} windows)", bandai))
    for title, walks in checks:
        if not walks.windows:
            continue
        hb, ha = held_out_rows(before, walks), held_out_rows(after, walks)
        print(f"\ngenerated / {title}, at each window's speed   before    after")
        for m in hb:
            print(f"  {m:20s} {hb[m]:7.2f}x {ha[m]:7.2f}x")
    if args.write:
        write_params(after)
        print(f"\n-> {PARAMS_FILE}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

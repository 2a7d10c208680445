"""Walking measured against the real walks at the same speed.

A *walking window* is a stretch of frames labelled ``walk`` (the locomotion database key)
whose pelvis moves faster than ``MIN_SPEED`` m/s, with ``TRIM_S`` seconds cut at each end
(starts and stops are not the gait) and cut into pieces of at most ``WINDOW_S`` seconds (the
speed stays about constant within one). Each window gets:

- from :func:`storyteller.benchmark.motion_quality.motion_stats` (the project's measures, not re-made
  here): jerk (median |d^3 x / dt^3| over joints, m/s^3), speed (m/s) and bob (standard
  deviation of the pelvis height, m);
- cadence (steps/min) from the median interval between foot-strikes (:func:`step_cadence`),
  the strikes from :func:`foot_contacts` (the same rule for generated and real motion);
- sway: standard deviation of the pelvis's sideways offset from its one-second moving-average
  path (m);
- arm swing: the wrists' fore-aft range (5th to 95th percentile) relative to the pelvis along
  the walking direction, the mean of both wrists (m);
- step length: speed over steps per second (m).

A foot is planted (:func:`foot_contacts`) when its ball is near its lowest height and slow, with
flicker shorter than ``CONTACT_MIN_S`` removed, so a step is counted once.

Real figures at the generated window's speed come from a straight line fitted to the real
windows (metric against speed; the mean when their speeds span less than 0.2 m/s), evaluated
at that speed clamped to the real speeds' range.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import binary_closing, binary_opening

from storyteller.benchmark.motion_quality import motion_stats
from storyteller.sim.body.skeleton import JOINT_INDEX

WALK_LABEL = "walk"
MIN_SPEED = 0.3  # m/s
TRIM_S = 0.5
WINDOW_S = 4.0
MIN_WINDOW_S = 1.5
CONTACT_SPEED = 0.3  # m/s: a foot slower than this, low enough, is planted
CONTACT_ABOVE_LOWEST = 0.05  # m above the foot's lowest height in the window
CONTACT_MIN_S = 0.1  # s: shorter contacts and gaps between contacts are flicker, not steps
GAIT_METRICS = ("speed", "cadence", "step_length", "bob", "sway", "arm_swing", "jerk")
UNITS = {"speed": "m/s", "cadence": "steps/min", "step_length": "m", "bob": "m", "sway": "m",
         "arm_swing": "m", "jerk": "m/s^3"}
FEET = (JOINT_INDEX["left_foot"], JOINT_INDEX["right_foot"])
WRISTS = (JOINT_INDEX["left_wrist"], JOINT_INDEX["right_wrist"])


def label_runs(labels: Sequence[str], label: str) -> list[tuple[int, int]]:
    """(first, end) frame ranges (end exclusive) of the runs of ``label`` in ``labels``."""
    out: list[tuple[int, int]] = []
    start: int | None = None
    for i, lab in enumerate([*labels, None]):
        if lab == label and start is None:
            start = i
        elif lab != label and start is not None:
            out.append((start, i))
            start = None
    return out


def walking_windows(labels: Sequence[str], pelvis_xy: NDArray[np.float64], fps: float) -> list[tuple[int, int]]:
    """The walking windows (first, end) of a track (see the module docstring)."""
    xy = np.asarray(pelvis_xy, dtype=np.float64)
    speed = np.linalg.norm(np.gradient(xy, axis=0), axis=-1) * fps if len(xy) > 1 else np.zeros(len(xy))
    fast = [lab == WALK_LABEL and s > MIN_SPEED for lab, s in zip(labels, speed, strict=True)]
    trim, longest, shortest = round(TRIM_S * fps), round(WINDOW_S * fps), round(MIN_WINDOW_S * fps)
    out: list[tuple[int, int]] = []
    for a, b in label_runs(["w" if f else "" for f in fast], "w"):
        a, b = a + trim, b - trim
        pieces = max(1, int(np.ceil((b - a) / longest)))
        edges = np.linspace(a, b, pieces + 1).round().astype(int)
        out.extend((int(lo), int(hi)) for lo, hi in pairwise(edges) if hi - lo >= shortest)
    return out


def foot_contacts(joints: NDArray[np.float64], fps: float) -> NDArray[np.bool_]:
    """(F, 2) planted feet: the ball of the foot within ``CONTACT_ABOVE_LOWEST`` of its lowest
    height in the motion and slower than ``CONTACT_SPEED`` horizontally."""
    feet = np.asarray(joints, dtype=np.float64)[:, list(FEET)]
    low = feet[..., 2] < feet[..., 2].min(axis=0) + CONTACT_ABOVE_LOWEST
    speed = np.linalg.norm(np.gradient(feet[..., :2], axis=0), axis=-1) * fps
    raw = low & (speed < CONTACT_SPEED)
    k = max(1, round(CONTACT_MIN_S * fps))
    out = np.zeros_like(raw)
    for side in range(raw.shape[1]):  # fill gaps shorter than k frames, then drop contacts shorter than k
        filled = binary_closing(raw[:, side], structure=np.ones(k, dtype=bool), border_value=0) | raw[:, side]
        out[:, side] = binary_opening(filled, structure=np.ones(k, dtype=bool))
    return np.asarray(out)


def step_cadence(contacts: NDArray[np.bool_], fps: float) -> float:
    """Steps per minute from the median interval between successive foot-strikes (either
    foot; nan with fewer than two). ``motion_stats``' onsets per minute is biased in a window of
    a few steps (one step more or less is 20% of a 3-second window), so cadence is taken here
    from the step interval instead."""
    c = np.asarray(contacts, dtype=bool)
    onsets = np.sort(np.concatenate([np.flatnonzero(c[1:, s] & ~c[:-1, s]) + 1 for s in range(c.shape[1])]))
    if len(onsets) < 2:
        return float("nan")
    return float(60.0 * fps / np.median(np.diff(onsets)))


def _travel_frame(pelvis_xy: NDArray[np.float64], fps: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The one-second moving average of the pelvis path (F, 2) and its unit direction (F, 2)."""
    k = max(1, round(fps)) | 1
    pad = np.pad(pelvis_xy, ((k // 2, k // 2), (0, 0)), mode="edge")
    kernel = np.ones(k) / k
    mean = np.stack([np.convolve(pad[:, i], kernel, mode="valid") for i in range(2)], axis=-1)
    d = np.gradient(mean, axis=0)
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    return mean, d / np.maximum(norm, 1e-9)


def sway(pelvis_xy: NDArray[np.float64], fps: float) -> float:
    """Standard deviation (m) of the pelvis's sideways offset from its averaged path."""
    xy = np.asarray(pelvis_xy, dtype=np.float64)
    mean, fwd = _travel_frame(xy, fps)
    side = np.stack([-fwd[:, 1], fwd[:, 0]], axis=-1)
    return float(np.std(np.sum((xy - mean) * side, axis=-1)))


def arm_swing(joints: NDArray[np.float64], fps: float) -> float:
    """Mean over both wrists of their fore-aft range (m) relative to the pelvis."""
    j = np.asarray(joints, dtype=np.float64)
    _, fwd = _travel_frame(j[:, 0, :2], fps)
    ranges = []
    for w in WRISTS:
        along = np.sum((j[:, w, :2] - j[:, 0, :2]) * fwd, axis=-1)
        ranges.append(float(np.percentile(along, 95) - np.percentile(along, 5)))
    return float(np.mean(ranges))


@dataclass(frozen=True)
class GaitWindow:
    """One walking window's figures (see ``GAIT_METRICS`` and ``UNITS``)."""

    frames: int
    speed: float
    cadence: float
    step_length: float
    bob: float
    sway: float
    arm_swing: float
    jerk: float

    def value(self, metric: str) -> float:
        return float(getattr(self, metric))


def gait_window(joints: NDArray[np.float64], fps: float) -> GaitWindow:
    """The figures of one window of world joints (F, 22, 3)."""
    j = np.asarray(joints, dtype=np.float64)
    contacts = foot_contacts(j, fps)
    stats = motion_stats(j, j[:, 0, :2], contacts, fps)
    cadence = step_cadence(contacts, fps)
    steps_per_s = cadence / 60.0
    return GaitWindow(
        frames=len(j), speed=stats.speed, cadence=cadence,
        step_length=stats.speed / steps_per_s if steps_per_s > 0 else float("nan"),
        bob=stats.bob, sway=sway(j[:, 0, :2], fps), arm_swing=arm_swing(j, fps), jerk=stats.jerk,
    )


def track_windows(joints: NDArray[np.float64], labels: Sequence[str], fps: float) -> list[GaitWindow]:
    """Every walking window of one track."""
    j = np.asarray(joints, dtype=np.float64)
    return [gait_window(j[a:b], fps) for a, b in walking_windows(labels, j[:, 0, :2], fps)]


@dataclass(frozen=True)
class SpeedFit:
    """A metric against speed over the real windows: ``value(speed)``."""

    slope: float
    intercept: float
    lo: float
    hi: float

    def value(self, speed: float) -> float:
        return self.intercept + self.slope * float(np.clip(speed, self.lo, self.hi))


def fit_speed(speeds: Sequence[float], values: Sequence[float]) -> SpeedFit:
    """A line through (speed, value) pairs (finite ones), flat when speeds span < 0.2 m/s."""
    s, v = np.asarray(speeds, dtype=float), np.asarray(values, dtype=float)
    ok = np.isfinite(s) & np.isfinite(v)
    s, v = s[ok], v[ok]
    if len(s) == 0:
        return SpeedFit(0.0, float("nan"), 0.0, 0.0)
    if np.ptp(s) < 0.2:
        return SpeedFit(0.0, float(v.mean()), float(s.min()), float(s.max()))
    slope, intercept = np.polyfit(s, v, 1)
    return SpeedFit(float(slope), float(intercept), float(s.min()), float(s.max()))


@dataclass(frozen=True)
class GaitComparison:
    """Per metric: median generated value, median real value at the generated speeds, and the
    median of the per-window ratios generated / real."""

    windows: int
    generated: dict[str, float]
    real: dict[str, float]
    ratio: dict[str, float]


def compare_gait(generated: Sequence[GaitWindow], real: Sequence[GaitWindow]) -> GaitComparison:
    """Generated windows against the real ones at the same speed (see the module docstring)."""
    nan = float("nan")
    if not generated or not real:
        empty = dict.fromkeys(GAIT_METRICS, nan)
        return GaitComparison(len(generated), empty, dict(empty), dict(empty))
    gen, ref, ratio = {}, {}, {}
    for m in GAIT_METRICS:
        fit = fit_speed([w.speed for w in real], [w.value(m) for w in real])
        g = np.array([w.value(m) for w in generated])
        r = np.array([w.speed if m == "speed" else fit.value(w.speed) for w in generated])
        if m == "speed":  # the real speed at which the others compare: clamped to the real range
            r = np.clip(r, min(w.speed for w in real), max(w.speed for w in real))
        ok = np.isfinite(g) & np.isfinite(r) & (np.abs(r) > 1e-12)
        gen[m] = float(np.nanmedian(g)) if np.isfinite(g).any() else nan
        ref[m] = float(np.median(r[ok])) if ok.any() else nan
        ratio[m] = float(np.median(g[ok] / r[ok])) if ok.any() else nan
    return GaitComparison(len(generated), gen, ref, ratio)


SPEED_BINS = (0.3, 0.7, 1.0, 1.3, 1.8)


def cadence_by_speed(windows: Sequence[GaitWindow]) -> list[tuple[str, int, float, float]]:
    """(speed bin, windows, median cadence, median step length) per ``SPEED_BINS`` bin."""
    out = []
    for lo, hi in pairwise(SPEED_BINS):
        inside = [w for w in windows if lo <= w.speed < hi]
        cad = float(np.nanmedian([w.cadence for w in inside])) if inside else float("nan")
        step = float(np.nanmedian([w.step_length for w in inside])) if inside else float("nan")
        out.append((f"{lo:.1f}-{hi:.1f}", len(inside), cad, step))
    return out

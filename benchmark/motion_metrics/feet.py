"""Feet against the floor: foot skating ratio (GMD's definition), floor penetration and float.

Foot skating follows the definition of GMD (Karunratanakul et al., 2023) as the text-to-motion
papers report it: the motion resampled to 20 fps, a frame *skates* when a foot joint (SMPL's
``left_foot`` / ``right_foot``, the ball of the foot) is lower than 5 cm above the floor in that
frame and the previous one and moves more than 2.5 cm horizontally between them (0.5 m/s);
the ratio is skating frames over frames with a previous frame. Real data scores 0.0; published
text-to-motion models 0.05-0.11.

Floor penetration and float read the lowest of the four foot joints (ankles and balls of the
feet) every frame: below the floor is penetration, above it float (millimetres). The joints
are joint centres, not the skin: a planted ball of the foot of our skeleton stands about
10 mm above the floor, so float is best read as a ratio to the real clips on the same skeleton.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import JOINT_INDEX

GMD_FPS = 20.0
"""Frames per second at which the skating ratio is evaluated (HumanML3D's rate)."""
CONTACT_HEIGHT_M = 0.05
"""A foot joint lower than this above the floor is taken to be on it."""
SKATE_STEP_M = 0.025
"""Horizontal metres a foot on the floor may move from one 20 fps frame to the next."""
FOOT_JOINTS = (JOINT_INDEX["left_foot"], JOINT_INDEX["right_foot"])
LOW_JOINTS = (JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"], *FOOT_JOINTS)


def resample(values: NDArray[np.float64], fps: float, new_fps: float) -> NDArray[np.float64]:
    """``values`` (F, ...) sampled at ``fps`` linearly resampled at ``new_fps`` over the same
    time span (first sample kept; the last new sample at or before the last old one)."""
    a = np.asarray(values, dtype=np.float64)
    if len(a) < 2:
        return a.copy()
    span = (len(a) - 1) / fps
    t = np.arange(int(np.floor(span * new_fps + 1e-9)) + 1) / new_fps
    x = np.minimum(t * fps, len(a) - 1)
    i0 = np.minimum(np.floor(x).astype(np.int64), len(a) - 2)
    w = (x - i0).reshape((-1,) + (1,) * (a.ndim - 1))
    return np.asarray(a[i0] * (1.0 - w) + a[i0 + 1] * w)


@dataclass(frozen=True)
class Skating:
    """Skating frames and frames counted (pool several motions by adding both)."""

    skating: int
    frames: int

    @property
    def ratio(self) -> float:
        return self.skating / self.frames if self.frames else float("nan")

    def __add__(self, other: Skating) -> Skating:
        return Skating(self.skating + other.skating, self.frames + other.frames)


def skating_frames(feet: NDArray[np.float64], floor_z: float = 0.0) -> NDArray[np.bool_]:
    """Per frame pair (F - 1,): whether a foot of ``feet`` (F, K, 3), already at 20 fps, lower
    than ``CONTACT_HEIGHT_M`` in both frames moved more than ``SKATE_STEP_M`` horizontally."""
    f = np.asarray(feet, dtype=np.float64)
    low = f[..., 2] - floor_z < CONTACT_HEIGHT_M
    on_floor = low[1:] & low[:-1]
    moved = np.linalg.norm(np.diff(f[..., :2], axis=0), axis=-1) > SKATE_STEP_M
    return np.asarray((on_floor & moved).any(axis=-1))


def foot_skating(joints: NDArray[np.float64], fps: float, floor_z: float = 0.0) -> Skating:
    """GMD's foot skating of one motion ``joints`` (F, 22, 3) sampled at ``fps``."""
    feet = resample(np.asarray(joints, dtype=np.float64)[:, list(FOOT_JOINTS)], fps, GMD_FPS)
    if len(feet) < 2:
        return Skating(0, 0)
    flags = skating_frames(feet, floor_z)
    return Skating(int(flags.sum()), int(flags.size))


def lowest_foot_height(joints: NDArray[np.float64], floor_z: float = 0.0) -> NDArray[np.float64]:
    """Per frame (F,): height above the floor of the lowest ankle or ball-of-foot joint (m)."""
    return np.asarray(np.asarray(joints, dtype=np.float64)[:, list(LOW_JOINTS), 2].min(axis=1) - floor_z)


@dataclass(frozen=True)
class FloorContact:
    """Penetration (below the floor) and float (above it) of the lowest foot joint, mm."""

    frames: int
    penetration_mean: float
    penetration_max: float
    penetrating_share: float  # share of frames with the lowest foot joint below the floor
    float_median: float
    float_p95: float


def floor_contact(heights: NDArray[np.float64]) -> FloorContact:
    """Figures of lowest-foot heights (F,) in metres (from :func:`lowest_foot_height`), pooled."""
    h = np.asarray(heights, dtype=np.float64) * 1000.0
    if h.size == 0:
        nan = float("nan")
        return FloorContact(0, nan, nan, nan, nan, nan)
    pen, flo = np.maximum(-h, 0.0), np.maximum(h, 0.0)
    return FloorContact(
        frames=int(h.size),
        penetration_mean=float(pen.mean()),
        penetration_max=float(pen.max()),
        penetrating_share=float(np.mean(h < 0.0)),
        float_median=float(np.median(flo)),
        float_p95=float(np.percentile(flo, 95)),
    )

"""Motion-matching feature vectors per action family.

A feature vector has a *pose* part, computed from joint positions and velocities in the
character frame (x forward, y left, z up, origin at the root's ground point), and a
*control* part that says where the character should go or what it acts on:

- locomotion: feet, pelvis and spine3 positions and velocities (pose) + root positions and
  facing directions 10, 20 and 30 frames ahead (control);
- sitting (and seated variants): pelvis height, pelvis velocity, feet positions (pose) +
  seat position, seat facing and seat height (control);
- partner: pelvis velocity, feet and wrist positions (pose) + partner position and facing;
- in_place / idle: wrist positions and velocities, head and feet positions (pose) + object
  position (control).

Units: metres, metres per second, unit direction vectors. The layout of each family is a
tuple of (group name, size); its sum is asserted where vectors are assembled.
``future_from_path`` samples a planned path at the control part's future frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import JOINT_INDEX
from storyteller.sim.motion.action_labels import family_of, is_seated_key

J = JOINT_INDEX
FUTURE_FRAMES = (10, 20, 30)

Layout = tuple[tuple[str, int], ...]
LayoutName = Literal["locomotion", "sitting", "seated", "partner", "in_place", "idle"]
FEATURE_LAYOUTS: dict[LayoutName, Layout] = {
    "locomotion": (
        ("left_foot_pos", 3), ("right_foot_pos", 3), ("left_foot_vel", 3), ("right_foot_vel", 3),
        ("pelvis_pos", 3), ("spine3_pos", 3), ("pelvis_vel", 3), ("spine3_vel", 3), ("future_pos", 6),
        ("future_dir", 6),
    ),
    "sitting": (
        ("pelvis_height", 1), ("pelvis_vel", 3), ("left_foot_pos", 3), ("right_foot_pos", 3),
        ("target_pos", 2), ("target_dir", 2), ("target_height", 1),
    ),
    "partner": (
        ("pelvis_vel", 3), ("left_foot_pos", 3), ("right_foot_pos", 3), ("left_wrist_pos", 3),
        ("right_wrist_pos", 3), ("target_pos", 2), ("target_dir", 2),
    ),
    "in_place": (
        ("left_wrist_pos", 3), ("right_wrist_pos", 3), ("left_wrist_vel", 3), ("right_wrist_vel", 3),
        ("head_pos", 3), ("left_foot_pos", 3), ("right_foot_pos", 3), ("target_pos", 2),
    ),
}
FEATURE_LAYOUTS["idle"] = FEATURE_LAYOUTS["in_place"]
# Seated actions (sit_idle, drink@seated...): the seat as control, the hands as pose.
FEATURE_LAYOUTS["seated"] = (
    ("pelvis_height", 1), ("left_wrist_pos", 3), ("right_wrist_pos", 3), ("left_wrist_vel", 3),
    ("right_wrist_vel", 3), ("head_pos", 3), ("left_foot_pos", 3), ("right_foot_pos", 3),
    ("target_pos", 2), ("target_dir", 2), ("target_height", 1),
)


def layout_for_key(key: str) -> LayoutName:
    """Feature layout of a database key: its family's, or ``seated`` for seated actions."""
    if is_seated_key(key) or key == "sit_idle":
        return "seated"
    return family_of(key)
CONTROL_GROUPS = frozenset({"future_pos", "future_dir", "target_pos", "target_dir", "target_height"})
DEFAULT_WEIGHTS: dict[str, float] = {
    "future_pos": 1.5, "future_dir": 1.5, "target_pos": 1.5, "target_dir": 1.0, "target_height": 1.0,
    "pelvis_pos": 0.5, "spine3_pos": 0.5,
}


def layout_size(layout: Layout) -> int:
    return sum(size for _, size in layout)


@dataclass(frozen=True)
class FeatureConfig:
    """Weights per feature group (missing groups weigh 1.0)."""

    weights: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_WEIGHTS))

    def weight(self, group: str) -> float:
        return float(self.weights.get(group, 1.0))

    def vector(self, layout: Layout) -> NDArray[np.float64]:
        return np.concatenate([np.full(size, self.weight(name)) for name, size in layout])


@dataclass(frozen=True)
class Control:
    """Control inputs (character frame), batched over leading dims.

    future_pos (...,3,2) root positions ahead; future_dir (...,3,2) unit facing ahead;
    target_pos (...,2) target ground point; target_dir (...,2) unit target facing;
    target_height (...,) seat height. Unused entries may be zeros.
    """

    future_pos: NDArray[np.float64]
    future_dir: NDArray[np.float64]
    target_pos: NDArray[np.float64]
    target_dir: NDArray[np.float64]
    target_height: NDArray[np.float64]


def _group(name: str, pos: NDArray[np.float64], vel: NDArray[np.float64], control: Control) -> NDArray[np.float64]:
    joint_groups = {
        "left_foot": J["left_foot"], "right_foot": J["right_foot"], "pelvis": J["pelvis"],
        "spine3": J["spine3"], "left_wrist": J["left_wrist"], "right_wrist": J["right_wrist"],
        "head": J["head"],
    }
    if name == "pelvis_height":
        return pos[..., J["pelvis"], 2:3]
    if name == "future_pos":
        return control.future_pos.reshape(*control.future_pos.shape[:-2], 6)
    if name == "future_dir":
        return control.future_dir.reshape(*control.future_dir.shape[:-2], 6)
    if name == "target_pos":
        return control.target_pos
    if name == "target_dir":
        return control.target_dir
    if name == "target_height":
        return control.target_height[..., None]
    joint, kind = name.rsplit("_", 1)
    src = pos if kind == "pos" else vel
    return src[..., joint_groups[joint], :]


def assemble(family: LayoutName, pos: NDArray[np.float64], vel: NDArray[np.float64], control: Control) -> NDArray[np.float64]:
    """Raw (unnormalised) feature vectors (..., D) from character-frame joint positions and
    velocities (..., 22, 3) and control inputs."""
    layout = FEATURE_LAYOUTS[family]
    parts = [_group(name, pos, vel, control) for name, _ in layout]
    out = np.concatenate(parts, axis=-1)
    assert out.shape[-1] == layout_size(layout), (family, out.shape)
    return out


def to_character_frame(points: NDArray[np.float64], root_xy: NDArray[np.float64], heading: NDArray[np.float64]) -> NDArray[np.float64]:
    """World points (..., K, 3) -> character frame of roots (..., 2) / headings (...)."""
    c, s = np.cos(heading)[..., None], np.sin(heading)[..., None]
    dx = points[..., 0] - root_xy[..., None, 0]
    dy = points[..., 1] - root_xy[..., None, 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy, points[..., 2]], axis=-1)


def vectors_to_character_frame(vec: NDArray[np.float64], heading: NDArray[np.float64]) -> NDArray[np.float64]:
    """World vectors (..., K, 3) rotated into the character frame of ``heading`` (...)."""
    c, s = np.cos(heading)[..., None], np.sin(heading)[..., None]
    return np.stack([c * vec[..., 0] + s * vec[..., 1], -s * vec[..., 0] + c * vec[..., 1], vec[..., 2]], axis=-1)


def relative_target(
    root_xy: NDArray[np.float64], heading: NDArray[np.float64], target_xy: NDArray[np.float64], target_facing: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Target ground point (..., 2) and unit facing (..., 2) in the character frame."""
    c, s = np.cos(heading), np.sin(heading)
    d = target_xy - root_xy
    pos = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)
    rel = target_facing - heading
    return pos, np.stack([np.cos(rel), np.sin(rel)], axis=-1)


def future_from_path(path_xy: NDArray[np.float64], frame_speed: float, heading: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Planned future root points (3,2) and headings (3,) from a polyline path (K,2) starting
    at the character, walked at ``frame_speed`` metres per frame (e.g. 1.0 / 30)."""
    path = np.asarray(path_xy, dtype=np.float64).reshape(-1, 2)
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    pts, hds = [], []
    for k in FUTURE_FRAMES:
        s = min(k * frame_speed, float(cum[-1]))
        x, y = np.interp(s, cum, path[:, 0]), np.interp(s, cum, path[:, 1])
        i = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, max(len(seg) - 1, 0)))
        if len(seg) and seg[i] > 1e-9 and s < cum[-1] - 1e-9:
            d = path[i + 1] - path[i]
            hds.append(float(np.arctan2(d[1], d[0])))
        else:
            hds.append(hds[-1] if hds else float(heading))
        pts.append((x, y))
    return np.array(pts), np.array(hds)

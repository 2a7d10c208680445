"""The motion clip: frames of an SMPL-X body pose with root trajectory and foot contacts.

A clip is the unit that importers and the procedural generators produce and motion
databases are built from. Positions are metres in the z-up world; frames are sampled at
``fps`` (30 for everything that enters a database).

The *root* is the character's ground trajectory: a smoothed projection of the pelvis on the
floor (``root_xy``) and the direction the character faces (``heading``, radians, world yaw
measured from +x toward +y). The pelvis itself may sway around the root; the body pose is
``local_rotations`` with joint 0 the pelvis rotation in the world. ``foot_sliding`` measures
how far the toes slide while their foot is in contact.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from storyteller.sim.body.skeleton import JOINT_INDEX, NUM_JOINTS, forward_kinematics

FPS = 30.0
FOOT_JOINTS = (JOINT_INDEX["left_foot"], JOINT_INDEX["right_foot"])
ANKLE_JOINTS = (JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"])


class MotionClipError(ValueError):
    """A clip whose arrays are inconsistent or not finite."""


@dataclass(frozen=True)
class MotionClip:
    """One clip. F frames.

    local_rotations (F,22,3,3); pelvis (F,3) world metres; root_xy (F,2); heading (F,) rad;
    contacts (F,2) bool for the left/right foot (toe joint on the ground and still);
    target (4,) = [x, y, facing, height] of the clip's interaction target in the clip's world
    (a seat: seated pelvis ground point, facing and seat height; a partner or object: its
    ground point and facing; NaN when the clip has none); loops: the last frame continues
    into the first.
    """

    name: str
    key: str
    local_rotations: NDArray[np.float64]
    pelvis: NDArray[np.float64]
    root_xy: NDArray[np.float64]
    heading: NDArray[np.float64]
    contacts: NDArray[np.bool_]
    loops: bool = False
    target: NDArray[np.float64] = field(default_factory=lambda: np.full(4, np.nan))
    fps: float = FPS
    source: str = "procedural"

    def __post_init__(self) -> None:
        n = self.local_rotations.shape[0]
        shapes = {
            "local_rotations": (self.local_rotations, (n, NUM_JOINTS, 3, 3)),
            "pelvis": (self.pelvis, (n, 3)),
            "root_xy": (self.root_xy, (n, 2)),
            "heading": (self.heading, (n,)),
            "contacts": (self.contacts, (n, 2)),
            "target": (self.target, (4,)),
        }
        for name, (arr, shape) in shapes.items():
            if arr.shape != shape:
                raise MotionClipError(f"clip {self.name!r}: {name} has shape {arr.shape}, expected {shape}")
            if name not in ("target", "contacts") and not np.all(np.isfinite(arr)):
                raise MotionClipError(f"clip {self.name!r}: {name} has non-finite values")
        if n < 2:
            raise MotionClipError(f"clip {self.name!r}: needs at least 2 frames, has {n}")

    def _replace_key(self, key: str) -> MotionClip:
        """The same frames filed under another database key."""
        return MotionClip(self.name, key, self.local_rotations, self.pelvis, self.root_xy, self.heading,
                          self.contacts, self.loops, self.target, self.fps, self.source)

    @property
    def num_frames(self) -> int:
        return int(self.local_rotations.shape[0])

    def joint_positions(self) -> NDArray[np.float64]:
        """World joint positions (F,22,3) by forward kinematics."""
        return forward_kinematics(self.local_rotations, self.pelvis)[0]


def estimate_root(
    pelvis: NDArray[np.float64], pelvis_rotation: NDArray[np.float64], smooth_frames: float = 4.0
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Root trajectory of a clip: smoothed pelvis ground point (F,2) and heading (F,) rad.

    The heading is the pelvis' forward axis (body +z) projected on the floor, unwrapped and
    smoothed with a Gaussian of ``smooth_frames`` standard deviation.
    """
    # imported here: 0.03 s, and only building clips (a motion cache miss) needs it
    from scipy.ndimage import gaussian_filter1d

    fwd = pelvis_rotation[:, :, 2]
    heading = np.unwrap(np.arctan2(fwd[:, 1], fwd[:, 0]))
    root = pelvis[:, :2]
    if smooth_frames > 0 and len(heading) > 1:
        heading = gaussian_filter1d(heading, smooth_frames, mode="nearest")
        root = gaussian_filter1d(root, smooth_frames, axis=0, mode="nearest")
    return root, heading


def detect_contacts(
    positions: NDArray[np.float64], fps: float, height: float = 0.06, speed: float = 0.25
) -> NDArray[np.bool_]:
    """Foot contacts (F,2): toe joint lower than ``height`` above the clip's lowest toe
    height and slower than ``speed`` m/s horizontally."""
    toes = positions[:, FOOT_JOINTS]
    floor = np.percentile(toes[:, :, 2], 2)
    vel = np.gradient(toes[:, :, :2], axis=0) * fps
    slow: NDArray[np.bool_] = np.linalg.norm(vel, axis=-1) < speed
    return (toes[:, :, 2] < floor + height) & slow


def resample_rotations(rotations: NDArray[np.float64], src_fps: float, dst_fps: float) -> NDArray[np.float64]:
    """Slerp (F,J,3,3) rotations from ``src_fps`` to ``dst_fps`` (same start time)."""
    n, nj = rotations.shape[:2]
    t_src = np.arange(n) / src_fps
    t_dst = np.arange(int(np.floor(t_src[-1] * dst_fps + 1e-9)) + 1) / dst_fps
    out = np.empty((len(t_dst), nj, 3, 3))
    for j in range(nj):
        out[:, j] = Slerp(t_src, Rotation.from_matrix(rotations[:, j]))(t_dst).as_matrix()
    return out


def resample_linear(values: NDArray[np.float64], src_fps: float, dst_fps: float) -> NDArray[np.float64]:
    """Linear resampling of (F,...) values along the first axis."""
    n = values.shape[0]
    t_src = np.arange(n) / src_fps
    t_dst = np.arange(int(np.floor(t_src[-1] * dst_fps + 1e-9)) + 1) / dst_fps
    flat = values.reshape(n, -1)
    out = np.stack([np.interp(t_dst, t_src, flat[:, k]) for k in range(flat.shape[1])], axis=1)
    return out.reshape(len(t_dst), *values.shape[1:])


def clip_from_pose_frames(
    name: str,
    key: str,
    local_rotations: NDArray[np.float64],
    pelvis: NDArray[np.float64],
    fps: float = FPS,
    *,
    source: str = "imported",
    loops: bool = False,
    target: NDArray[np.float64] | None = None,
) -> MotionClip:
    """Build a clip at 30 fps from raw pose frames (any fps): resample, estimate the root
    trajectory and detect contacts."""
    if abs(fps - FPS) > 1e-6:
        local_rotations = resample_rotations(local_rotations, fps, FPS)
        pelvis = resample_linear(pelvis, fps, FPS)
    root, heading = estimate_root(pelvis, local_rotations[:, 0])
    positions = forward_kinematics(local_rotations, pelvis)[0]
    contacts = detect_contacts(positions, FPS)
    tgt = np.full(4, np.nan) if target is None else np.asarray(target, dtype=np.float64)
    return MotionClip(name, key, local_rotations, pelvis, root, heading, contacts, loops, tgt, FPS, source)


def foot_sliding(joint_positions: NDArray[np.float64], contacts: NDArray[np.bool_], fps: float = FPS) -> float:
    """Mean horizontal speed (m/s) of the toe joints over frames where that foot is in
    contact in both the frame and the next; 0.0 when there is no such frame."""
    toes = np.asarray(joint_positions)[:, FOOT_JOINTS, :2]
    speed = np.linalg.norm(np.diff(toes, axis=0), axis=-1) * fps
    c = np.asarray(contacts, dtype=bool)
    both = c[1:] & c[:-1]
    return float(speed[both].mean()) if both.any() else 0.0

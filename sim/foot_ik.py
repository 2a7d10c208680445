"""Leg IK after motion matching: feet kept out of furniture, planted feet pinned.

The world puts each pelvis exactly on its planned path (a disc clear of furniture) and motion
matching picks the body pose, so a stride can reach into the footprint of a chair or a table
and a planted foot slides with the root. ``FootSolver.apply`` is a per-frame filter over all
characters that moves only the feet, with the legs' local rotations:

1. *pinning*: a foot flagged in contact is locked where its toe is when the contact starts
   (the foot keeps the animation's world orientation, so it rolls about the pinned toe); the
   lock is released when the contact ends, or while in contact when the lock drifts more than
   ``max_drift`` from the animated toe, and the foot then blends back to the animation over
   ``release_frames`` frames (a smoothstep on the offset it had at the release);
2. *clearance*: the foot (ankle and toe joints, as one rigid piece) is moved horizontally out
   of every floor-standing footprint grown by ``margin``, by the shortest shift that clears
   all of them (``push_out``);
3. *two-bone IK* on hip-knee-ankle reaches the ankle target: the knee bends in the animated
   leg's plane (for a straight leg, in the plane that bends the knee towards the body's
   front), then the leg swings to the target with the smallest rotation; the ankle's local
   rotation is recomputed so the foot keeps its world orientation. An unreachable target
   stretches the leg towards it (or folds it as far as the bones allow).

Only the local rotations of hips, knees and ankles change; the pelvis position and every other
joint's local rotation are returned untouched, and a foot that is neither locked, blending nor
pushed keeps its exact input rotations. ``apply`` is a pure function of its inputs and the
state it returns (plain arrays in a frozen dataclass), so world snapshots can copy it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from sim.motion_clips import ANKLE_JOINTS, FOOT_JOINTS
from sim.scene import Scene
from sim.skeleton import JOINT_INDEX, NUM_JOINTS, REST_OFFSETS, forward_kinematics

__all__ = [
    "HIP_JOINTS",
    "KNEE_JOINTS",
    "LEG_JOINTS",
    "FootIKError",
    "FootSolver",
    "FootState",
    "Footprints",
    "push_out",
    "solve_legs",
    "two_bone_ik",
]

HIP_JOINTS = (JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"])
KNEE_JOINTS = (JOINT_INDEX["left_knee"], JOINT_INDEX["right_knee"])
LEG_JOINTS = (*HIP_JOINTS, *KNEE_JOINTS, *ANKLE_JOINTS)
THIGH_LENGTH = np.linalg.norm(REST_OFFSETS[list(KNEE_JOINTS)], axis=-1)  # (2,) left, right
SHIN_LENGTH = np.linalg.norm(REST_OFFSETS[list(ANKLE_JOINTS)], axis=-1)
_BODY_RIGHT = np.array([-1.0, 0.0, 0.0])  # body frame: +x is the body's left


class FootIKError(ValueError):
    """Input the foot solver cannot use (wrong shapes, non-finite values, state mismatch)."""


# ----- footprints and the clearance push ----------------------------------------------------
@dataclass(frozen=True)
class Footprints:
    """Oriented xy boxes: centres, unit right / facing axes (B, 2) and half sizes (B, 2)
    (along right, along facing), already grown by the margin."""

    centers: np.ndarray
    rights: np.ndarray
    facings: np.ndarray
    halves: np.ndarray

    @classmethod
    def from_scene(cls, scene: Scene, margin: float, floor_support: float = 0.10) -> Footprints:
        """The footprints of the objects standing on the floor (bottom within
        ``floor_support`` of ``scene.floor_z``), each grown by ``margin`` metres."""
        objs = [o for o in scene.objects if o.z_min - scene.floor_z < floor_support]
        if not objs:
            empty = np.zeros((0, 2))
            return cls(empty, empty.copy(), empty.copy(), empty.copy())
        return cls(
            centers=np.array([o.center_xy for o in objs], dtype=float),
            rights=np.array([o.right for o in objs], dtype=float),
            facings=np.array([o.facing for o in objs], dtype=float),
            halves=np.array([[o.width / 2 + margin, o.depth / 2 + margin] for o in objs], dtype=float),
        )

    def __len__(self) -> int:
        return len(self.centers)


@njit(cache=True)
def _depth(x: float, y: float, centers: np.ndarray, rights: np.ndarray, facings: np.ndarray,
           halves: np.ndarray, b: int) -> float:  # pragma: no cover - compiled
    """How deep (m) point (x, y) is inside box ``b`` (<= 0: outside or on its edge)."""
    dx = x - centers[b, 0]
    dy = y - centers[b, 1]
    lx = dx * rights[b, 0] + dy * rights[b, 1]
    ly = dx * facings[b, 0] + dy * facings[b, 1]
    return min(halves[b, 0] - abs(lx), halves[b, 1] - abs(ly))


@njit(cache=True)
def _penetration(points: np.ndarray, m: int, sx: float, sy: float, centers: np.ndarray,
                 rights: np.ndarray, facings: np.ndarray, halves: np.ndarray) -> float:  # pragma: no cover - compiled
    """Summed depth of foot ``m``'s points, shifted by (sx, sy), inside all boxes."""
    total = 0.0
    for b in range(centers.shape[0]):
        for p in range(points.shape[1]):
            d = _depth(points[m, p, 0] + sx, points[m, p, 1] + sy, centers, rights, facings, halves, b)
            if d > 0.0:
                total += d
    return total


@njit(cache=True)
def _push_out_kernel(points: np.ndarray, centers: np.ndarray, rights: np.ndarray, facings: np.ndarray,
                     halves: np.ndarray, passes: int) -> np.ndarray:  # pragma: no cover - compiled
    m_count = points.shape[0]
    shift = np.zeros((m_count, 2))
    for m in range(m_count):
        sx = 0.0
        sy = 0.0
        for _ in range(passes):
            if _penetration(points, m, sx, sy, centers, rights, facings, halves) <= 0.0:
                break
            best_pen = np.inf
            best_len = np.inf
            bx = sx
            by = sy
            for b in range(centers.shape[0]):
                inside = False
                for p in range(points.shape[1]):
                    if _depth(points[m, p, 0] + sx, points[m, p, 1] + sy, centers, rights, facings, halves, b) > 0.0:
                        inside = True
                if not inside:
                    continue
                for side in range(4):
                    axis = side // 2
                    sign = 1.0 if side % 2 == 0 else -1.0
                    ax = rights[b, 0] if axis == 0 else facings[b, 0]
                    ay = rights[b, 1] if axis == 0 else facings[b, 1]
                    need = 0.0  # move along sign*axis until every inside point leaves box b
                    for p in range(points.shape[1]):
                        x = points[m, p, 0] + sx
                        y = points[m, p, 1] + sy
                        if _depth(x, y, centers, rights, facings, halves, b) > 0.0:
                            loc = (x - centers[b, 0]) * ax + (y - centers[b, 1]) * ay
                            need = max(need, halves[b, axis] - sign * loc)
                    cx = sx + sign * ax * need
                    cy = sy + sign * ay * need
                    pen = _penetration(points, m, cx, cy, centers, rights, facings, halves)
                    length = np.hypot(cx, cy)
                    if pen < best_pen - 1e-12 or (pen <= best_pen + 1e-12 and length < best_len):
                        best_pen = pen
                        best_len = length
                        bx = cx
                        by = cy
            sx = bx
            sy = by
        shift[m, 0] = sx
        shift[m, 1] = sy
    return shift


def push_out(points: np.ndarray, footprints: Footprints, passes: int = 4) -> np.ndarray:
    """Horizontal shifts (M, 2) that move each rigid group of points (M, P, 2) out of every
    footprint: each pass tries, for every box the group is in, the four sides' exits and keeps
    the one leaving the least summed depth inside all boxes (then the shortest); a group that
    cannot be cleared in ``passes`` passes keeps the best shift found."""
    pts = np.ascontiguousarray(points, dtype=float)
    if pts.ndim != 3 or pts.shape[2] != 2:
        raise FootIKError(f"points must be (M, P, 2), got {pts.shape}")
    if len(footprints) == 0 or len(pts) == 0:
        return np.zeros((len(pts), 2))
    return _push_out_kernel(pts, footprints.centers, footprints.rights, footprints.facings,
                            footprints.halves, int(passes))


# ----- two-bone IK -------------------------------------------------------------------------
def _unit(v: np.ndarray, eps: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    n = np.linalg.norm(v, axis=-1)
    return v / np.maximum(n, eps)[..., None], n


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def _axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) about unit axes (..., 3) by angles (...,) (Rodrigues)."""
    k = np.zeros((*axis.shape[:-1], 3, 3))
    k[..., 0, 1], k[..., 0, 2] = -axis[..., 2], axis[..., 1]
    k[..., 1, 0], k[..., 1, 2] = axis[..., 2], -axis[..., 0]
    k[..., 2, 0], k[..., 2, 1] = -axis[..., 1], axis[..., 0]
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def _perpendicular(v: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to each unit vector v (..., 3)."""
    e = np.zeros_like(v)
    idx = np.argmin(np.abs(v), axis=-1)
    np.put_along_axis(e, idx[..., None], 1.0, axis=-1)
    return _unit(np.cross(v, e))[0]


def _swing(a: np.ndarray, b: np.ndarray, flip_axis: np.ndarray) -> np.ndarray:
    """Smallest rotations (..., 3, 3) taking unit vectors a to unit vectors b; for opposite
    vectors a half turn about ``flip_axis`` made perpendicular to a."""
    axis, s = _unit(np.cross(a, b))
    c = np.clip(_dot(a, b), -1.0, 1.0)
    angle = np.arctan2(s, c)
    opposite = (s < 1e-9) & (c < 0.0)
    if np.any(opposite):
        f = flip_axis - _dot(flip_axis, a)[..., None] * a
        f, fn = _unit(f)
        f = np.where((fn > 1e-9)[..., None], f, _perpendicular(a))
        axis = np.where(opposite[..., None], f, axis)
    return _axis_angle(axis, angle)


def two_bone_ik(hip: np.ndarray, knee: np.ndarray, ankle: np.ndarray, hip_rot: np.ndarray,
                knee_rot: np.ndarray, target: np.ndarray, bend_normal: np.ndarray,
                thigh: np.ndarray, shin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """New world rotations (hip, knee) (M, 3, 3) putting the ankle on ``target`` (M, 3).

    hip, knee, ankle: joint world positions (M, 3); hip_rot, knee_rot: their world rotations;
    bend_normal (M, 3): the fallback knee hinge axis for a straight leg (the body's right for a
    knee bending forward); thigh, shin: bone lengths (M,). The knee's interior angle is set by
    the law of cosines with a rotation about the leg plane's normal, then the leg swings about
    the hip onto the target direction. The reach is clamped to the bones' range."""
    kh = hip - knee
    ka = ankle - knee
    e1, _ = _unit(kh)
    n_raw = np.cross(kh, ka)
    fb = bend_normal - _dot(bend_normal, e1)[..., None] * e1
    fb, fbn = _unit(fb)
    fb = np.where((fbn > 1e-6)[..., None], fb, _perpendicular(e1))
    # the animated plane unless the leg is straight (|sin| < ~1e-3): then the fallback hinge
    n, _ = _unit(n_raw + (1e-3 * thigh * shin)[..., None] * fb)
    e2 = np.cross(n, e1)
    c1, c2 = _dot(ka, e1), _dot(ka, e2)
    phi0 = np.arctan2(c2, c1)
    in_plane = np.maximum(np.hypot(c1, c2), 1e-12)

    d, dist = _unit(target - hip)
    d = np.where((dist > 1e-9)[..., None], d, _unit(ankle - hip)[0])
    lo = np.abs(thigh - shin) + 1e-6
    hi = thigh + shin - 1e-6
    reach = np.clip(dist, lo, hi)
    cos_knee = (thigh**2 + shin**2 - reach**2) / (2.0 * thigh * shin)
    phi1 = np.arccos(np.clip(shin * cos_knee / in_plane, -1.0, 1.0))
    bend = _axis_angle(n, phi1 - phi0)
    ankle1 = knee + np.einsum("...ij,...j->...i", bend, ka)
    swing = _swing(_unit(ankle1 - hip)[0], d, n)
    return swing @ hip_rot, swing @ bend @ knee_rot


# ----- the per-frame filter ----------------------------------------------------------------
@dataclass(frozen=True)
class FootState:
    """Per character and foot (N, 2, ...): ``locked`` feet and their pinned toe position
    ``lock`` (world, m); ``offset`` (toe, m) being blended out over ``release`` more frames
    after a release; ``drifted``: released for drift during this contact (no relock until the
    blend is over or the contact ends)."""

    locked: np.ndarray
    lock: np.ndarray
    offset: np.ndarray
    release: np.ndarray
    drifted: np.ndarray

    @classmethod
    def initial(cls, n: int) -> FootState:
        return cls(
            locked=np.zeros((n, 2), dtype=bool),
            lock=np.zeros((n, 2, 3)),
            offset=np.zeros((n, 2, 3)),
            release=np.zeros((n, 2), dtype=np.int64),
            drifted=np.zeros((n, 2), dtype=bool),
        )

    @property
    def characters(self) -> int:
        return int(self.locked.shape[0])


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


class FootSolver:
    """Keeps feet out of floor-standing footprints and pins planted feet (see the module doc).

    ``FootSolver.from_scene(scene)``, then per frame
    ``rots, state = solver.apply(pelvis, rots, contacts, state)`` starting from
    ``solver.initial_state(n)``."""

    def __init__(self, footprints: Footprints, *, max_drift: float = 0.15, release_frames: int = 6,
                 passes: int = 4) -> None:
        if max_drift <= 0 or release_frames < 0 or passes < 1:
            raise FootIKError(
                f"need max_drift > 0, release_frames >= 0 and passes >= 1, got {max_drift}, "
                f"{release_frames}, {passes}")
        self.footprints = footprints
        self.max_drift = float(max_drift)
        self.release_frames = int(release_frames)
        self.passes = int(passes)

    @classmethod
    def from_scene(cls, scene: Scene, *, margin: float = 0.03, floor_support: float = 0.10,
                   max_drift: float = 0.15, release_frames: int = 6) -> FootSolver:
        """A solver for ``scene``'s floor-standing objects, footprints grown by ``margin`` m."""
        if margin < 0:
            raise FootIKError(f"margin must be >= 0 m, got {margin}")
        return cls(Footprints.from_scene(scene, margin, floor_support), max_drift=max_drift,
                   release_frames=release_frames)

    @staticmethod
    def initial_state(n: int) -> FootState:
        return FootState.initial(n)

    def apply(self, pelvis: np.ndarray, rots: np.ndarray, contacts: np.ndarray, state: FootState,
              active: np.ndarray | None = None) -> tuple[np.ndarray, FootState]:
        """One frame for N characters.

        pelvis (N, 3) world positions (unchanged), rots (N, 22, 3, 3) local rotations (joint 0
        in world), contacts (N, 2) left/right foot contact flags, state from the previous frame
        (or ``initial_state(N)``); ``active`` (N,) bool, default all: an inactive character's
        feet are neither pinned nor pushed (a held lock is released smoothly). Returns the new
        local rotations (a copy; only hips, knees and ankles differ) and the new state."""
        pelvis = np.asarray(pelvis, dtype=float)
        rots = np.asarray(rots, dtype=float)
        contacts = np.asarray(contacts)
        n = len(pelvis)
        if pelvis.shape != (n, 3) or rots.shape != (n, NUM_JOINTS, 3, 3) or contacts.shape != (n, 2):
            raise FootIKError(
                f"need pelvis (N, 3), rots (N, {NUM_JOINTS}, 3, 3), contacts (N, 2); got "
                f"{pelvis.shape}, {rots.shape}, {contacts.shape}")
        if state.characters != n:
            raise FootIKError(f"state holds {state.characters} characters, the frame has {n}")
        if not (np.isfinite(pelvis).all() and np.isfinite(rots).all()):
            raise FootIKError("pelvis and rotations must be finite")
        act = np.ones(n, dtype=bool) if active is None else np.asarray(active, dtype=bool).reshape(n)
        contact = contacts.astype(bool) & act[:, None]

        pos, glob = forward_kinematics(rots, pelvis)
        toe = pos[:, FOOT_JOINTS]  # (N, 2, 3)
        ankle = pos[:, ANKLE_JOINTS]
        foot = toe - ankle  # the foot keeps its animated world orientation

        # pinning: release, blend, lock
        drift = np.linalg.norm(state.lock - toe, axis=-1)
        lost = state.locked & ~contact
        drifted_now = state.locked & contact & (drift > self.max_drift)
        released = lost | drifted_now
        offset = np.where(released[..., None], state.lock - toe, state.offset)
        release = np.where(released, self.release_frames,
                           np.where(state.locked, 0, np.maximum(state.release - 1, 0)))
        locked = state.locked & ~released
        drifted = (state.drifted | drifted_now) & contact & (release > 0)
        weight = _smoothstep(release / self.release_frames) if self.release_frames > 0 else np.zeros(release.shape)
        offset = np.where((release > 0)[..., None], offset, 0.0)
        target = np.where(locked[..., None], state.lock, toe + offset * weight[..., None])

        # clearance: the rigid foot (ankle, toe) out of every footprint, horizontally
        shift = np.zeros((n, 2, 2))
        if len(self.footprints) and act.any():
            pts = np.stack([target - foot, target], axis=2)[act][..., :2]  # (A, 2 feet, 2 points, 2)
            shift[act] = push_out(pts.reshape(-1, 2, 2), self.footprints, self.passes).reshape(-1, 2, 2)
        target = target.copy()
        target[..., :2] += shift

        start = contact & ~locked & ~drifted
        lock = np.where(start[..., None], target, state.lock)
        locked = locked | start
        release = np.where(start, 0, release)
        offset = np.where(start[..., None], 0.0, offset)
        new_state = FootState(locked=locked, lock=np.where(locked[..., None], lock, 0.0),
                              offset=offset, release=release, drifted=drifted)

        moved = np.linalg.norm(target - toe, axis=-1) > 0.0
        return _solve(pos, glob, rots, target - foot, moved), new_state


def _solve(pos: np.ndarray, glob: np.ndarray, rots: np.ndarray, ankle_targets: np.ndarray,
           which: np.ndarray) -> np.ndarray:
    """``solve_legs`` on a pose whose forward kinematics (pos, glob) is already known."""
    out = rots.copy()
    if not which.any():
        return out
    ci, leg = np.nonzero(which)
    hips = np.array(HIP_JOINTS)[leg]
    knees = np.array(KNEE_JOINTS)[leg]
    ankles = np.array(ANKLE_JOINTS)[leg]
    right = glob[ci, 0] @ _BODY_RIGHT
    hip_rot, knee_rot = two_bone_ik(
        pos[ci, hips], pos[ci, knees], pos[ci, ankles], glob[ci, hips], glob[ci, knees],
        ankle_targets[ci, leg], right, THIGH_LENGTH[leg], SHIN_LENGTH[leg])
    out[ci, hips] = np.swapaxes(glob[ci, 0], -1, -2) @ hip_rot
    out[ci, knees] = np.swapaxes(hip_rot, -1, -2) @ knee_rot
    out[ci, ankles] = np.swapaxes(knee_rot, -1, -2) @ glob[ci, ankles]
    return out


def solve_legs(pelvis: np.ndarray, rots: np.ndarray, ankle_targets: np.ndarray,
               which: np.ndarray | None = None) -> np.ndarray:
    """Local rotations (N, 22, 3, 3) with the ankles of the legs ``which`` (N, 2) bool
    (default all) on ``ankle_targets`` (N, 2, 3) (world, m; left, right), the feet keeping their
    world orientation; other joints and legs keep their input rotations exactly."""
    pelvis = np.asarray(pelvis, dtype=float)
    rots = np.asarray(rots, dtype=float)
    targets = np.asarray(ankle_targets, dtype=float)
    n = len(pelvis)
    if pelvis.shape != (n, 3) or rots.shape != (n, NUM_JOINTS, 3, 3) or targets.shape != (n, 2, 3):
        raise FootIKError(
            f"need pelvis (N, 3), rots (N, {NUM_JOINTS}, 3, 3), ankle_targets (N, 2, 3); got "
            f"{pelvis.shape}, {rots.shape}, {targets.shape}")
    if not (np.isfinite(pelvis).all() and np.isfinite(rots).all() and np.isfinite(targets).all()):
        raise FootIKError("pelvis, rotations and ankle targets must be finite")
    mask = np.ones((n, 2), dtype=bool) if which is None else np.asarray(which, dtype=bool).reshape(n, 2)
    pos, glob = forward_kinematics(rots, pelvis)
    return _solve(pos, glob, rots, targets, mask)

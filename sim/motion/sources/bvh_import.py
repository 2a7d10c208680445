"""BVH import: parse any BVH skeleton and retarget it onto our 22-joint SMPL-X body.

Steps: parse the hierarchy and motion (channel order per joint); forward kinematics in the
source skeleton; map source joints to ours by name (automatic aliases for the common CMU,
Daz, 3ds Max and Mixamo-style namings, overridable); find the source's axes from its rest
pose (left = left hip - right hip, up = head - pelvis) so y-up and z-up files both work;
transfer each mapped joint's global rotation with a fixed rest-pose correction that aligns
our bone direction with the source's; scale root motion by the leg-length ratio; put the
lowest toe on the floor; resample to 30 fps.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from storyteller.sim.body.skeleton import (
    BODY_TO_WORLD,
    JOINT_INDEX,
    JOINT_NAMES,
    NUM_JOINTS,
    PARENTS,
    forward_kinematics,
    rest_positions,
)
from storyteller.sim.bounded_files import BoundedFileError, read_bounded_bytes
from storyteller.sim.motion.clips import FOOT_JOINTS, MotionClip, clip_from_pose_frames
from storyteller.sim.motion.sources.procedural_rig import TOE_HEIGHT

MAX_MOCAP_FILE_BYTES = 64 * 1024 * 1024
"""Bytes of one mocap clip file (BVH or AMASS ``.npz``; the CMU BVH files are under 4 MB, a long AMASS sequence tens of MB)."""
MAX_MOCAP_ARRAY_BYTES = 256 * 1024 * 1024
"""Bytes the arrays of one AMASS ``.npz`` may unpack to (declared sizes, checked before inflating)."""


class MocapImportError(ValueError):
    """A mocap file that cannot be imported; names the file and what is wrong."""

    def __init__(self, path: str | Path, message: str) -> None:
        super().__init__(f"{path}: {message}")
        self.path = str(path)


@dataclass(frozen=True)
class BvhData:
    """A parsed BVH file. J joints (End Sites excluded), N frames.

    names, parents (-1 for the root), offsets (J,3) in file units, channels per joint,
    end_offsets: End Site offset per joint (or None), frames (N, total channels), frame_time (s).
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: NDArray[np.float64]
    channels: tuple[tuple[str, ...], ...]
    end_offsets: tuple[NDArray[np.float64] | None, ...]
    frames: NDArray[np.float64]
    frame_time: float

    def global_transforms(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Source FK: global rotations (N,J,3,3) and positions (N,J,3) in file units/axes."""
        n, nj = len(self.frames), len(self.names)
        rot = np.empty((n, nj, 3, 3))
        pos = np.empty((n, nj, 3))
        col = 0
        for j in range(nj):
            chans = self.channels[j]
            vals = self.frames[:, col : col + len(chans)]
            col += len(chans)
            rot_axes = [c[0].upper() for c in chans if c.lower().endswith("rotation")]
            rot_cols = [i for i, c in enumerate(chans) if c.lower().endswith("rotation")]
            local = (Rotation.from_euler("".join(rot_axes), vals[:, rot_cols], degrees=True).as_matrix()
                     if rot_axes else np.broadcast_to(np.eye(3), (n, 3, 3)))
            trans = np.broadcast_to(self.offsets[j], (n, 3)).copy()
            for i, c in enumerate(chans):  # a position channel is the joint's translation (in place of its offset)
                if c.lower().endswith("position"):
                    trans[:, "xyz".index(c[0].lower())] = vals[:, i]
            p = self.parents[j]
            if p < 0:
                rot[:, j], pos[:, j] = local, trans
            else:
                rot[:, j] = rot[:, p] @ local
                pos[:, j] = pos[:, p] + np.einsum("nij,nj->ni", rot[:, p], trans)
        return rot, pos

    def rest_positions(self) -> NDArray[np.float64]:
        pos = np.zeros((len(self.names), 3))
        for j, p in enumerate(self.parents):
            pos[j] = self.offsets[j] + (pos[p] if p >= 0 else 0.0)
        return pos


def parse_bvh(path: str | Path) -> BvhData:
    """Parse a BVH file (LF or CRLF). Raises MocapImportError on malformed input."""
    try:
        text = read_bounded_bytes(path, MAX_MOCAP_FILE_BYTES, str(path)).decode("utf-8", errors="replace")
    except BoundedFileError as exc:
        raise MocapImportError(path, f"cannot read file ({exc.problem})") from None
    head, sep, motion = text.partition("MOTION")
    if not sep or "HIERARCHY" not in head:
        raise MocapImportError(path, "not a BVH file (HIERARCHY / MOTION sections missing)")
    tokens = head.split()
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    end_offsets: list[NDArray[np.float64] | None] = []
    stack: list[int] = []
    i = tokens.index("HIERARCHY") + 1
    pending_end = False
    try:
        while i < len(tokens):
            tok = tokens[i]
            if tok in ("ROOT", "JOINT"):
                names.append(tokens[i + 1])
                parents.append(stack[-1] if stack else -1)
                offsets.append([0.0, 0.0, 0.0])
                channels.append(())
                end_offsets.append(None)
                i += 2
            elif tok == "End":
                pending_end = True
                i += 2
            elif tok == "{":
                stack.append(-2 if pending_end else len(names) - 1)
                i += 1
            elif tok == "}":
                stack.pop()
                pending_end = False
                i += 1
            elif tok == "OFFSET":
                vals = [float(v) for v in tokens[i + 1 : i + 4]]
                if stack and stack[-1] == -2:
                    owner = [s for s in stack if s >= 0][-1]
                    end_offsets[owner] = np.array(vals)
                else:
                    offsets[-1] = vals
                i += 4
            elif tok == "CHANNELS":
                k = int(tokens[i + 1])
                channels[-1] = tuple(tokens[i + 2 : i + 2 + k])
                i += 2 + k
            else:
                raise MocapImportError(path, f"unexpected token {tok!r} in HIERARCHY")
        m = re.search(r"Frames:\s*(\d+)\s*Frame Time:\s*([0-9.eE+-]+)", motion)
        if not m:
            raise MocapImportError(path, "MOTION section lacks 'Frames:' / 'Frame Time:'")
        n, frame_time = int(m.group(1)), float(m.group(2))
        body = motion[m.end():].split()
        total = sum(len(c) for c in channels)
        values = np.array(body[: n * total], dtype=np.float64)
    except (IndexError, ValueError) as exc:
        if isinstance(exc, MocapImportError):
            raise
        raise MocapImportError(path, f"malformed BVH ({exc})") from None
    if not names:
        raise MocapImportError(path, "no joints in HIERARCHY")
    if values.size < n * total or n < 2:
        raise MocapImportError(path, f"expected {n} frames of {total} channels, found {values.size // max(total, 1)}")
    if not np.all(np.isfinite(values)) or frame_time <= 0:
        raise MocapImportError(path, "non-finite channel values or non-positive frame time")
    return BvhData(tuple(names), tuple(parents), np.array(offsets, dtype=np.float64), tuple(channels),
                   tuple(end_offsets), values.reshape(n, total), frame_time)


def _norm(name: str) -> str:
    return re.sub(r"[^a-z0-9]", "", name.lower().split(":")[-1])


# Candidate source names per joint, most specific first (normalised: lowercase alphanumerics).
ALIASES: dict[str, tuple[str, ...]] = {
    "pelvis": ("hips", "hip", "pelvis", "root"),
    "left_hip": ("lthigh", "leftupleg", "leftupperleg", "lefthip", "lhip", "leftthigh"),
    "right_hip": ("rthigh", "rightupleg", "rightupperleg", "righthip", "rhip", "rightthigh"),
    "left_knee": ("lshin", "leftleg", "leftknee", "lknee", "leftlowerleg", "leftshin"),
    "right_knee": ("rshin", "rightleg", "rightknee", "rknee", "rightlowerleg", "rightshin"),
    "left_ankle": ("lfoot", "leftfoot", "leftankle", "lankle"),
    "right_ankle": ("rfoot", "rightfoot", "rightankle", "rankle"),
    "left_foot": ("ltoe", "lefttoebase", "lefttoe", "ltoes", "lefttoes"),
    "right_foot": ("rtoe", "righttoebase", "righttoe", "rtoes", "righttoes"),
    "spine1": ("abdomen", "lowerback", "spine", "spine1", "lowerspine"),
    "spine2": ("chest", "spine1", "spine2", "upperback"),
    "spine3": ("chest2", "spine2", "spine3", "upperchest", "chest3"),
    "neck": ("neck", "lowerneck", "neck1"),
    "head": ("head",),
    "left_collar": ("lcollar", "leftcollar", "leftshoulder", "lclavicle", "leftclavicle"),
    "right_collar": ("rcollar", "rightcollar", "rightshoulder", "rclavicle", "rightclavicle"),
    "left_shoulder": ("lshldr", "leftarm", "leftupperarm", "leftshoulder", "lshoulder", "lupperarm"),
    "right_shoulder": ("rshldr", "rightarm", "rightupperarm", "rightshoulder", "rshoulder", "rupperarm"),
    "left_elbow": ("lforearm", "leftforearm", "leftelbow", "lelbow", "leftlowerarm"),
    "right_elbow": ("rforearm", "rightforearm", "rightelbow", "relbow", "rightlowerarm"),
    "left_wrist": ("lhand", "lefthand", "leftwrist", "lwrist"),
    "right_wrist": ("rhand", "righthand", "rightwrist", "rwrist"),
}
REQUIRED = ("pelvis", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "head")
# Resolve in this order so that e.g. "LeftShoulder" is the upper arm when no "LeftArm" exists.
_ORDER = ("pelvis", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
          "left_foot", "right_foot", "head", "neck", "left_shoulder", "right_shoulder", "left_elbow",
          "right_elbow", "left_wrist", "right_wrist", "left_collar", "right_collar", "spine1", "spine2", "spine3")
_PRIMARY_CHILD = {
    "pelvis": None, "left_hip": "left_knee", "right_hip": "right_knee", "left_knee": "left_ankle",
    "right_knee": "right_ankle", "left_ankle": "left_foot", "right_ankle": "right_foot", "spine1": "spine2",
    "spine2": "spine3", "spine3": "neck", "neck": "head", "left_collar": "left_shoulder",
    "right_collar": "right_shoulder", "left_shoulder": "left_elbow", "right_shoulder": "right_elbow",
    "left_elbow": "left_wrist", "right_elbow": "right_wrist",
}


def auto_joint_mapping(names: tuple[str, ...], overrides: Mapping[str, str] | None = None) -> dict[str, str]:
    """Map our joint names to source joint names (each source joint used once).

    ``overrides`` (our name -> source name) win. Raises KeyError listing missing required joints.
    """
    by_norm: dict[str, str] = {}
    for n in names:
        by_norm.setdefault(_norm(n), n)
    mapping: dict[str, str] = {}
    used: set[str] = set()
    for ours, src in (overrides or {}).items():
        if ours not in JOINT_INDEX:
            raise KeyError(f"unknown joint {ours!r} in the mapping; expected one of {', '.join(JOINT_NAMES)}")
        if src not in names:
            raise KeyError(f"mapping for {ours!r}: the file has no joint {src!r}")
        mapping[ours] = src
        used.add(src)
    for ours in _ORDER:
        if ours in mapping:
            continue
        for cand in ALIASES[ours]:
            found = by_norm.get(cand)
            if found is not None and found not in used:
                mapping[ours] = found
                used.add(found)
                break
    missing = [j for j in REQUIRED if j not in mapping]
    if missing:
        raise KeyError(f"cannot find joints for {', '.join(missing)}; give them in the mapping")
    return mapping


def _min_rotation(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Smallest rotation taking direction a to direction b."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(np.dot(a, b))
    if c < -1 + 1e-9:
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        return Rotation.from_rotvec(np.pi * axis / np.linalg.norm(axis)).as_matrix()
    vx: NDArray[np.float64] = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


UPRIGHT_REST_DEG = 30.0
"""A rest pose whose pelvis-to-head line is within this angle of the file's vertical stands
upright: the file's world is read in the rest pose's axes (as every upright T-pose file)."""


def _world_axes(rest_axes: NDArray[np.float64], head_over_pelvis: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rows: the file's world -> our y-up frame. The vertical is the file axis (+-x, +-y, +-z)
    nearest the motion's median pelvis-to-head direction; a rest pose standing upright keeps its
    own axes (so a tilted T-pose tilts nothing), one that does not (Bandai Namco's rest pose
    has its bones along +x) takes that axis as up and its hip line, made level, as left."""
    d = np.median(np.asarray(head_over_pelvis, dtype=np.float64), axis=0)
    k = int(np.argmax(np.abs(d)))
    vertical = np.zeros(3)
    vertical[k] = np.sign(d[k]) if d[k] != 0 else 1.0
    if float(np.dot(rest_axes[1], vertical)) >= np.cos(np.radians(UPRIGHT_REST_DEG)):
        return rest_axes
    left = rest_axes[0] - np.dot(rest_axes[0], vertical) * vertical
    if np.linalg.norm(left) < 1e-6:  # the rest hip line is vertical: any level direction
        left = np.roll(vertical, 1)
    left /= np.linalg.norm(left)
    return np.stack([left, vertical, np.cross(left, vertical)])


def retarget(
    data: BvhData,
    mapping: Mapping[str, str],
    *,
    snap_to_floor: bool = True,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Our local rotations (N,22,3,3) (joint 0 in the z-up world) and pelvis positions (N,3) m."""
    idx = {n: i for i, n in enumerate(data.names)}
    src = {ours: idx[name] for ours, name in mapping.items()}
    rest = data.rest_positions()
    left = rest[src["left_hip"]] - rest[src["right_hip"]]
    up = rest[src["head"]] - rest[src["pelvis"]]
    left /= np.linalg.norm(left)
    up = up - np.dot(up, left) * left
    up /= np.linalg.norm(up)
    axes = np.stack([left, up, np.cross(left, up)])  # rows: source rest pose -> our body frame
    g_src, p_src = data.global_transforms()
    world = _world_axes(axes, p_src[:, src["head"]] - p_src[:, src["pelvis"]])
    g = world @ g_src @ axes.T  # source global rotations, from our rest body frame to our (y-up) world
    rest_b = rest @ axes.T
    ours_rest = rest_positions()
    n = len(data.frames)
    glob = np.empty((n, NUM_JOINTS, 3, 3))
    for j, name in enumerate(JOINT_NAMES):
        if name not in src:
            glob[:, j] = glob[:, PARENTS[j]] if j else np.eye(3)
            continue
        corr = np.eye(3)
        child = _PRIMARY_CHILD.get(name)
        if child is not None and child in src:
            ours_dir = ours_rest[JOINT_INDEX[child]] - ours_rest[j]
            src_dir = rest_b[src[child]] - rest_b[src[name]]
            if np.linalg.norm(src_dir) > 1e-9:
                corr = _min_rotation(ours_dir, src_dir)
        glob[:, j] = g[:, src[name]] @ corr
    local = np.empty_like(glob)
    local[:, 0] = BODY_TO_WORLD @ glob[:, 0]
    for j in range(1, NUM_JOINTS):
        local[:, j] = np.swapaxes(glob[:, PARENTS[j]], -1, -2) @ glob[:, j]
    src_leg = float(np.linalg.norm(rest_b[src["left_knee"]] - rest_b[src["left_hip"]]) + np.linalg.norm(
        rest_b[src["left_ankle"]] - rest_b[src["left_knee"]]))
    our_leg = float(np.linalg.norm(ours_rest[JOINT_INDEX["left_knee"]] - ours_rest[JOINT_INDEX["left_hip"]]) + np.linalg.norm(
        ours_rest[JOINT_INDEX["left_ankle"]] - ours_rest[JOINT_INDEX["left_knee"]]))
    scale = our_leg / max(src_leg, 1e-9)
    pelvis = (p_src[:, src["pelvis"]] @ world.T * scale) @ BODY_TO_WORLD.T
    if snap_to_floor:
        toes = forward_kinematics(local, pelvis)[0][:, FOOT_JOINTS, 2]
        pelvis[:, 2] += TOE_HEIGHT - float(np.percentile(toes.min(axis=1), 2))
    return local, pelvis


def import_bvh(
    path: str | Path,
    key: str,
    *,
    start: int = 0,
    end: int | None = None,
    fps: float | None = None,
    mapping: Mapping[str, str] | None = None,
    loops: bool = False,
    name: str | None = None,
) -> MotionClip:
    """Import frames [start, end) of a BVH file as a 30 fps clip filed under database ``key``.

    fps overrides the header's frame rate (some conversions write a wrong Frame Time).
    """
    data = parse_bvh(path)
    try:
        joint_map = auto_joint_mapping(data.names, mapping)
    except KeyError as exc:
        raise MocapImportError(path, str(exc.args[0])) from None
    stop = len(data.frames) if end is None else min(end, len(data.frames))
    if not 0 <= start < stop - 1:
        raise MocapImportError(path, f"frame range [{start}, {end}) leaves fewer than 2 of {len(data.frames)} frames")
    sub = BvhData(data.names, data.parents, data.offsets, data.channels, data.end_offsets,
                  data.frames[start:stop], data.frame_time)
    local, pelvis = retarget(sub, joint_map)
    rate = fps if fps is not None else 1.0 / data.frame_time
    return clip_from_pose_frames(name or f"{Path(path).stem}[{start}:{stop}]", key, local, pelvis, rate,
                                 source=str(path), loops=loops)

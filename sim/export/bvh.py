"""BVH export of a character track.

Conventions of the written file:

- **Y up**, the body facing +z in the rest pose (the SMPL-X body frame; Blender's BVH importer
  defaults to Y up, forward -Z, and reads it upright). Our z-up world maps to it by
  ``(x, y, z) -> (x, z, -y)``, i.e. ``BODY_TO_WORLD.T``.
- **Metres** by default (``units="m"``: a 1.7 m figure imports at 1.7 Blender units);
  ``units="cm"`` multiplies every length by 100, as many BVH tools expect.
- Hierarchy: our 22 SMPL-X joints, depth first from the pelvis, with our rest offsets;
  End Sites after the head, the wrists and the feet (our own lengths).
- Channels: the root has ``Xposition Yposition Zposition Zrotation Xrotation Yrotation``
  (root offset 0, positions absolute); every other joint ``Zrotation Xrotation Yrotation``.
  As everywhere in BVH, the listed order composes left to right: ``R = Rz(a) @ Rx(b) @ Ry(c)``
  and a child point maps to its parent by ``p_parent = offset + R @ p_child``.
  Angles are in degrees, unwrapped along time so curves have no 360-degree jumps.
- Frame rate: the track's (30 fps by default); numbers written with 6 decimals.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Final, Literal

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import (
    BODY_TO_WORLD,
    JOINT_INDEX,
    JOINT_NAMES,
    NUM_JOINTS,
    PARENTS,
    REST_OFFSETS,
)
from storyteller.sim.export.joint_rotations import JointRotations
from storyteller.sim.no_follow_writes import write_file
from storyteller.sim.world.character_track import CharacterTrack

Units = Literal["m", "cm"]
UNIT_SCALE: dict[str, float] = {"m": 1.0, "cm": 100.0}
EULER_ORDER: Final = "ZXY"  # intrinsic, as scipy spells it; BVH channel order Z, X, Y
ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
JOINT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")
WORLD_TO_BVH = BODY_TO_WORLD.T
# End Site offsets (body frame, metres) after the skeleton's leaves: top of head, finger tips, toes.
END_SITES: dict[str, tuple[float, float, float]] = {
    "head": (0.0, 0.12, 0.02),
    "left_wrist": (0.09, 0.0, 0.0),
    "right_wrist": (-0.09, 0.0, 0.0),
    "left_foot": (0.0, -0.01, 0.06),
    "right_foot": (0.0, -0.01, 0.06),
}
_CHILDREN: tuple[tuple[int, ...], ...] = tuple(
    tuple(c for c in range(NUM_JOINTS) if PARENTS[c] == j) for j in range(NUM_JOINTS)
)


def depth_first_order() -> tuple[int, ...]:
    """Our joint indices in the depth-first order a BVH file lists them (pelvis first)."""
    order: list[int] = []
    stack = [0]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(_CHILDREN[j]))
    return tuple(order)


def bvh_hierarchy(units: Units = "m") -> str:
    """The HIERARCHY section (with trailing newline)."""
    scale = UNIT_SCALE[units]
    lines = ["HIERARCHY"]

    def vec(v: NDArray[np.float64] | tuple[float, float, float]) -> str:
        return " ".join(f"{x * scale:.6f}" for x in v)

    def write(j: int, depth: int) -> None:
        pad = "  " * depth
        keyword = "ROOT" if j == 0 else "JOINT"
        offset = np.zeros(3) if j == 0 else REST_OFFSETS[j]
        channels = ROOT_CHANNELS if j == 0 else JOINT_CHANNELS
        lines.extend(
            [
                f"{pad}{keyword} {JOINT_NAMES[j]}",
                f"{pad}{{",
                f"{pad}  OFFSET {vec(offset)}",
                f"{pad}  CHANNELS {len(channels)} {' '.join(channels)}",
            ]
        )
        for c in _CHILDREN[j]:
            write(c, depth + 1)
        if JOINT_NAMES[j] in END_SITES:
            lines.extend(
                [
                    f"{pad}  End Site",
                    f"{pad}  {{",
                    f"{pad}    OFFSET {vec(END_SITES[JOINT_NAMES[j]])}",
                    f"{pad}  }}",
                ]
            )
        lines.append(f"{pad}}}")

    write(0, 0)
    return "\n".join(lines) + "\n"


def bvh_motion_values(
    track: CharacterTrack, units: Units = "m", rotations: JointRotations | None = None
) -> NDArray[np.float64]:
    """The MOTION rows (N, 6 + 3 * 21): root position and Euler degrees, depth-first order.
    ``rotations``: the track's, converted once for every exporter (default: converted here)."""
    n = track.num_frames
    joints = rotations if rotations is not None else JointRotations.of(track)
    euler = joints.with_root(WORLD_TO_BVH, depth_first_order()).as_euler(EULER_ORDER)
    euler = np.degrees(np.unwrap(euler.reshape(n, NUM_JOINTS, 3), axis=0))
    root = (track.root_positions @ WORLD_TO_BVH.T) * UNIT_SCALE[units]
    return np.concatenate([root, euler.reshape(n, NUM_JOINTS * 3)], axis=1)


def bvh_text(track: CharacterTrack, units: Units = "m", rotations: JointRotations | None = None) -> str:
    """The whole BVH file as text (deterministic for identical input)."""
    values = bvh_motion_values(track, units, rotations) + 0.0  # no negative zeros
    out = io.StringIO()
    out.write(bvh_hierarchy(units))
    out.write(f"MOTION\nFrames: {track.num_frames}\nFrame Time: {1.0 / track.fps:.8f}\n")
    np.savetxt(out, values, fmt="%.6f", delimiter=" ", newline="\n")
    return out.getvalue()


def export_bvh(
    track: CharacterTrack, path: str | Path, units: Units = "m", rotations: JointRotations | None = None
) -> Path:
    """Write ``track`` as a BVH file (see the module docstring). Returns the path."""
    if units not in UNIT_SCALE:
        raise ValueError(f"units must be one of {sorted(UNIT_SCALE)}, got {units!r}")
    path = Path(path)
    write_file(path, bvh_text(track, units, rotations).encode("ascii"))
    return path


assert depth_first_order()[0] == JOINT_INDEX["pelvis"] and len(depth_first_order()) == NUM_JOINTS

"""AMASS-style SMPL-X ``.npz`` import (and the matching array layout for round trips).

Accepted keys: ``poses`` (N, 3 + 3k) axis-angle with the root orientation first and the 21
body joints next (SMPL-X 165, SMPL-H 156 and SMPL 72 columns all start this way), or
``root_orient`` (N,3) + ``pose_body`` (N,63); ``trans`` (N,3) metres in the z-up world; and
``mocap_frame_rate`` (or ``mocap_framerate``) in frames per second. Our skeleton's body frame
is SMPL-X's, so rotations transfer unchanged. The pelvis is ``trans + pelvis_rest`` (the SMPL
``transl`` convention; ``pelvis_rest`` is the model's rest pelvis, ours by default).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import NUM_JOINTS, REST_OFFSETS, axis_angle_to_matrix, forward_kinematics
from storyteller.sim.bounded_files import BoundedFileError, read_bounded_npz
from storyteller.sim.motion.clips import FOOT_JOINTS, MotionClip, clip_from_pose_frames
from storyteller.sim.motion.sources.bvh_import import (
    MAX_MOCAP_ARRAY_BYTES,
    MAX_MOCAP_FILE_BYTES,
    MocapImportError,
)
from storyteller.sim.motion.sources.procedural_rig import TOE_HEIGHT


def load_amass_arrays(path: str | Path) -> dict[str, NDArray[np.float64]]:
    try:
        return read_bounded_npz(path, MAX_MOCAP_FILE_BYTES, MAX_MOCAP_ARRAY_BYTES, str(path))
    except BoundedFileError as exc:
        raise MocapImportError(path, f"cannot read npz ({exc.problem})") from None


def amass_pose_frames(
    arrays: dict[str, NDArray[np.float64]], path: str | Path = "<arrays>", pelvis_rest: NDArray[np.float64] | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """(local rotations (N,22,3,3), pelvis (N,3), fps) from AMASS-style arrays."""
    if "poses" in arrays:
        poses = np.asarray(arrays["poses"], dtype=np.float64)
        if poses.ndim != 2 or poses.shape[1] < 3 * NUM_JOINTS:
            raise MocapImportError(path, f"'poses' has shape {poses.shape}, expected (N, >= {3 * NUM_JOINTS})")
        aa = poses[:, : 3 * NUM_JOINTS].reshape(-1, NUM_JOINTS, 3)
    elif "root_orient" in arrays and "pose_body" in arrays:
        root, body = np.asarray(arrays["root_orient"], float), np.asarray(arrays["pose_body"], float)
        if root.shape[-1] != 3 or body.shape[-1] != 3 * (NUM_JOINTS - 1) or len(root) != len(body):
            raise MocapImportError(path, f"'root_orient' {root.shape} / 'pose_body' {body.shape} do not fit (N,3) / (N,63)")
        aa = np.concatenate([root, body], axis=1).reshape(-1, NUM_JOINTS, 3)
    else:
        raise MocapImportError(path, "needs 'poses' or 'root_orient' + 'pose_body'")
    if "trans" not in arrays:
        raise MocapImportError(path, "missing 'trans'")
    trans = np.asarray(arrays["trans"], dtype=np.float64)
    if trans.shape != (len(aa), 3):
        raise MocapImportError(path, f"'trans' has shape {trans.shape}, expected ({len(aa)}, 3)")
    rate_key = "mocap_frame_rate" if "mocap_frame_rate" in arrays else "mocap_framerate"
    if rate_key not in arrays:
        raise MocapImportError(path, "missing 'mocap_frame_rate'")
    fps = float(np.asarray(arrays[rate_key]).reshape(-1)[0])
    if not (np.isfinite(fps) and fps > 0) or not (np.all(np.isfinite(aa)) and np.all(np.isfinite(trans))):
        raise MocapImportError(path, "non-finite values or non-positive frame rate")
    if len(aa) < 2:
        raise MocapImportError(path, "needs at least 2 frames")
    j0 = REST_OFFSETS[0] if pelvis_rest is None else np.asarray(pelvis_rest, dtype=np.float64).reshape(3)
    return axis_angle_to_matrix(aa), trans + j0, fps


def import_amass(
    path: str | Path,
    key: str,
    *,
    start: int = 0,
    end: int | None = None,
    fps: float | None = None,
    pelvis_rest: NDArray[np.float64] | None = None,
    snap_to_floor: bool = True,
    loops: bool = False,
    name: str | None = None,
) -> MotionClip:
    """Import frames [start, end) of an AMASS-style npz as a 30 fps clip for database ``key``."""
    local, pelvis, rate = amass_pose_frames(load_amass_arrays(path), path, pelvis_rest)
    stop = len(local) if end is None else min(end, len(local))
    if not 0 <= start < stop - 1:
        raise MocapImportError(path, f"frame range [{start}, {end}) leaves fewer than 2 of {len(local)} frames")
    local, pelvis = local[start:stop], pelvis[start:stop].copy()
    if snap_to_floor:
        toes = forward_kinematics(local, pelvis)[0][:, FOOT_JOINTS, 2]
        pelvis[:, 2] += TOE_HEIGHT - float(np.percentile(toes.min(axis=1), 2))
    return clip_from_pose_frames(name or f"{Path(path).stem}[{start}:{stop}]", key, local, pelvis,
                                 fps if fps is not None else rate, source=str(path), loops=loops)

"""SMPL-X parameters of a character track, as an AMASS-style ``.npz``.

The file holds, for N frames at ``mocap_frame_rate`` (30):

- ``poses`` (N, 165) axis-angle in SMPL-X order: root_orient 3, body 21 x 3, jaw 3,
  left/right eye 3 + 3, left/right hand 15 x 3 + 15 x 3. We animate only the 22 body joints;
  jaw, eyes and fingers are zero (flat hands, i.e. read it with ``flat_hand_mean=True``);
- the same values split as ``root_orient`` (N, 3), ``pose_body`` (N, 63), ``pose_jaw`` (N, 3),
  ``pose_eye`` (N, 6), ``pose_hand`` (N, 90), for tools that read those keys;
- ``trans`` (N, 3), metres, in the SMPL ``transl`` convention: the model puts the pelvis at
  ``J0 + transl`` (it rotates the body about its own pelvis joint ``J0``), so
  ``trans = pelvis_world - J0``. ``J0`` is the rest pelvis of the model for the given betas;
  by default ours (``REST_OFFSETS[0]``, in the body frame), the one our stand-in model uses.
  Pass ``pelvis_rest`` to target another model's pelvis;
- ``betas`` (10,), ``gender``, ``mocap_frame_rate``, ``mocap_time_length`` (seconds),
  ``surface_model_type`` ("smplx") and, when the track has them, ``action_labels`` (N,).

The world is z up, as in AMASS: ``root_orient`` maps the SMPL-X body frame (y up) to it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import NUM_JOINTS, REST_OFFSETS
from storyteller.sim.export.joint_rotations import JointRotations
from storyteller.sim.world.character_track import CharacterTrack, write_npz

NUM_POSE_PARAMS = 165
BODY_POSE_SLICE = slice(3, 66)
JAW_SLICE = slice(66, 69)
EYES_SLICE = slice(69, 75)
HANDS_SLICE = slice(75, 165)


def smplx_parameters(
    track: CharacterTrack, pelvis_rest: NDArray[np.float64] | None = None, rotations: JointRotations | None = None
) -> dict[str, NDArray[np.float64]]:
    """The AMASS-style arrays for ``track`` (see the module docstring), float64 except strings.
    ``rotations``: the track's, converted once for every exporter (default: converted here)."""
    j0 = REST_OFFSETS[0] if pelvis_rest is None else np.asarray(pelvis_rest, dtype=np.float64).reshape(3)
    n = track.num_frames
    local = (rotations if rotations is not None else JointRotations.of(track)).local
    aa = local.as_rotvec().reshape(n, NUM_JOINTS, 3)
    poses = np.zeros((n, NUM_POSE_PARAMS))
    poses[:, : NUM_JOINTS * 3] = aa.reshape(n, NUM_JOINTS * 3)
    arrays: dict[str, NDArray[np.float64]] = {
        "poses": poses,
        "trans": track.root_positions - j0,
        "betas": np.array(track.betas),
        "gender": np.array(track.gender),
        "mocap_frame_rate": np.array(track.fps),
        "mocap_time_length": np.array(n / track.fps),
        "surface_model_type": np.array("smplx"),
        "root_orient": poses[:, :3].copy(),
        "pose_body": poses[:, BODY_POSE_SLICE].copy(),
        "pose_jaw": poses[:, JAW_SLICE].copy(),
        "pose_eye": poses[:, EYES_SLICE].copy(),
        "pose_hand": poses[:, HANDS_SLICE].copy(),
    }
    if track.action_labels is not None:
        arrays["action_labels"] = np.array(track.action_labels, dtype=str)
    return arrays


def export_smplx_npz(
    track: CharacterTrack,
    path: str | Path,
    pelvis_rest: NDArray[np.float64] | None = None,
    rotations: JointRotations | None = None,
) -> Path:
    """Write ``track`` as an AMASS-style SMPL-X ``.npz`` (deterministic bytes). Returns the path."""
    return write_npz(path, smplx_parameters(track, pelvis_rest, rotations))

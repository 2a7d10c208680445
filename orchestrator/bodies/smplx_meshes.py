"""SMPL-X bodies for the viewer and the GLB export, computed with ``smplx`` and ``torch`` (CPU).

From the model files a user downloads (``SMPLX_NEUTRAL.npz`` etc.) and a character's exported
parameters (``poses`` (N, 165), ``trans`` (N, 3), ``betas``, ``gender``; AMASS-style, see
:mod:`storyteller.sim.export.smplx_npz`), :func:`smplx_body` computes:

- the rest mesh for the character's betas (``smplx`` forward pass at zero pose): vertices
  (V, 3) in the body frame (y up), faces, and the 22 body joints it regresses;
- skin weights on our 22 joints: the model's 55-joint linear-blend weights with jaw, eyes
  and fingers folded into the body joint they hang from (head, wrists). The export leaves those
  joints unposed (zero pose, flat hands), so they move exactly with that body joint and the
  folding changes nothing; the 4 largest weights per vertex are kept and renormalised;
- per frame, each body joint's world rotation and position, chained by
  ``smplx.lbs.batch_rigid_transform`` from the exported poses, placed at ``trans`` (the
  pelvis at ``J0 + trans``, the SMPL ``transl`` convention), in the world frame (z up).

A vertex ``v`` then lands at ``sum_k w_k (R_k (v - J_k) + p_k)`` (:func:`posed_vertices`),
which is the model's own output except for its pose-corrective shapes (``posedirs``).

``smplx`` and ``torch`` are imported inside the functions that need them.
"""

from __future__ import annotations

import tempfile
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import NUM_JOINTS
from storyteller.sim.bounded_files import BoundedFileError, read_bounded_npz
from storyteller.sim.export.glb import SkinnedBody

INFLUENCES = 4  # skin weights kept per vertex (glTF JOINTS_0 / WEIGHTS_0, viser's skinning)
GENDERS = ("neutral", "female", "male")
MAX_PARAMETER_FILE_BYTES = 256 << 20
"""Largest ``<name>.smplx.npz`` read back, and most bytes its arrays may unpack to."""
MAX_MODEL_FILE_BYTES = 512 << 20
"""Largest SMPL-X model file read (SMPLX_NEUTRAL.npz of the 1.1 release: about 110 MB)."""
MAX_MODEL_ARRAY_BYTES = 512 << 20
"""Most bytes a model file's arrays may unpack to (the 1.1 release: about 260 MB)."""


class SmplxModelError(Exception):
    """The SMPL-X model folder or a parameters file cannot be used (the message names it)."""


@dataclass(frozen=True)
class SmplxBody:
    """One character's body: the skinned rest mesh and its bones' world transforms per frame."""

    skin: SkinnedBody
    bone_wxyz: NDArray[np.float64]
    """(N, 22, 4) world rotations of the joints, unit quaternions (w, x, y, z)."""
    bone_positions: NDArray[np.float64]
    """(N, 22, 3) world positions of the joints, metres (z up)."""

    @property
    def num_frames(self) -> int:
        return int(self.bone_positions.shape[0])


def model_file(model_dir: Path, gender: str) -> Path:
    """The model file for ``gender`` in ``model_dir`` (or its ``smplx/`` subfolder).

    Falls back to the neutral model when the gendered one is missing.
    """
    if not model_dir.is_dir():
        raise SmplxModelError(f"{model_dir}: not a folder (expected the folder holding SMPLX_NEUTRAL.npz)")
    wanted = [gender.upper(), "NEUTRAL"] if gender.lower() != "neutral" else ["NEUTRAL"]
    for g in wanted:
        for folder in (model_dir, model_dir / "smplx"):
            for ext in ("npz", "pkl"):
                path = folder / f"SMPLX_{g}.{ext}"
                if path.is_file():
                    return path
    raise SmplxModelError(
        f"{model_dir}: no SMPLX_{wanted[0]}.npz (nor .pkl, nor in smplx/) -- "
        "download the SMPL-X model files from https://smpl-x.is.tue.mpg.de"
    )


def load_parameters(path: Path) -> dict[str, NDArray[Any]]:
    """The arrays of an exported ``<name>.smplx.npz`` (checked for the keys used here)."""
    try:  # a shared run folder's file: bounded, never unpickled
        params = read_bounded_npz(path, MAX_PARAMETER_FILE_BYTES, MAX_PARAMETER_FILE_BYTES, str(path))
    except BoundedFileError as exc:
        raise SmplxModelError(f"{path}: not readable as an .npz ({exc.problem})") from None
    for key in ("poses", "trans", "betas"):
        if key in params and params[key].dtype.kind not in "fiu":
            raise SmplxModelError(f"{path}: field {key!r}: expected real numbers, got {params[key].dtype}")
    for key, ndim in (("poses", 2), ("trans", 2), ("betas", 1)):
        if key not in params or params[key].ndim != ndim:
            raise SmplxModelError(f"{path}: field {key!r}: missing or not a {ndim}-d array")
    if params["poses"].shape[1] < NUM_JOINTS * 3 or params["trans"].shape != (params["poses"].shape[0], 3):
        raise SmplxModelError(f"{path}: fields 'poses' (N, 165) and 'trans' (N, 3) do not match")
    return params


def _fold_to_body(parents: NDArray[np.int64]) -> NDArray[np.int64]:
    """For each model joint, the first of our 22 body joints on its chain to the root."""
    owner = np.arange(parents.size)
    for j in range(parents.size):
        k = j
        while k >= NUM_JOINTS:
            k = int(parents[k])
        owner[j] = k
    return owner


def _top_weights(weights: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The ``INFLUENCES`` largest weights per vertex (ids, renormalised weights)."""
    ids = np.argsort(-weights, axis=1, kind="stable")[:, :INFLUENCES]
    top = np.take_along_axis(weights, ids, axis=1)
    top = top / np.maximum(top.sum(axis=1, keepdims=True), 1e-12)
    return ids.astype(np.int64), top


def _numeric_copy(path: Path, folder: Path) -> Path:
    """A copy of the model file ``path`` in ``folder`` holding only its numeric arrays, for
    ``smplx`` to load: ``smplx`` loads a model with ``pickle`` (``.pkl``) or ``allow_pickle=True``
    (``.npz``), so a crafted model file would run code. The arrays are read as any other file
    from outside (``storyteller.sim.bounded_files.read_bounded_npz``: bounded, never unpickled); the model's
    arrays of Python objects (``joint2num``, ``part2num``: names, unused here) are left out, and
    a ``.pkl`` model (a pickle through and through) is refused."""
    if path.suffix != ".npz":
        raise SmplxModelError(f"{path}: a .pkl model is a pickle, which could run code when loaded; "
                              "use the .npz model files")
    try:
        arrays = read_bounded_npz(path, MAX_MODEL_FILE_BYTES, MAX_MODEL_ARRAY_BYTES, str(path), skip_objects=True)
    except BoundedFileError as exc:
        raise SmplxModelError(f"{path}: not a usable SMPL-X model file ({exc.problem})") from None
    clean = folder / path.name
    with zipfile.ZipFile(clean, "w") as npz:  # np.savez's layout, written array by array
        for name, array in arrays.items():
            with npz.open(f"{name}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, array, allow_pickle=False)
    return clean


class SmplxModels:
    """Loaded SMPL-X models of one folder, one per gender, reused across characters."""

    def __init__(self, model_dir: Path) -> None:
        self.model_dir = model_dir
        self._models: dict[tuple[Path, int], Any] = {}

    def model(self, gender: str, num_betas: int) -> Any:
        import smplx

        path = model_file(self.model_dir, gender)
        key = (path, num_betas)
        if key not in self._models:
            with tempfile.TemporaryDirectory(prefix="smplx-") as private:
                clean = _numeric_copy(path, Path(private))
                try:
                    self._models[key] = smplx.create(
                        str(clean), model_type="smplx", gender=gender, ext="npz", use_pca=False,
                        flat_hand_mean=True, num_betas=num_betas, batch_size=1,
                    )  # fmt: skip
                except (OSError, KeyError, ValueError, AssertionError, AttributeError, IndexError, RuntimeError) as exc:
                    raise SmplxModelError(f"{path}: not a usable SMPL-X model file ({str(exc)[:200]})") from None
        return self._models[key]

    def body(self, params: Mapping[str, NDArray[Any]]) -> SmplxBody:
        """The skinned body and bone transforms of one character's parameters."""
        import torch
        from smplx.lbs import batch_rigid_transform, batch_rodrigues

        gender = str(params.get("gender", "neutral"))
        gender = gender if gender in GENDERS else "neutral"
        betas = np.asarray(params["betas"], dtype=np.float64)
        model = self.model(gender, betas.size)
        with torch.no_grad():
            rest = model(betas=torch.tensor(betas[None], dtype=torch.float32), return_verts=True)
            vertices = rest.vertices[0].double().numpy()
            joints = rest.joints[0, : model.NUM_JOINTS + 1].double().numpy()
            parents = model.parents.numpy().astype(np.int64)
            weights = model.lbs_weights.double().numpy()
            faces = model.faces_tensor.numpy().astype(np.int64)

            poses = np.asarray(params["poses"], dtype=np.float64)[:, : NUM_JOINTS * 3]
            n = poses.shape[0]
            rot = batch_rodrigues(torch.tensor(poses.reshape(-1, 3))).reshape(n, NUM_JOINTS, 3, 3)
            bind = torch.tensor(joints[:NUM_JOINTS]).expand(n, NUM_JOINTS, 3).contiguous()
            posed, rel = batch_rigid_transform(rot, bind, torch.tensor(parents[:NUM_JOINTS]), dtype=torch.float64)
            world_rot = rel[..., :3, :3].numpy()
            positions = posed.numpy() + np.asarray(params["trans"], dtype=np.float64)[:, None, :]

        owner = _fold_to_body(parents)
        body_weights = np.zeros((weights.shape[0], NUM_JOINTS))
        np.add.at(body_weights.T, owner, weights.T)
        ids, top = _top_weights(body_weights)
        skin = SkinnedBody(
            vertices=vertices, faces=faces, joints=ids, weights=top, bind_joints=joints[:NUM_JOINTS]
        )
        return SmplxBody(skin=skin, bone_wxyz=_wxyz(world_rot), bone_positions=positions)


def _wxyz(matrices: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, J, 3, 3) rotations -> (N, J, 4) unit quaternions (w, x, y, z), sign-continuous."""
    from scipy.spatial.transform import Rotation

    xyzw = Rotation.from_matrix(matrices.reshape(-1, 3, 3)).as_quat().reshape(*matrices.shape[:-2], 4)
    for k in range(1, xyzw.shape[0]):
        flip = np.einsum("ji,ji->j", xyzw[k], xyzw[k - 1]) < 0.0
        xyzw[k, flip] *= -1.0
    return np.concatenate([xyzw[..., 3:], xyzw[..., :3]], axis=-1)


def posed_vertices(body: SmplxBody, frame: int) -> NDArray[np.float64]:
    """World vertex positions at ``frame`` by linear blend skinning (what a renderer computes)."""
    from scipy.spatial.transform import Rotation

    wxyz = body.bone_wxyz[frame]
    rot = Rotation.from_quat(np.concatenate([wxyz[:, 1:], wxyz[:, :1]], axis=1)).as_matrix()
    skin = body.skin
    local = skin.vertices[:, None, :] - skin.bind_joints[skin.joints]  # (V, 4, 3)
    moved = np.einsum("vkij,vkj->vki", rot[skin.joints], local) + body.bone_positions[frame][skin.joints]
    out: NDArray[np.float64] = np.einsum("vk,vki->vi", skin.weights, moved)
    return out


def smplx_bodies(model_dir: Path, parameters: Mapping[str, Mapping[str, NDArray[Any]]]) -> dict[str, SmplxBody]:
    """The bodies of several characters (parameters by character name), one model per gender."""
    models = SmplxModels(model_dir)
    return {name: models.body(params) for name, params in parameters.items()}


def run_bodies(folder: Path, names: Sequence[str], models: SmplxModels) -> dict[str, SmplxBody]:
    """The bodies of a run folder's characters, from their ``<slug>.smplx.npz`` files."""
    from storyteller.sim.run_folder_names import SMPLX_SUFFIX, file_slug

    bodies = {}
    for name in names:
        path = folder / f"{file_slug(name)}{SMPLX_SUFFIX}"
        if not path.is_file():
            raise SmplxModelError(f"{path}: not found (the SMPL-X parameters of {name!r} that `storyteller run` writes)")
        bodies[name] = models.body(load_parameters(path))
    return bodies

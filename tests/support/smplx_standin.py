"""A stand-in SMPL-X model file built on our own skeleton, for testing the SMPL-X export path.

The real SMPL-X model files need a licence and cannot be shipped or installed, so tests write
this stand-in instead and load it with the real ``smplx`` package (``smplx.create(...,
model_type="smplx", ext="npz")``). It has the keys, shapes and dtypes that ``smplx`` 0.1.28
reads from ``SMPLX_<GENDER>.npz`` (v1.1 layout: 300 shape + 100 expression directions):

======================== =================== ===========================================
key                      shape               content here
======================== =================== ===========================================
v_template               (10475, 3)          points along our bones (body frame, metres)
f                        (20908, 3)          valid but meaningless triangles
shapedirs                (10475, 3, 400)     beta 0 scales height about the floor; rest 0
posedirs                 (10475, 3, 486)     zeros (no pose correctives)
J_regressor              (55, 10475)         each joint = mean of 4 vertices around it
weights                  (10475, 55)         each vertex rigidly bound to one joint
kintree_table            (2, 55)             the SMPL-X parents (row 0), joint ids (row 1)
hands_componentsl / r    (45, 45)            identity PCA basis
hands_meanl / r          (45,)               a slight finger curl
lmk_faces_idx            (51,)               face ids
lmk_bary_coords          (51, 3)             barycentric thirds
dynamic_lmk_faces_idx    (79, 17)            face ids
dynamic_lmk_bary_coords  (79, 17, 3)         barycentric thirds
======================== =================== ===========================================

With zero betas the first 22 regressed joints are exactly our rest joints
(``storyteller.sim.body.skeleton.rest_positions()``), so posing the stand-in with our exported parameters
must reproduce our own forward kinematics. Not a body model anyone should render.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from storyteller.sim.body.skeleton import NUM_JOINTS, PARENTS, rest_positions
from storyteller.sim.world.character_track import write_npz

NUM_VERTICES = 10475
NUM_FACES = 20908
NUM_MODEL_JOINTS = 55
NUM_SHAPE_DIRS = 400  # 300 shape + 100 expression (SMPL-X v1.1 npz)
NUM_POSE_DIRS = 486  # 54 non-root joints x 9
FINGERS = ("index", "middle", "pinky", "ring", "thumb")  # SMPL-X hand joint order
# SMPL-X parents of joints 22..54: jaw and eyes hang from the head, fingers from the wrists.
_HAND_PARENTS_LEFT = (20, 25, 26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38)
MODEL_PARENTS: tuple[int, ...] = (
    *PARENTS,
    15,
    15,
    15,
    *_HAND_PARENTS_LEFT,
    *(21 if p == 20 else p + 15 for p in _HAND_PARENTS_LEFT),
)
_VERTS_PER_JOINT = 4
_JOINT_SPREAD = 0.01  # metres between a joint and its 4 regressor vertices


def standin_joint_positions() -> np.ndarray:
    """Rest positions (55, 3) of all SMPL-X joints in the body frame; the first 22 are ours."""
    body = rest_positions()
    joints = np.zeros((NUM_MODEL_JOINTS, 3))
    joints[:NUM_JOINTS] = body
    head = body[15]
    joints[22] = head + np.array([0.0, -0.03, 0.05])  # jaw
    joints[23] = head + np.array([0.03, 0.05, 0.08])  # left eye
    joints[24] = head + np.array([-0.03, 0.05, 0.08])  # right eye
    # Finger bases across the palm (x along the arm, z across it), three 3 cm segments each.
    bases = {"index": 0.025, "middle": 0.005, "pinky": -0.035, "ring": -0.015}
    for side, wrist_idx, first in ((1.0, 20, 25), (-1.0, 21, 40)):
        wrist = body[wrist_idx]
        for f, finger in enumerate(FINGERS):
            if finger == "thumb":
                base = wrist + np.array([side * 0.03, -0.01, 0.035])
            else:
                base = wrist + np.array([side * 0.09, 0.0, bases[finger]])
            for k in range(3):
                joints[first + 3 * f + k] = base + np.array([side * 0.03 * k, 0.0, 0.0])
    return joints


def standin_model_arrays(seed: int = 0) -> dict[str, np.ndarray]:
    """All arrays of the stand-in model (see the module docstring), deterministic for ``seed``."""
    rng = np.random.default_rng(seed)
    joints = standin_joint_positions()
    v = np.zeros((NUM_VERTICES, 3))
    owner = np.zeros(NUM_VERTICES, dtype=np.int64)
    regressor = np.zeros((NUM_MODEL_JOINTS, NUM_VERTICES))
    spread = _JOINT_SPREAD * np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], dtype=float)
    for j in range(NUM_MODEL_JOINTS):
        ids = np.arange(j * _VERTS_PER_JOINT, (j + 1) * _VERTS_PER_JOINT)
        v[ids] = joints[j] + spread
        owner[ids] = j
        regressor[j, ids] = 1.0 / _VERTS_PER_JOINT
    # The remaining vertices: a jittered cloud along each bone, bound to the bone's parent joint.
    rest_ids = np.arange(NUM_MODEL_JOINTS * _VERTS_PER_JOINT, NUM_VERTICES)
    child = 1 + rng.integers(0, NUM_MODEL_JOINTS - 1, size=rest_ids.size)
    parent = np.array(MODEL_PARENTS)[child]
    t = rng.random(rest_ids.size)[:, None]
    v[rest_ids] = (
        joints[parent] * (1 - t) + joints[child] * t + rng.normal(0.0, 0.03, (rest_ids.size, 3))
    )
    owner[rest_ids] = parent

    weights = np.zeros((NUM_VERTICES, NUM_MODEL_JOINTS), dtype=np.float32)
    weights[np.arange(NUM_VERTICES), owner] = 1.0
    shapedirs = np.zeros((NUM_VERTICES, 3, NUM_SHAPE_DIRS), dtype=np.float32)
    shapedirs[:, 1, 0] = 0.02 * v[:, 1]  # beta 0: +2 % height per unit
    i = np.arange(NUM_FACES)
    faces = np.stack([i, i + 1, i + 2], axis=1) % NUM_VERTICES
    kintree = np.stack([np.array(MODEL_PARENTS), np.arange(NUM_MODEL_JOINTS)]).astype(np.int64)
    kintree[0, 0] = 2**32 - 1  # the real files store the root's parent as uint32 -1
    hand_mean = np.tile([0.0, 0.0, 0.1], 15)
    return {
        "v_template": v,
        "f": faces.astype(np.uint32),
        "shapedirs": shapedirs,
        "posedirs": np.zeros((NUM_VERTICES, 3, NUM_POSE_DIRS), dtype=np.float32),
        "J_regressor": regressor,
        "weights": weights,
        "kintree_table": kintree.astype(np.uint32),
        "hands_componentsl": np.eye(45),
        "hands_componentsr": np.eye(45),
        "hands_meanl": hand_mean,
        "hands_meanr": hand_mean.copy(),
        "lmk_faces_idx": (np.arange(51) * 37).astype(np.int64),
        "lmk_bary_coords": np.full((51, 3), 1.0 / 3.0),
        "dynamic_lmk_faces_idx": (np.arange(79 * 17).reshape(79, 17) * 11 % NUM_FACES).astype(
            np.int64
        ),
        "dynamic_lmk_bary_coords": np.full((79, 17, 3), 1.0 / 3.0),
    }


def write_standin_model(models_root: str | Path, gender: str = "neutral", seed: int = 0) -> Path:
    """Write ``<models_root>/smplx/SMPLX_<GENDER>.npz`` (about 0.5 MB, compressed).

    That is the folder layout ``smplx.create(models_root, model_type="smplx", ext="npz")``
    expects. Returns the file's path.
    """
    folder = Path(models_root) / "smplx"
    folder.mkdir(parents=True, exist_ok=True)
    return write_npz(folder / f"SMPLX_{gender.upper()}.npz", standin_model_arrays(seed))

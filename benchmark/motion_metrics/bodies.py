"""Bodies against furniture and against each other: capsules as chains of spheres.

A body is a set of capsules between joints of the 22-joint skeleton (``CAPSULES``: the trunk,
the legs, the arms, the head), each sampled as spheres of the capsule's radius at most half a
radius apart, so a sphere set's surface lies within a few millimetres of the capsule's. A
scene object is its oriented box (``storyteller.sim.scene.model.SceneObject``: centre, size, facing).

- Penetration of a sphere into a box is ``radius - signed distance`` of its centre to the box
  (positive inside); a body's penetration in a frame is the deepest of its spheres (metres).
  A seat a character sits on (the frame's action label is a sitting one) counts only up to its
  seat surface (the cushion; the body belongs above it and against the backrest), less
  ``SEAT_SINK_M`` (the soft contact the seat-height target implies); a table or desk counts as
  its top only (``TABLE_TOP_M``: the box under it is legroom, where a seated person's legs are,
  as a chair tucked under a table puts them); and the arms
  of an action whose hands work on an object (``storyteller.sim.world.facing.needs_reach``) do not count:
  touching is the point.
- Overlap of two bodies is the deepest ``r_a + r_b - |c_a - c_b|`` over their trunk, leg and
  head spheres (arms left out: hands meet in a handshake); a hug is contact by design.

Pure numpy; frames are processed in blocks so long runs stay within memory.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import JOINT_INDEX
from storyteller.sim.scene.model import SceneObject
from storyteller.sim.world.legroom import TABLE_TOP_M, has_legroom, seat_surface

J = JOINT_INDEX
CAPSULES: tuple[tuple[str, str, float, str], ...] = (
    ("pelvis", "spine1", 0.085, "trunk"),
    ("spine1", "spine2", 0.10, "trunk"),
    ("spine2", "spine3", 0.11, "trunk"),
    ("spine3", "neck", 0.09, "trunk"),
    ("left_hip", "right_hip", 0.08, "trunk"),
    ("neck", "head", 0.05, "head"),
    ("head", "head", 0.10, "head"),
    ("left_hip", "left_knee", 0.07, "leg"),
    ("right_hip", "right_knee", 0.07, "leg"),
    ("left_knee", "left_ankle", 0.05, "leg"),
    ("right_knee", "right_ankle", 0.05, "leg"),
    ("left_ankle", "left_foot", 0.04, "leg"),
    ("right_ankle", "right_foot", 0.04, "leg"),
    ("left_shoulder", "left_elbow", 0.045, "arm"),
    ("right_shoulder", "right_elbow", 0.045, "arm"),
    ("left_elbow", "left_wrist", 0.035, "arm"),
    ("right_elbow", "right_wrist", 0.035, "arm"),
    ("left_wrist", "left_wrist", 0.045, "arm"),
    ("right_wrist", "right_wrist", 0.045, "arm"),
)
"""(joint, joint, radius in metres, part) of each capsule: our own round figures for an adult
of about 1.72 m (the skeleton's rest proportions); a joint twice is a sphere (head, hand)."""
BLOCK_FRAMES = 256
SEAT_SINK_M = 0.08
"""How far under its seat surface a seated body's capsules may reach into the seat it sits on:
the seat-height target (the pelvis joint 9 cm above the surface, ``interactions.PELVIS_ABOVE_SEAT_M``)
puts the hip joints 1 cm above it, so the rigid hip capsule (8 cm radius) reaches 7 cm under
it and the thighs sloping to the knees about 8 cm: buttocks, thighs and cushion are soft."""
CONTACT_ACTIONS = frozenset({"hug"})
"""Partner actions whose bodies touch by design: overlap between two characters both doing
one of these is not counted."""


@dataclass(frozen=True)
class SphereBody:
    """Sphere samples of ``CAPSULES``: joint pair (S, 2), blend weight (S,), radius (S,), arm (S,)."""

    pairs: NDArray[np.int64]
    weights: NDArray[np.float64]
    radii: NDArray[np.float64]
    arm: NDArray[np.bool_]

    def centres(self, joints: NDArray[np.float64]) -> NDArray[np.float64]:
        """Sphere centres (F, S, 3) of ``joints`` (F, 22, 3)."""
        j = np.asarray(joints, dtype=np.float64)
        w = self.weights[None, :, None]
        return np.asarray(j[:, self.pairs[:, 0]] * (1.0 - w) + j[:, self.pairs[:, 1]] * w)


def sphere_body(rest_lengths: dict[tuple[str, str], float] | None = None) -> SphereBody:
    """The spheres of ``CAPSULES``, spaced at most half a radius along a capsule whose length
    ``rest_lengths`` gives (default: 0.45 m, longer than any of the skeleton's bones)."""
    pairs, weights, radii, arm = [], [], [], []
    for a, b, r, part in CAPSULES:
        length = 0.0 if a == b else (rest_lengths or {}).get((a, b), 0.45)
        n = max(1, int(np.ceil(length / (0.5 * r))) + 1) if length > 0 else 1
        for t in np.linspace(0.0, 1.0, n):
            pairs.append((J[a], J[b]))
            weights.append(float(t))
            radii.append(r)
            arm.append(part == "arm")
    return SphereBody(np.array(pairs, dtype=np.int64), np.array(weights), np.array(radii), np.array(arm))


@dataclass(frozen=True)
class Box:
    """An oriented box: centre (3,), half sizes (3,), the unit xy axes of its width and depth."""

    centre: NDArray[np.float64]
    half: NDArray[np.float64]
    right: NDArray[np.float64]
    facing: NDArray[np.float64]

    @classmethod
    def of(cls, obj: SceneObject, top: float | None = None, bottom: float | None = None) -> Box:
        """``obj``'s box, cut at height ``top`` (world z) and from height ``bottom`` when given."""
        lo, hi = obj.z_min if bottom is None else max(obj.z_min, bottom), obj.z_max if top is None else min(obj.z_max, top)
        hi = max(hi, lo)
        centre = np.array([obj.center[0], obj.center[1], (lo + hi) / 2.0])
        half = np.array([obj.size[0] / 2.0, obj.size[1] / 2.0, max(hi - lo, 0.0) / 2.0])
        return cls(centre, half, obj.right, np.asarray(obj.facing, dtype=np.float64))


def signed_distance(points: NDArray[np.float64], box: Box) -> NDArray[np.float64]:
    """Signed distance (...,) of ``points`` (..., 3) to ``box`` (negative inside)."""
    d = np.asarray(points, dtype=np.float64) - box.centre
    local = np.stack([d[..., :2] @ box.right, d[..., :2] @ box.facing, d[..., 2]], axis=-1)
    q = np.abs(local) - box.half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    inside = np.minimum(q.max(axis=-1), 0.0)
    return np.asarray(outside + inside)


def solid_box(obj: SceneObject) -> Box:
    """The part of ``obj``'s box a body must stay out of: the whole box, or a table's top."""
    return Box.of(obj, bottom=obj.z_max - TABLE_TOP_M) if has_legroom(obj) else Box.of(obj)


def furniture_penetration(
    centres: NDArray[np.float64], body: SphereBody, objects: Sequence[SceneObject],
    seated: NDArray[np.bool_] | None = None, hands_free: NDArray[np.bool_] | None = None,
) -> NDArray[np.float64]:
    """Deepest penetration (F,) in metres of a body's spheres ``centres`` (F, S, 3) into the
    boxes of ``objects``; ``seated`` (F,) frames cut seats at their surface, ``hands_free``
    (F,) frames leave the arms out (see the module docstring). 0 where nothing touches."""
    c = np.asarray(centres, dtype=np.float64)
    n = len(c)
    seated = np.zeros(n, dtype=bool) if seated is None else np.asarray(seated, dtype=bool)
    hands_free = np.zeros(n, dtype=bool) if hands_free is None else np.asarray(hands_free, dtype=bool)
    out = np.zeros(n)
    if n == 0 or not objects:
        return out
    reach = float(body.radii.max())
    for obj in objects:
        whole = solid_box(obj)
        cushion = Box.of(obj, seat_surface(obj) - SEAT_SINK_M) if obj.is_seat else whole
        bound = float(np.linalg.norm(whole.half)) + reach
        for lo in range(0, n, BLOCK_FRAMES):
            blk = c[lo: lo + BLOCK_FRAMES]
            near = np.linalg.norm(blk[:, 0, :2] - whole.centre[:2], axis=-1) < bound + 1.2
            if not near.any():
                continue
            idx = np.flatnonzero(near)
            pts = blk[idx]
            depth = body.radii - signed_distance(pts, whole)
            if obj.is_seat:
                sit = seated[lo + idx]
                if sit.any():
                    depth[sit] = body.radii - signed_distance(pts[sit], cushion)
            free = hands_free[lo + idx]
            if free.any():
                depth[np.ix_(free, body.arm)] = 0.0
            out[lo + idx] = np.maximum(out[lo + idx], np.maximum(depth.max(axis=1), 0.0))
    return out


def body_overlap(
    a: NDArray[np.float64], b: NDArray[np.float64], body: SphereBody,
) -> NDArray[np.float64]:
    """Deepest overlap (F,) in metres between two bodies' sphere centres ``a`` and ``b``
    (F, S, 3), arms left out; 0 where they do not touch."""
    keep = ~body.arm
    pa, pb, r = np.asarray(a)[:, keep], np.asarray(b)[:, keep], body.radii[keep]
    out = np.zeros(len(pa))
    near = np.flatnonzero(np.linalg.norm(pa[:, 0, :2] - pb[:, 0, :2], axis=-1) < 1.5)
    for lo in range(0, len(near), BLOCK_FRAMES):
        idx = near[lo: lo + BLOCK_FRAMES]
        d = np.linalg.norm(pa[idx][:, :, None, :] - pb[idx][:, None, :, :], axis=-1)
        depth = (r[:, None] + r[None, :]) - d
        out[idx] = np.maximum(depth.max(axis=(1, 2)), 0.0)
    return out


def crowd_overlaps(
    centres: Sequence[NDArray[np.float64]], body: SphereBody, contact: Sequence[NDArray[np.bool_]] | None = None,
) -> tuple[NDArray[np.float64], int]:
    """Overlap over every pair of characters (their sphere centres (F, S, 3), one length F):
    the deepest overlap per frame (F,) in metres, and the number of pairs that ever overlap.
    Frames where both of a pair are in a ``CONTACT_ACTIONS`` action (``contact``, (F,) each)
    are left out. Each frame's spheres (arms left out) go into one k-d tree, so a crowd costs
    about its spheres, not its pairs (the same figures as :func:`body_overlap` on each pair)."""
    from scipy.spatial import cKDTree

    if not centres:
        return np.zeros(0), 0
    keep = ~body.arm
    r = body.radii[keep]
    per = int(keep.sum())
    owner = np.repeat(np.arange(len(centres)), per)
    radii = np.tile(r, len(centres))
    pts = np.concatenate([np.asarray(c)[:, keep] for c in centres], axis=1)  # (F, P * S', 3)
    busy = None if contact is None else np.stack([np.asarray(f, dtype=bool) for f in contact])  # (P, F)
    out = np.zeros(len(pts))
    seen: set[tuple[int, int]] = set()
    for f in range(len(pts)):
        pairs = cKDTree(pts[f]).query_pairs(2.0 * float(r.max()), output_type="ndarray")
        if len(pairs) == 0:
            continue
        a, b = owner[pairs[:, 0]], owner[pairs[:, 1]]
        other = a != b
        if busy is not None:
            other &= ~(busy[a, f] & busy[b, f])
        pairs, a, b = pairs[other], a[other], b[other]
        if len(pairs) == 0:
            continue
        depth = radii[pairs[:, 0]] + radii[pairs[:, 1]] - np.linalg.norm(pts[f, pairs[:, 0]] - pts[f, pairs[:, 1]], axis=-1)
        hit = depth > 0
        if hit.any():
            out[f] = float(depth[hit].max())
            seen.update(zip(np.minimum(a[hit], b[hit]).tolist(), np.maximum(a[hit], b[hit]).tolist(), strict=True))
    return out, len(seen)

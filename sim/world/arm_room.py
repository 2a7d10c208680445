"""Arms kept out of the furniture: an arm whose elbow, forearm or hand would pass into a box is
swung out of it at the shoulder.

The motion layer swings the arms as in its clips, where there is no furniture: walking past a
plant, standing beside a couch or sitting down at a table, a hand goes into the box. After the
working hands are placed (``storyteller.sim.world.contacts.hand_targets``), each arm of a character whose
hands are not working on an object (``storyteller.sim.world.facing.needs_reach``) is tested against the solid
boxes of the scene (a table's or desk's top only, as the legroom rule reads them:
``storyteller.sim.world.legroom.solid_bottom``; the seat it is sitting on, sitting onto or standing up from
is left out: arms rest on it). Where the elbow, the middle of the forearm or the wrist comes
within its flesh (``ARM_FLESH_M``) plus ``ARM_CLEAR_M`` of a box, the arm turns about its shoulder
by the least rotation that takes that point out along the box's outward normal (the deepest
point first, up to ``PASSES`` times). The turn is zero at the surface and grows with the depth,
so it is as smooth in time as the animation; the elbow keeps its bend, and an arm whose
shoulder is itself in a box is left as it is. A person does the same: the arm swings in past
the plant, or rests on the table's edge.

Pure: a function of one frame's poses and the scene's boxes; deterministic. Metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from storyteller.sim.body.arm_ik import COLLAR_JOINTS, ELBOW_JOINTS, SHOULDER_JOINTS, WRIST_JOINTS
from storyteller.sim.body.skeleton import PARENTS, REST_OFFSETS
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.facing import needs_reach
from storyteller.sim.world.legroom import solid_bottom
from storyteller.sim.world.phases import CharacterState

__all__ = ["ARM_CLEAR_M", "ARM_FLESH_M", "ArmBoxes", "arm_rules", "arms_clear"]

ARM_FLESH_M = np.array([0.045, 0.035, 0.045])
"""Flesh around the elbow, the middle of the forearm and the wrist (the hand), metres."""
ARM_CLEAR_M = 0.01
"""Room kept between that flesh and a box, metres."""
ARM_REACH_M = 0.8
"""Farthest a hand's flesh reaches from the pelvis joint, horizontally (shoulder 0.19 m out, arm
0.51 m, hand, clearance: 0.76 m), metres: a body farther than this from a box's footprint is not
tested."""
ARM_BELOW_M = 0.65
"""Lowest a hand's flesh reaches below the pelvis joint (an arm hanging straight), metres."""
ARM_ABOVE_M = 1.2
"""Highest a hand's flesh reaches above the pelvis joint (an arm raised straight up), metres."""
LOW_M = 0.2
"""A box whose solid part ends this low over the floor (a rug) is under the arms' reach, metres."""
PASSES = 3


@dataclass(frozen=True)
class ArmBoxes:
    """The scene's solid boxes the arms keep out of: names, centres (B, 3), half sizes (B, 3)
    (along right, facing, up), unit xy right and facing axes (B, 2)."""

    names: tuple[str, ...]
    centres: NDArray[np.float64]
    halves: NDArray[np.float64]
    rights: NDArray[np.float64]
    facings: NDArray[np.float64]

    @classmethod
    def from_scene(cls, scene: Scene) -> ArmBoxes:
        """The boxes of ``scene``'s objects that are solid above ``LOW_M`` over its floor."""
        objs = [o for o in scene.objects if o.z_max - scene.floor_z > LOW_M]
        lo = np.array([solid_bottom(o) for o in objs], dtype=np.float64).reshape(-1)
        hi = np.array([o.z_max for o in objs], dtype=np.float64).reshape(-1)
        centres = np.array([[o.center[0], o.center[1], 0.0] for o in objs], dtype=np.float64).reshape(-1, 3)
        centres[:, 2] = (lo + hi) / 2.0
        halves = np.array([[o.size[0] / 2.0, o.size[1] / 2.0, 0.0] for o in objs], dtype=np.float64).reshape(-1, 3)
        halves[:, 2] = (hi - lo) / 2.0
        return cls(tuple(o.name for o in objs), centres, halves,
                   np.array([o.right for o in objs], dtype=np.float64).reshape(-1, 2),
                   np.array([o.facing for o in objs], dtype=np.float64).reshape(-1, 2))


@njit(cache=True)
def _signed_normal(p: NDArray[np.float64], c: NDArray[np.float64], h: NDArray[np.float64], r: NDArray[np.float64],
                   f: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:  # pragma: no cover - compiled
    """Signed distance of point ``p`` (3,) to the box of centre ``c``, half sizes ``h``, xy axes
    ``r``, ``f`` (negative inside), and the world direction (3,) that leaves the box fastest."""
    dx, dy = p[0] - c[0], p[1] - c[1]
    q = np.array([dx * r[0] + dy * r[1], dx * f[0] + dy * f[1], p[2] - c[2]])
    out = np.zeros(3)
    for k in range(3):
        out[k] = q[k] - max(-h[k], min(q[k], h[k]))
    dist = math.sqrt(out[0] ** 2 + out[1] ** 2 + out[2] ** 2)
    if dist > 1e-12:
        local = out / dist
    else:  # inside: through the nearest face
        gaps = h - np.abs(q)
        k = int(np.argmin(gaps))
        local = np.zeros(3)
        local[k] = 1.0 if q[k] >= 0.0 else -1.0
        dist = -gaps[k]
    n = np.array([local[0] * r[0] + local[1] * f[0], local[0] * r[1] + local[1] * f[1], local[2]])
    return dist, n


@njit(cache=True)
def _turn(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """The smallest rotation (3, 3) turning direction ``a`` onto ``b`` (Rodrigues; identity when parallel)."""
    a = a / max(float(np.linalg.norm(a)), 1e-12)
    b = b / max(float(np.linalg.norm(b)), 1e-12)
    axis = np.cross(a, b)
    s = float(np.linalg.norm(axis))
    if s < 1e-12:
        return np.eye(3)
    k = axis / s
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    angle = math.atan2(s, float(np.dot(a, b)))
    out: NDArray[np.float64] = np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * (kx @ kx)
    return out


@njit(cache=True)
def _swing(shoulder: NDArray[np.float64], p: NDArray[np.float64], n: NDArray[np.float64],
           need: float) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """The rotation (3, 3) about ``shoulder`` that takes arm point ``p`` ``need`` metres further
    along the unit normal ``n`` by the least turn: onto the nearest point of the circle where
    the sphere of ``p``'s distance from the shoulder meets that plane (as far along ``n`` as the
    arm goes when it cannot). Pointing straight into the box, the arm swings down (it hangs)."""
    r = p - shoulder
    length = float(np.linalg.norm(r))
    h = min(float(np.dot(n, r)) + need, length)
    rho = math.sqrt(max(length * length - h * h, 0.0))
    v = r - n * float(np.dot(n, r))  # p's offset from the normal's axis through the shoulder
    if float(np.linalg.norm(v)) < 1e-6:
        v = np.array([0.0, 0.0, -1.0]) + n * n[2]
        if float(np.linalg.norm(v)) < 1e-6:
            v = np.cross(n, np.array([1.0, 0.0, 0.0]))
    v = v / float(np.linalg.norm(v))
    return _turn(r, n * h + rho * v)


@njit(cache=True)
def _clear_arm(shoulder: NDArray[np.float64], pts: NDArray[np.float64], near: NDArray[np.bool_],
               centres: NDArray[np.float64], halves: NDArray[np.float64], rights: NDArray[np.float64],
               facings: NDArray[np.float64], flesh: NDArray[np.float64]) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """The turn (3, 3) about ``shoulder`` that takes the arm's points ``pts`` (elbow, mid-forearm,
    wrist; (3, 3)) out of the ``near`` boxes by their ``flesh``: the deepest point first, up to
    ``PASSES`` times."""
    total = np.eye(3)
    pts = pts.copy()
    for _ in range(PASSES):
        best, at, normal = 1e-6, -1, np.zeros(3)
        for j in range(3):
            for b in range(len(near)):
                if not near[b]:
                    continue
                d, n = _signed_normal(pts[j], centres[b], halves[b], rights[b], facings[b])
                if flesh[j] - d > best:
                    best, at, normal = flesh[j] - d, j, n
        if at < 0:
            break
        turn = _swing(shoulder, pts[at], normal, best)
        for j in range(3):
            pts[j] = shoulder + turn @ (pts[j] - shoulder)
        total = turn @ total
    return total


_CHAIN = np.array((3, 6, 9, *COLLAR_JOINTS, *SHOULDER_JOINTS, *ELBOW_JOINTS, *WRIST_JOINTS), dtype=np.int64)
"""Joints from the pelvis out to the wrists, parents first (spine1, spine2, spine3, collars, ...)."""
_PARENTS = np.array(PARENTS, dtype=np.int64)
_ARM = np.array([SHOULDER_JOINTS, ELBOW_JOINTS, WRIST_JOINTS], dtype=np.int64)  # (3, 2 sides)


@njit(cache=True)
def _signed(x: float, y: float, z: float, c: NDArray[np.float64], h: NDArray[np.float64], r: NDArray[np.float64],
            f: NDArray[np.float64]) -> float:  # pragma: no cover - compiled
    """Signed distance of point (x, y, z) to the box of centre ``c``, half sizes ``h``, axes ``r``, ``f``."""
    dx, dy = x - c[0], y - c[1]
    qx = abs(dx * r[0] + dy * r[1]) - h[0]
    qy = abs(dx * f[0] + dy * f[1]) - h[1]
    qz = abs(z - c[2]) - h[2]
    out = math.sqrt(max(qx, 0.0) ** 2 + max(qy, 0.0) ** 2 + max(qz, 0.0) ** 2)
    return float(out + min(max(qx, max(qy, qz)), 0.0))


@njit(cache=True)
def _screen(rots: NDArray[np.float64], pelvis: NDArray[np.float64], skip: NDArray[np.bool_], own: NDArray[np.int64],
            centres: NDArray[np.float64], halves: NDArray[np.float64], rights: NDArray[np.float64],
            facings: NDArray[np.float64], flesh: NDArray[np.float64]) -> tuple[
                NDArray[np.bool_], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                NDArray[np.bool_]]:  # pragma: no cover - compiled
    """The boxes near (N, B) each body not ``skip``ped (its pelvis within ``ARM_REACH_M`` of the
    footprint, the box's height within ``ARM_BELOW_M`` / ``ARM_ABOVE_M`` of it; not its ``own``
    box index, -1: none) and, for the bodies with one: the arms' forward kinematics (positions
    (N, 22, 3) and global rotations (N, 22, 3, 3) of the pelvis and ``_CHAIN``, as
    ``storyteller.sim.body.skeleton.forward_kinematics`` gives them; zero elsewhere), how far (N, 2) the
    flesh of each arm's elbow, mid-forearm or wrist (``flesh``) reaches into a near box at most
    (-inf: no box near), and whether (N, 2) its shoulder is inside one."""
    n, nb = rots.shape[0], centres.shape[0]
    near = np.zeros((n, nb), dtype=np.bool_)
    pos = np.zeros((n, rots.shape[1], 3))
    glob = np.zeros((n, rots.shape[1], 3, 3))
    need = np.full((n, 2), -np.inf)
    stuck = np.zeros((n, 2), dtype=np.bool_)
    pt = np.zeros(3)
    for i in range(n):
        if skip[i]:
            continue
        found = False
        for b in range(nb):
            if b == own[i] or centres[b, 2] + halves[b, 2] < pelvis[i, 2] - ARM_BELOW_M \
                    or centres[b, 2] - halves[b, 2] > pelvis[i, 2] + ARM_ABOVE_M:
                continue
            dx, dy = pelvis[i, 0] - centres[b, 0], pelvis[i, 1] - centres[b, 1]
            qx = max(abs(dx * rights[b, 0] + dy * rights[b, 1]) - halves[b, 0], 0.0)
            qy = max(abs(dx * facings[b, 0] + dy * facings[b, 1]) - halves[b, 1], 0.0)
            if qx * qx + qy * qy < ARM_REACH_M * ARM_REACH_M:
                near[i, b] = True
                found = True
        if not found:
            continue
        pos[i, 0] = pelvis[i]
        glob[i, 0] = rots[i, 0]
        for j in _CHAIN:
            pa = _PARENTS[j]
            for r in range(3):
                acc = 0.0
                for c in range(3):
                    acc += glob[i, pa, r, c] * REST_OFFSETS[j, c]
                pos[i, j, r] = pos[i, pa, r] + acc
                for c in range(3):
                    acc = 0.0
                    for m in range(3):
                        acc += glob[i, pa, r, m] * rots[i, j, m, c]
                    glob[i, j, r, c] = acc
        for side in range(2):
            s, e, w = _ARM[0, side], _ARM[1, side], _ARM[2, side]
            for b in range(nb):
                if not near[i, b]:
                    continue
                if _signed(pos[i, s, 0], pos[i, s, 1], pos[i, s, 2], centres[b], halves[b], rights[b], facings[b]) < 0.0:
                    stuck[i, side] = True
                for k in range(3):
                    t = 0.5 * k
                    for c in range(3):
                        pt[c] = pos[i, e, c] + t * (pos[i, w, c] - pos[i, e, c])
                    v = flesh[k] - _signed(pt[0], pt[1], pt[2], centres[b], halves[b], rights[b], facings[b])
                    if v > need[i, side]:
                        need[i, side] = v
    return near, pos, glob, need, stuck


def arm_rules(c: CharacterState) -> tuple[bool, str | None]:
    """(whether ``c``'s hands work on an object now, the seat its arms may rest on) for
    :func:`arms_clear`: hands work while it interacts in an action that needs them on the object;
    the seat is its assignment's while it sits down, sits or stands up."""
    a = c.assignment
    if a is None or c.phase not in ("transition_in", "interacting", "transition_out"):
        return False, None
    working = c.phase == "interacting" and needs_reach(a.action)
    return working, a.seat


def arms_clear(boxes: ArmBoxes, pelvis: NDArray[np.float64], rots: NDArray[np.float64],
               skip: Sequence[bool], own: Sequence[str | None]) -> NDArray[np.float64]:
    """Local rotations (N, 22, 3, 3) with the arms of the characters not ``skip``ped turned out
    of ``boxes`` at the shoulder (see the module docstring); ``own`` (N,): a box name each
    character's arms may rest on (its seat), or None. The input itself when nothing moves."""
    n, nb = len(pelvis), len(boxes.names)
    if n == 0 or nb == 0:
        return rots
    p = np.ascontiguousarray(pelvis, dtype=np.float64)
    index = {name: k for k, name in enumerate(boxes.names)}
    mine = np.array([-1 if name is None else index.get(name, -1) for name in own], dtype=np.int64)
    near, pos, glob, need, stuck = _screen(np.ascontiguousarray(rots, dtype=np.float64), p, np.asarray(skip, dtype=np.bool_),
                                           mine, boxes.centres, boxes.halves, boxes.rights, boxes.facings,
                                           ARM_FLESH_M + ARM_CLEAR_M)
    out = rots
    for row, side in zip(*np.nonzero((need > 1e-6) & ~stuck), strict=True):
        e, w = pos[row, ELBOW_JOINTS[side]], pos[row, WRIST_JOINTS[side]]
        total = _clear_arm(pos[row, SHOULDER_JOINTS[side]], np.stack([e, (e + w) / 2.0, w]), near[row], boxes.centres,
                           boxes.halves, boxes.rights, boxes.facings, ARM_FLESH_M + ARM_CLEAR_M)
        if out is rots:
            out = np.array(rots, copy=True)
        collar, sh = COLLAR_JOINTS[side], SHOULDER_JOINTS[side]
        out[row, sh] = glob[row, collar].T @ (total @ glob[row, sh])
    return out

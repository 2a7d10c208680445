"""Room around a seat: which way to sit on a seat with no back, feet kept out of the furniture
around a seat, and a way onto the seat that goes round the furniture.

A seated adult's knees reach about 0.45 m ahead of the hips and its shins and feet hang in front
of the seat down to the floor (``LEG_REACH_M``, ``LEG_HALF_WIDTH_M``). Two rules, both general
(no furniture label names a seat; a table's or desk's box is legroom under its top, as the
benchmark's furniture measure reads scene boxes: ``has_legroom``):

- **which way** (``sitting_yaw``): a seat with no back (its box ends within ``BACKLESS_M`` of its
  seat surface: a stool, a bench) is sat on facing the planner's way when the room in front of it
  is clear; when another object's solid box takes that room (a stool 5 cm from a bar counter's
  solid face), the body turns by one of ``TURNS`` whose room is clear: the one that backs it onto
  the seat from where it stood (else the smallest, left before right), else the one whose room
  is least taken. A seat with a back is always sat on facing its front;
- **feet out of other boxes** (``feet_clear_of``): an ankle on the floor inside, or closer than
  ``FOOT_CLEAR_M`` to, the footprint of floor-standing furniture other than the seat (a foot
  under the couch beside an armchair) moves straight out of it, by the least distance;
- **onto the seat round furniture** (``sit_via``): sitting down, the body goes from where it
  stood to the seat while it lowers (and back standing up). When that straight way passes
  within ``PASS_CLEAR_M`` of a box solid at the lowering body's height (a chair tucked under a
  table sat on from beside the table's end: the hips cross the table's top), it goes by a corner
  instead: first across or along the seat's facing, then the other way (the first of the two
  corners whose legs are both clear and pass no nearer to another body than the straight way),
  so the body goes round the box's corner. The corner is chosen once, when the body starts to
  sit down (``CharacterState.seat_via``), and kept until it has stood up.

Pure geometry of the scene's boxes; deterministic. Distances metres, angles radians.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.scene.model import SceneObject

BACKLESS_M = 0.1
"""A seat whose box ends at most this far above its seat surface has no back to sit against."""
LEG_REACH_M = 0.5
"""How far ahead of the seated pelvis the knees and shins reach (knee joint ~0.45 m, plus its
flesh), metres."""
LEG_HALF_WIDTH_M = 0.18
"""Half the width the two legs take beside each other (hip joints 0.09 m off the middle, plus a
knee's flesh), metres."""
KNEE_ABOVE_SEAT_M = 0.12
"""Highest a seated knee's flesh reaches above the seat surface, metres."""
TABLE_TOP_M = 0.05
"""Thickness of a table's or desk's top: the box below it is legroom."""
LATTICE_M = 0.05
"""Spacing of the points that sample the room in front of a seat, metres."""
TURNS = tuple(math.radians(d) for d in (0, 45, -45, 90, -90, 135, -135, 180))
"""Turns from the planner's facing tried on a seat with no back, in order of preference."""
FLOOR_COVER_M = 0.05
"""An object whose top is this low over the seat's floor is under the feet (a rug), not in their way."""
CLEAR_M = 0.01
"""Room taken by less than this counts as clear, metres."""
PASS_CLEAR_M = 0.15
"""Least distance from the way onto a seat to a box solid at the lowering body's height (hips and
thighs), metres."""
BODY_NEAR_M = 1.0
"""A corner of the way onto a seat that stays this far from every other body is never too near one."""
PASS_HEIGHT_M = 0.45
"""How far above the seat surface the lowering body's hips and thighs reach, metres."""
FOOT_CLEAR_M = 0.08
"""Least distance from a floor-standing object's footprint to an ankle on the floor (the foot's
half width and flesh), metres."""


def has_legroom(obj: SceneObject) -> bool:
    """Whether ``obj`` is a top on legs (a table or a desk, by its label): the space under its top
    (below ``TABLE_TOP_M``) is legroom, where seated legs and feet belong."""
    return any(w in ("table", "desk") for w in obj.label.split("_"))


def solid_bottom(obj: SceneObject) -> float:
    """World height from which ``obj``'s box is solid: its bottom, or its top's underside."""
    return obj.z_max - TABLE_TOP_M if has_legroom(obj) else obj.z_min


def seat_surface(obj: SceneObject) -> float:
    """World height of ``obj``'s seat surface (its bottom plus its seat offset)."""
    return obj.z_min + obj.sit_offset_vertical


def is_backless(seat: SceneObject) -> bool:
    """Whether ``seat`` has no back: its box ends within ``BACKLESS_M`` of its seat surface."""
    return seat.z_max <= seat_surface(seat) + BACKLESS_M


def _inside_depth(obj: SceneObject, pts: NDArray[np.float64]) -> NDArray[np.float64]:
    """How deep (m) each xy point (K, 2) lies inside ``obj``'s footprint (0 outside)."""
    local = obj.to_local(pts)
    q = np.abs(local) - np.array([obj.size[0] / 2.0, obj.size[1] / 2.0])
    return np.asarray(np.maximum(-q.max(axis=-1), 0.0))


def legroom_taken(seat: SceneObject, objects: Sequence[SceneObject], place: Sequence[float] | NDArray[np.float64], yaw: float) -> float:
    """How deep (m) other objects' solid boxes reach into the room of the legs of a body seated at
    ``place`` (its pelvis, xy) on ``seat`` facing ``yaw``: from the seat's edge out to
    ``LEG_REACH_M``, ``LEG_HALF_WIDTH_M`` either side, from the floor to ``KNEE_ABOVE_SEAT_M`` over
    the seat surface. 0 when the room is clear."""
    u = np.array([math.cos(yaw), math.sin(yaw)])
    s = np.array([-u[1], u[0]])
    p = np.asarray(place, dtype=np.float64)
    edge = float(_inside_depth(seat, p[None])[0])  # about where the seat ends ahead of the pelvis
    edge = min(edge, LEG_REACH_M)
    along = np.arange(edge, LEG_REACH_M + 1e-9, LATTICE_M)
    side = np.arange(-LEG_HALF_WIDTH_M, LEG_HALF_WIDTH_M + 1e-9, LATTICE_M)
    a, b = np.meshgrid(along, side, indexing="ij")
    pts = p + a.reshape(-1, 1) * u + b.reshape(-1, 1) * s
    top = seat_surface(seat) + KNEE_ABOVE_SEAT_M
    taken = 0.0
    for obj in objects:
        if obj.name == seat.name or solid_bottom(obj) >= top or obj.z_max <= seat.z_min + FLOOR_COVER_M:
            continue
        if float(np.linalg.norm(obj.center_xy - p)) > LEG_REACH_M + math.hypot(obj.size[0], obj.size[1]) / 2.0:
            continue
        taken = max(taken, float(_inside_depth(obj, pts).max(initial=0.0)))
    return taken


def sitting_yaw(seat: SceneObject, objects: Sequence[SceneObject], place: Sequence[float] | NDArray[np.float64],
                planned: float, stood: Sequence[float] | NDArray[np.float64] | None = None) -> float | None:
    """The yaw to sit on ``seat`` at ``place`` with, when it differs from the ``planned`` one (see
    the module docstring); None: sit as planned. Given where the body ``stood`` before sitting
    down, of the turns whose room is clear the one nearest to facing away from the seat towards
    that point is taken: the body backs onto the seat, its legs ending where it stood."""
    if not is_backless(seat) or legroom_taken(seat, objects, place, planned) < CLEAR_M:
        return None
    best, best_taken = planned, math.inf
    clear: list[float] = []
    for turn in TURNS[1:]:
        yaw = math.atan2(math.sin(planned + turn), math.cos(planned + turn))
        taken = legroom_taken(seat, objects, place, yaw)
        if taken < CLEAR_M:
            clear.append(yaw)
        elif taken < best_taken - 1e-9:
            best, best_taken = yaw, taken
    if clear:
        away = np.asarray(stood, dtype=np.float64) - np.asarray(place, dtype=np.float64) if stood is not None else None
        if away is None or float(np.linalg.norm(away)) < 1e-6:
            return clear[0]
        back = math.atan2(float(away[1]), float(away[0]))
        return min(clear, key=lambda y: abs(math.remainder(y - back, 2.0 * math.pi)))  # first of equals: TURNS order
    return best if best_taken < legroom_taken(seat, objects, place, planned) else None


def feet_clear_of(ankles: NDArray[np.float64], low: NDArray[np.bool_], seat: SceneObject,
                  objects: Sequence[SceneObject], toes: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """``ankles`` (2, 3) with each one on the floor (``low``) moved out of the footprints, grown by
    ``FOOT_CLEAR_M``, of the objects other than ``seat`` solid down to its height (see the module
    docstring), its toe (``toes``: offsets (2, 3) from the ankle) with it. The seat's own box is
    ``storyteller.sim.world.contacts.seat_pelvis``'s business."""
    out = np.array(ankles, dtype=np.float64)
    offsets = np.zeros_like(out) if toes is None else np.asarray(toes, dtype=np.float64)
    for leg in range(len(out)):
        if not low[leg]:
            continue
        for obj in objects:
            if obj.name == seat.name or solid_bottom(obj) > out[leg, 2] + FOOT_CLEAR_M or obj.z_max < out[leg, 2]:
                continue
            pts = out[leg, :2] + np.stack([np.zeros(2), offsets[leg, :2]])
            local = obj.to_local(pts)
            half = np.array([obj.size[0] / 2.0, obj.size[1] / 2.0]) + FOOT_CLEAR_M
            gap = half - np.abs(local)  # (2 points, 2 axes): positive on both axes inside
            inside = gap.min(axis=1) > 0.0
            if not inside.any():
                continue
            deep = int(np.argmax(np.where(inside, gap.min(axis=1), -np.inf)))
            k = int(np.argmin(gap[deep]))
            sign = 1.0 if local[deep, k] >= 0.0 else -1.0
            push = float(np.max(half[k] - sign * local[inside, k]))
            axis = np.asarray(obj.right if k == 0 else obj.facing, dtype=np.float64)
            out[leg, :2] += sign * push * axis
    return out


def _blocked(seat: SceneObject, objects: Sequence[SceneObject], a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """How deep (m) segment ``a``-``b`` (xy) passes into the footprints, grown by ``PASS_CLEAR_M``,
    of the boxes other than ``seat`` solid between the seat surface and ``PASS_HEIGHT_M`` over it."""
    lo, hi = seat_surface(seat), seat_surface(seat) + PASS_HEIGHT_M
    n = max(2, int(math.ceil(float(np.linalg.norm(b - a)) / LATTICE_M)) + 1)
    pts = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    deepest = 0.0
    for obj in objects:
        if obj.name == seat.name or solid_bottom(obj) >= hi or obj.z_max <= lo:
            continue
        local = obj.to_local(pts)
        gap = np.array([obj.size[0] / 2.0, obj.size[1] / 2.0]) + PASS_CLEAR_M - np.abs(local)
        deepest = max(deepest, float(np.max(gap.min(axis=1), initial=0.0)))
    return deepest


def _nearest_body(bodies: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """Least distance (m) from segment ``a``-``b`` to the points ``bodies`` (K, 2) (inf: none)."""
    if len(bodies) == 0:
        return math.inf
    ab = b - a
    t = np.clip((bodies - a) @ ab / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return float(np.min(np.linalg.norm(bodies - (a + t[:, None] * ab), axis=1)))


def sit_via(seat: SceneObject, objects: Sequence[SceneObject], anchor: Sequence[float] | NDArray[np.float64],
            place: Sequence[float] | NDArray[np.float64],
            bodies: Sequence[Sequence[float]] | NDArray[np.float64] = ()) -> NDArray[np.float64] | None:
    """The corner (xy) the way from ``anchor`` (where the body stood) onto ``place`` on ``seat``
    goes by, or None: straight (see the module docstring). A corner that passes nearer to one of
    the other ``bodies`` (xy points) than the straight way does is not taken."""
    a, b = np.asarray(anchor, dtype=np.float64), np.asarray(place, dtype=np.float64)
    if _blocked(seat, objects, a, b) <= 0.0:
        return None
    others = np.asarray(bodies, dtype=np.float64).reshape(-1, 2)
    straight = _nearest_body(others, a, b)
    f = np.asarray(seat.facing, dtype=np.float64)
    for via in (a + f * float((b - a) @ f), b + f * float((a - b) @ f)):
        if _blocked(seat, objects, a, via) > 0.0 or _blocked(seat, objects, via, b) > 0.0:
            continue
        if min(_nearest_body(others, a, via), _nearest_body(others, via, b)) < min(straight, BODY_NEAR_M):
            continue
        return np.asarray(via)
    return None


def along_way(a: NDArray[np.float64], via: NDArray[np.float64] | None, b: NDArray[np.float64], u: float) -> NDArray[np.float64]:
    """The point a share ``u`` (0-1) of the way from ``a`` to ``b`` (by ``via`` when given) along it."""
    if via is None:
        return np.asarray(a + u * (b - a))
    first, second = float(np.linalg.norm(via - a)), float(np.linalg.norm(b - via))
    total = first + second
    d = u * total
    if total <= 0.0:
        return np.asarray(a.copy())
    if d <= first:
        return np.asarray(a + (d / first) * (via - a)) if first > 0.0 else np.asarray(via.copy())
    return np.asarray(via + ((d - first) / second) * (b - via))


__all__ = ["along_way", "feet_clear_of", "has_legroom", "is_backless", "legroom_taken", "sit_via", "sitting_yaw",
           "solid_bottom"]

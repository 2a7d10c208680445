"""How candidate places (seats) stand to the things and people an instruction names, from geometry.

Pure and deterministic: scene objects and character points in, numbers and kept candidates out.
The words that state a relation are read elsewhere (``storyteller.agents.relation_words``); here a relation
is only a kind and its references:

- ``nearest`` / ``near``: the gap from a candidate's footprint to the nearest reference
  (another object's footprint, or a character's point); ``nearest`` keeps the candidates within
  :data:`TIE_M` of the least gap, ``near`` those within :data:`NEAR_M` (else the nearest);
- ``farthest``: within :data:`TIE_M` of the greatest gap;
- ``facing``: the candidate's front points at the reference (the angle between its facing
  and the direction to the reference's centre under :data:`FACING_DEG`); of those, the ones
  facing it most squarely (within :data:`SQUARE_TIE_DEG`), and of those the nearest;
- ``between`` (two references): the least distance from the candidate's centre to the middle
  of the segment joining the references (within :data:`TIE_M`);
- ``left`` / ``right``: on that side of a reference that has a front (an object with a facing, or
  a character with the facing of the seat they sit on): the candidate's centre lies more to that
  side, in the reference's own frame, than in front of or behind it, past the reference's half
  width (right = the facing turned clockwise, as the spatial API's ``get_area_right_of``). A
  reference without a front states no side.

:func:`keep_satisfying` applies every stated relation in turn and never empties the set: a
relation that no candidate meets (or whose references are missing) leaves the set as it was,
so the check only ever narrows towards what the words say.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.scene_graph import footprint_distance, point_footprint_distance

RelationKind = Literal["nearest", "near", "farthest", "facing", "between", "left", "right"]

TIE_M = 0.3
"""Gaps (m) within this of the best count as equally near / far (an instruction's "nearest" is
not a 5 cm decision)."""
NEAR_M = 1.0
"""Gap (m) under which a place counts as near a reference (the scene graph's ``close to``)."""
FACING_DEG = 50.0
"""Largest angle (degrees) between a seat's front and the direction to what it faces."""
SQUARE_TIE_DEG = 15.0
"""Facing candidates within this angle (degrees) of the most squarely facing one count as facing
it as squarely; of those, the nearest is kept."""


@dataclass(frozen=True)
class Reference:
    """What a relation is measured against: an object, or a character at a point."""

    name: str
    obj: SceneObject | None = None
    point: tuple[float, float] | None = None
    facing: tuple[float, float] | None = None
    """A character's front (the facing of the seat they sit on); objects use their own."""

    def center(self) -> np.ndarray:
        if self.obj is not None:
            return np.asarray(self.obj.center[:2], dtype=float)
        assert self.point is not None
        return np.asarray(self.point, dtype=float)


@dataclass(frozen=True)
class StatedRelation:
    """A relation the words state: its kind and the reference groups (one group per thing named;
    a group holds every instance of that thing, e.g. both coffee makers)."""

    kind: RelationKind
    references: tuple[tuple[Reference, ...], ...]


def gap(candidate: SceneObject, ref: Reference) -> float:
    """Horizontal gap (m) from ``candidate``'s footprint to ``ref`` (its footprint, or its point)."""
    if ref.obj is not None:
        return 0.0 if ref.obj.name == candidate.name else float(footprint_distance(candidate, ref.obj))
    assert ref.point is not None
    return float(point_footprint_distance(candidate, np.asarray(ref.point, dtype=float)))


def group_gap(candidate: SceneObject, group: Sequence[Reference]) -> float:
    """The gap to the nearest member of ``group`` (inf for an empty group)."""
    return min((gap(candidate, r) for r in group), default=math.inf)


def facing_angle(candidate: SceneObject, ref: Reference) -> float:
    """Degrees between ``candidate``'s front and the direction from its centre to ``ref``."""
    to = ref.center() - np.asarray(candidate.center[:2], dtype=float)
    norm = float(np.linalg.norm(to))
    if norm < 1e-9:
        return 180.0
    cos = float(np.dot(np.asarray(candidate.facing, dtype=float), to / norm))
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


def faces(candidate: SceneObject, group: Sequence[Reference]) -> bool:
    return any(facing_angle(candidate, r) <= FACING_DEG for r in group)


def midpoint_distance(candidate: SceneObject, first: Sequence[Reference], second: Sequence[Reference]) -> float:
    """Distance (m) from ``candidate``'s centre to the nearest midpoint of a pair of references."""
    c = np.asarray(candidate.center[:2], dtype=float)
    return min(
        (float(np.linalg.norm(c - (a.center() + b.center()) / 2.0)) for a in first for b in second),
        default=math.inf,
    )


def side_offset(candidate: SceneObject, ref: Reference) -> float | None:
    """How far (m) ``candidate``'s centre lies to ``ref``'s right (negative: its left), beyond
    ``ref``'s half width, when it lies more to the side than in front or behind; 0 when it does
    not; None when ``ref`` has no front."""
    if ref.obj is not None:
        if not ref.obj.has_facing:
            return None
        front, half = np.asarray(ref.obj.facing, dtype=float), ref.obj.size[0] / 2.0
    elif ref.facing is not None:
        front, half = np.asarray(ref.facing, dtype=float), 0.0
    else:
        return None
    right = np.array([front[1], -front[0]])
    d = np.asarray(candidate.center[:2], dtype=float) - ref.center()
    across, along = float(d @ right), float(d @ front)
    if abs(across) <= half or abs(across) - half < abs(along):
        return 0.0
    return across - half if across > 0 else across + half


def satisfying(relation: StatedRelation, candidates: Sequence[SceneObject]) -> list[SceneObject]:
    """The candidates that meet ``relation`` (see the module docstring); [] when none can."""
    groups = [g for g in relation.references if g]
    if not groups or not candidates:
        return []
    first = groups[0]
    if relation.kind in ("left", "right"):
        sign = 1.0 if relation.kind == "right" else -1.0
        return [c for c in candidates
                if any((o := side_offset(c, r)) is not None and sign * o > 0 for r in first)]  # fmt: skip
    if relation.kind in ("nearest", "near", "farthest"):
        gaps = {c.name: group_gap(c, first) for c in candidates}
        if relation.kind == "farthest":
            best = max(gaps.values())
            return [c for c in candidates if gaps[c.name] >= best - TIE_M]
        least = min(gaps.values())
        if relation.kind == "near":
            within = [c for c in candidates if gaps[c.name] <= NEAR_M]
            if within:
                return within
        return [c for c in candidates if gaps[c.name] <= least + TIE_M]
    if relation.kind == "facing":
        angles = {c.name: min(facing_angle(c, r) for r in first) for c in candidates}
        facing = [c for c in candidates if angles[c.name] <= FACING_DEG]
        if not facing:
            return []
        squarest = min(angles[c.name] for c in facing)
        facing = [c for c in facing if angles[c.name] <= squarest + SQUARE_TIE_DEG]
        gaps = {c.name: group_gap(c, first) for c in facing}
        least = min(gaps.values())
        return [c for c in facing if gaps[c.name] <= least + TIE_M]
    if len(groups) < 2:
        return []
    mids = {c.name: midpoint_distance(c, groups[0], groups[1]) for c in candidates}
    least = min(mids.values())
    return [c for c in candidates if mids[c.name] <= least + TIE_M]


def keep_satisfying(relations: Sequence[StatedRelation], candidates: Sequence[SceneObject]) -> list[SceneObject]:
    """``candidates`` narrowed by each relation in turn; a relation none meets is skipped."""
    kept = list(candidates)
    for relation in relations:
        narrowed = satisfying(relation, kept)
        if narrowed:
            kept = narrowed
    return kept


AT_M = 0.6
"""A seat within this gap (m) of a non-seat object sits at it ("at table_2")."""
SURFACE_HEIGHT_M = (0.4, 1.3)
SURFACE_AREA_M2 = 0.2


def sits_at(obj: SceneObject) -> bool:
    """Whether people sit at ``obj``: a surface (not a seat) of table height and table size."""
    return not obj.is_seat and SURFACE_HEIGHT_M[0] <= obj.z_max - obj.z_min <= SURFACE_HEIGHT_M[1] and (
        obj.width * obj.depth >= SURFACE_AREA_M2
    )


def table_of(scene: Scene, seat: SceneObject) -> SceneObject | None:
    """The thing ``seat`` sits at (a table, desk or counter within ``AT_M``; the nearest), or None."""
    near = [(gap(seat, Reference(o.name, obj=o)), o) for o in scene.objects if sits_at(o) and o.name != seat.name]
    return min((x for x in near if x[0] <= AT_M), key=lambda x: x[0], default=(0.0, None))[1]

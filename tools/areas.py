"""Areas: regions of the floor where a character may stand or sit.

An ``Area`` is a predicate over xy points (metres) plus a hint box that bounds where its points
can be, an optional list of seat slots (exact places to sit, with the seat's facing), a focus
point (what a character there looks at by default) and a short description written in the
reference expression syntax ("in front of fridge_1", "A && B", "A || B"). Areas combine with
``intersect`` and ``union``; ``storyteller.tools.position_sampling`` turns them into exact positions.

Reference distances: adjacent 0.5 m, close 1.0 m, between <= 0.5 m off the centre line.

Relaxation: a single directional area (``directional``: in front of / behind / to the left of /
to the right of one object) carries ``relaxations``, wider versions of the same relation (up to
0.8 m past the sides of the face and 2.5 m out from it, in ``RELAXED_STEPS``), each with a
measure of how far a point lies outside the strict strip. The sampler tries them, smallest
first, only when the strict area has no free reachable floor, so a character still ends up on
that side of the object in a cramped room; an area with room is sampled exactly as without
them. "adjacent to" (0.5 m) and "close to" (1.0 m) relax the same way to wider rings
(``RELAXED_ADJACENT``, ``RELAXED_CLOSE``): a thing on a stand against a wall has no floor right
beside it, and a person stands by the stand. Combined areas (``intersect``, ``union``) have no
relaxations: they keep their strict meaning.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from storyteller.sim.scene.model import SceneObject
from storyteller.tools.errors import ToolArgumentError
from storyteller.tools.scene_graph import point_footprint_distance
from storyteller.tools.value_text import show

ADJACENT_DISTANCE = 0.5  # m from the footprint
CLOSE_DISTANCE = 1.0  # m from the footprint
INTERACT_DISTANCE = 0.6  # m from the footprint, on the object's front side
EDGE_REACH = 0.45  # m past an object's inset in its supporter (0.25 body radius + 0.2)
INTERACT_SIDE_MARGIN = 0.3  # m beyond the object's sides still counted as its front
DIRECTIONAL_REACH = 1.5  # m beyond the face for in front of / behind / left of / right of
BETWEEN_OFF_LINE = 0.5  # m off the centre line
ALIGNED_BEYOND = (
    1.0  # how far past the ends "aligned with" reaches, in units of the centre distance
)
SEAT_SLOT_WIDTH = 0.6  # m of seat width per sitting person
SEAT_MATCH = 0.05  # m: a point this close to a seat slot is on it
MAX_PARTS = 32  # most single-relation areas one combined area may hold
RELAXED_STEPS = ((0.3, 1.8), (0.55, 2.15), (0.8, 2.5))
"""Relaxed directional areas, tried in this order: (m past each side of the face, m out from
the face), the strict area being (0, ``DIRECTIONAL_REACH``)."""
RELAXED_SIDE_WEIGHT = 2.0
"""How much more a metre past the side of the face counts than a metre further out, when the
sampler prefers relaxed points nearest the strict area (straight out is still "in front of";
off to the side much less so)."""

Predicate = Callable[[NDArray[np.float64]], NDArray[np.bool_]]
Box = tuple[float, float, float, float]  # xmin, ymin, xmax, ymax


@dataclass(frozen=True)
class SeatSlot:
    """One place to sit: the seat object, the pelvis xy and the facing of the seat."""

    seat: str
    position: tuple[float, float]
    facing: tuple[float, float]


@dataclass(frozen=True, eq=False)
class Area:
    """A region of the floor (see the module docstring). Immutable; combine with
    ``intersect(other)`` and ``union(other)``."""

    description: str
    predicate: Predicate = field(repr=False)
    hint: Box
    focus: tuple[float, float] | None = None
    seats: tuple[SeatSlot, ...] = ()
    free_region: bool = True
    anchors: tuple[str, ...] = ()
    parts: int = 1
    relaxations: tuple[Relaxation, ...] = ()
    """Wider versions of this area, smallest first, that the sampler tries only when this
    area has no free reachable floor (single directional relations only; see the module
    docstring)."""

    sandbox_attributes: ClassVar[frozenset[str]] = frozenset({"description", "intersect", "union"})

    def contains(self, xy: ArrayLike) -> NDArray[np.bool_]:
        """Whether xy points (N, 2) lie in the area (seat slots included)."""
        points = np.asarray(xy, dtype=float).reshape(-1, 2)
        return np.asarray(self.predicate(points), dtype=bool)

    def intersect(self, other: Area) -> Area:
        """The points in both areas. Seat slots survive when the other area contains them."""
        a, b = self, _combinable(self, other, "intersect")
        seats = [s for s in a.seats if bool(b.contains(np.array(s.position))[0])]
        seats += [
            s for s in b.seats if bool(a.contains(np.array(s.position))[0]) and s not in seats
        ]
        hint = (
            max(a.hint[0], b.hint[0]),
            max(a.hint[1], b.hint[1]),
            min(a.hint[2], b.hint[2]),
            min(a.hint[3], b.hint[3]),
        )

        def predicate(p: NDArray[np.float64]) -> NDArray[np.bool_]:
            return a.contains(p) & b.contains(p)

        return Area(
            description=f"{_wrap(a, '||')} && {_wrap(b, '||')}",
            predicate=predicate,
            hint=hint,
            focus=a.focus if a.focus is not None else b.focus,
            seats=tuple(seats),
            free_region=a.free_region and b.free_region,
            anchors=_merge(a.anchors, b.anchors),
            parts=a.parts + b.parts,
        )

    def union(self, other: Area) -> Area:
        """The points in either area; seat slots of both."""
        a, b = self, _combinable(self, other, "union")
        hint = (
            min(a.hint[0], b.hint[0]),
            min(a.hint[1], b.hint[1]),
            max(a.hint[2], b.hint[2]),
            max(a.hint[3], b.hint[3]),
        )

        def predicate(p: NDArray[np.float64]) -> NDArray[np.bool_]:
            return a.contains(p) | b.contains(p)

        return Area(
            description=f"{_wrap(a, '&&')} || {_wrap(b, '&&')}",
            predicate=predicate,
            hint=hint,
            focus=a.focus if a.focus is not None else b.focus,
            seats=a.seats + tuple(s for s in b.seats if s not in a.seats),
            free_region=(a.free_region and a.hint_nonempty) or (b.free_region and b.hint_nonempty),
            anchors=_merge(a.anchors, b.anchors),
            parts=a.parts + b.parts,
        )

    @property
    def hint_nonempty(self) -> bool:
        return self.hint[0] <= self.hint[2] and self.hint[1] <= self.hint[3]


@dataclass(frozen=True)
class Relaxation:
    """A relaxed version of a single directional area (see the module docstring)."""

    area: Area
    """The wider strip; its description is the strict area's."""
    side: float
    """Metres the strip reaches past each side of the face."""
    reach: float
    """Metres the strip reaches out from the face."""
    excess: Callable[[NDArray[np.float64]], NDArray[np.float64]] = field(repr=False)
    """How far points (N, 2) lie outside the strict area (m; past the sides counted
    ``RELAXED_SIDE_WEIGHT`` times); 0 inside it."""
    extent: str = ""
    """How far this relaxation reaches, in words for feedback ("0.8 m past its sides and 2.5 m
    out"); built from ``side`` and ``reach`` when empty."""
    ring: bool = False
    """A wider distance ring ("adjacent to" / "close to" in a cramped spot), not a strip."""

    def describe(self) -> str:
        return self.extent or f"{self.side:g} m past its sides and {self.reach:g} m out"


def _combinable(a: Area, b: object, method: str) -> Area:
    if not isinstance(b, Area):
        raise ToolArgumentError(
            f"{method}() expects an Area from a get_area_* function, got {show(b)}"
        )
    if a.parts + b.parts > MAX_PARTS:
        raise ToolArgumentError(f"an area may combine at most {MAX_PARTS} simple areas")
    return b


def _wrap(area: Area, other_operator: str) -> str:
    """Parenthesise a description that uses the other operator, so the text parses back."""
    return (
        f"({area.description})" if f" {other_operator} " in area.description else area.description
    )


def _merge(a: tuple[str, ...], b: tuple[str, ...]) -> tuple[str, ...]:
    return a + tuple(n for n in b if n not in a)


def _grown_box(obj: SceneObject, margin: float) -> Box:
    corners = obj.footprint(margin)
    return (
        float(corners[:, 0].min()),
        float(corners[:, 1].min()),
        float(corners[:, 0].max()),
        float(corners[:, 1].max()),
    )


def _focus(obj: SceneObject) -> tuple[float, float]:
    return (float(obj.center[0]), float(obj.center[1]))


# ----- single-object areas ---------------------------------------------------------------------
def within_distance(
    obj: SceneObject, distance: float, relation: str, relaxed: tuple[float, ...] = ()
) -> Area:
    """Points whose distance to the object's footprint is at most ``distance`` metres; with
    ``relaxed`` distances (m, increasing), the wider rings the sampler tries, nearest points
    first, when this one has no free reachable floor (a TV on its stand against a wall has no
    floor within 0.5 m: a person stands by the stand)."""

    def area(within: float) -> Area:
        def predicate(p: NDArray[np.float64]) -> NDArray[np.bool_]:
            return point_footprint_distance(obj, p) <= within

        return Area(f"{relation} {obj.name}", predicate, _grown_box(obj, within), _focus(obj), anchors=(obj.name,))

    def excess(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(np.maximum(point_footprint_distance(obj, p) - distance, 0.0), dtype=float)

    relaxations = tuple(
        Relaxation(area(d), 0.0, d, excess, extent=f"to {d:g} m from it", ring=True) for d in relaxed if d > distance
    )
    return replace(area(distance), relaxations=relaxations)


RELAXED_ADJACENT = (0.75, 1.0)
"""Wider rings (m) tried for "adjacent to" when the 0.5 m ring has no free reachable floor."""
RELAXED_CLOSE = (1.5,)
"""The wider ring (m) tried for "close to" when the 1.0 m ring has none."""


def adjacent_to(obj: SceneObject) -> Area:
    """Within 0.5 m of the object's footprint (relaxed to :data:`RELAXED_ADJACENT` in a cramped spot)."""
    return within_distance(obj, ADJACENT_DISTANCE, "adjacent to", RELAXED_ADJACENT)


def close_to(obj: SceneObject) -> Area:
    """Within 1.0 m of the object's footprint (relaxed to :data:`RELAXED_CLOSE` in a cramped spot)."""
    return within_distance(obj, CLOSE_DISTANCE, "close to", RELAXED_CLOSE)


_DIRECTIONS = {
    # relation: (local axis index, sign): the strip beyond the face along +-axis
    "in front of": (1, 1.0),
    "behind": (1, -1.0),
    "to the right of": (0, 1.0),
    "to the left of": (0, -1.0),
}


def _strip(obj: SceneObject, relation: str, reach: float, side: float) -> Predicate:
    """The strip beyond one face of ``obj``: from the face out to ``reach`` metres, as wide as
    the face plus ``side`` metres past each of its ends."""
    axis, sign = _DIRECTIONS[relation]
    half = (obj.width / 2.0, obj.depth / 2.0)

    def predicate(p: NDArray[np.float64]) -> NDArray[np.bool_]:
        local = obj.to_local(p)
        along = sign * local[:, axis]
        across = np.abs(local[:, 1 - axis])
        return (
            (along >= half[axis]) & (along <= half[axis] + reach) & (across <= half[1 - axis] + side)
        )

    return predicate


def _strip_excess(
    obj: SceneObject, relation: str, reach: float
) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
    """How far points lie outside ``_strip(obj, relation, reach, 0)`` (see ``Relaxation``)."""
    axis, sign = _DIRECTIONS[relation]
    half = (obj.width / 2.0, obj.depth / 2.0)

    def excess(p: NDArray[np.float64]) -> NDArray[np.float64]:
        local = obj.to_local(p)
        along = sign * local[:, axis]
        past_side = np.maximum(np.abs(local[:, 1 - axis]) - half[1 - axis], 0.0)
        out = np.maximum(along - (half[axis] + reach), 0.0) + np.maximum(half[axis] - along, 0.0)
        return np.asarray(np.hypot(RELAXED_SIDE_WEIGHT * past_side, out), dtype=float)

    return excess


def directional(obj: SceneObject, relation: str, reach: float = DIRECTIONAL_REACH) -> Area:
    """The strip swept by one face of the object's footprint, from the face out to ``reach``
    metres, as wide as that face. Directions are the object's own (its facing is its front;
    its right is the facing turned clockwise). Carries the relaxations of ``RELAXED_STEPS``
    (for a cramped room; see the module docstring)."""
    description = f"{relation} {obj.name}"

    def area(out: float, side: float) -> Area:
        return Area(
            description,
            _strip(obj, relation, out, side),
            _grown_box(obj, max(out, side)),
            _focus(obj),
            anchors=(obj.name,),
        )

    excess = _strip_excess(obj, relation, reach)
    relaxations = tuple(
        Relaxation(area(max(out, reach), side), side, max(out, reach), excess)
        for side, out in RELAXED_STEPS
    )
    return replace(area(reach, 0.0), relaxations=relaxations)


def inset_depth(obj: SceneObject, supporter: SceneObject) -> float:
    """How far (m) the object sits inside its supporter's footprint: for an object with a front,
    from the middle of its front face straight ahead to the supporter's edge; otherwise from its
    corner nearest to an edge of the supporter to that edge. 0 when it overhangs."""
    half = np.array([supporter.width / 2.0, supporter.depth / 2.0])
    if obj.has_facing:
        facing = np.array(obj.facing)
        start = supporter.to_local(obj.center_xy + facing * obj.depth / 2.0)
        direction = np.array([facing @ supporter.right, facing @ np.array(supporter.facing)])
        exits = [
            (half[i] - np.sign(direction[i]) * start[i]) / abs(direction[i])
            for i in range(2)
            if abs(direction[i]) > 1e-9
        ]
        return float(max(0.0, min(exits))) if exits else 0.0
    local = np.abs(supporter.to_local(obj.footprint()))
    return float(max(0.0, (half[None, :] - local).min()))


def to_interact_with(obj: SceneObject, supporter: SceneObject | None = None) -> Area:
    """Where a character can use the object. A seat: its seat slots. Otherwise within 0.6 m of
    its footprint (for an object on a ``supporter``: at least its inset + 0.45 m, so that a
    laptop deep on a desk is reached from the desk's edge) and, for objects with a front, on
    the front side (no further than 0.3 m past its sides)."""
    if obj.is_seat:
        return replace(to_sit_on(obj), description=f"interact with {obj.name}")
    reach = INTERACT_DISTANCE
    if supporter is not None:  # stand at the supporter's edge: body radius + a short arm's reach
        reach = max(reach, inset_depth(obj, supporter) + EDGE_REACH)

    def predicate(p: NDArray[np.float64]) -> NDArray[np.bool_]:
        near = point_footprint_distance(obj, p) <= reach
        if not obj.has_facing:
            return near
        local = obj.to_local(p)
        front = (local[:, 1] >= obj.depth / 2.0) & (
            np.abs(local[:, 0]) <= obj.width / 2.0 + INTERACT_SIDE_MARGIN
        )
        return near & front

    return Area(
        f"interact with {obj.name}",
        predicate,
        _grown_box(obj, reach),
        _focus(obj),
        anchors=(obj.name,),
    )


def seat_slots(obj: SceneObject) -> tuple[SeatSlot, ...]:
    """Sitting places of a seat: one per 0.6 m of width (a chair has one, a couch several),
    on the line ``centre + facing * depth * sit_offset_horizontal``, facing the seat's front."""
    count = max(1, int(obj.width // SEAT_SLOT_WIDTH)) if obj.width >= 2 * SEAT_SLOT_WIDTH else 1
    base = obj.seat_point()
    right = obj.right
    slots = []
    for i in range(count):
        offset = -obj.width / 2.0 + (i + 0.5) * obj.width / count if count > 1 else 0.0
        xy = base + right * offset
        slots.append(
            SeatSlot(
                obj.name, (float(xy[0]), float(xy[1])), (float(obj.facing[0]), float(obj.facing[1]))
            )
        )
    return tuple(slots)


def to_sit_on(obj: SceneObject) -> Area:
    """The seat slots of a seat object (see ``seat_slots``); no free-floor points."""
    slots = seat_slots(obj)
    points = np.array([s.position for s in slots])

    def predicate(p: NDArray[np.float64]) -> NDArray[np.bool_]:
        d: NDArray[np.float64] = np.linalg.norm(p[:, None, :] - points[None, :, :], axis=2)
        nearest: NDArray[np.float64] = d.min(axis=1)
        return nearest <= SEAT_MATCH

    xs, ys = points[:, 0], points[:, 1]
    hint = (float(xs.min()), float(ys.min()), float(xs.max()), float(ys.max()))
    return Area(
        f"sit on {obj.name}",
        predicate,
        hint,
        _focus(obj),
        seats=slots,
        free_region=False,
        anchors=(obj.name,),
    )


# ----- two-object areas -----------------------------------------------------------------------
def _line_area(a: SceneObject, b: SceneObject, t_min: float, t_max: float, relation: str) -> Area:
    c1, c2 = a.center_xy, b.center_xy
    v = c2 - c1
    length2 = float(v @ v)
    if length2 < 1e-12:
        raise ValueError(f"{a.name} and {b.name} have the same centre")

    def predicate(p: NDArray[np.float64]) -> NDArray[np.bool_]:
        t = (p - c1) @ v / length2
        off: NDArray[np.float64] = np.linalg.norm(p - (c1 + t[:, None] * v), axis=1)
        return (t >= t_min) & (t <= t_max) & (off <= BETWEEN_OFF_LINE)

    ends = np.array([c1 + t_min * v, c1 + t_max * v])
    m = BETWEEN_OFF_LINE
    hint = (
        float(ends[:, 0].min() - m),
        float(ends[:, 1].min() - m),
        float(ends[:, 0].max() + m),
        float(ends[:, 1].max() + m),
    )
    mid = (c1 + c2) / 2.0
    return Area(
        f"{relation} {a.name} and {b.name}",
        predicate,
        hint,
        (float(mid[0]), float(mid[1])),
        anchors=(a.name, b.name),
    )


def between(a: SceneObject, b: SceneObject) -> Area:
    """Points whose projection falls between the two centres and that lie <= 0.5 m off the
    line joining them."""
    return _line_area(a, b, 0.0, 1.0, "between")


def aligned_with(a: SceneObject, b: SceneObject) -> Area:
    """Points <= 0.5 m off the line through both centres, from one centre distance before the
    first object to one centre distance past the second."""
    return _line_area(a, b, -ALIGNED_BEYOND, 1.0 + ALIGNED_BEYOND, "aligned with")

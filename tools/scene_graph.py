"""Scene graph: support, vertical and horizontal relations between the objects of a scene.

Relations are directed edges ``subject --relation--> anchor`` of a networkx MultiDiGraph:

- ``on`` / ``inside``: the subject's centre lies over the anchor's footprint grown by
  ``support_xy`` and its bottom is within ``support_z`` of the anchor's top (``on``) or its
  centre height lies inside the anchor's height range (``inside``). "Inside" a surface-like
  anchor (a table, a couch, a counter) or an appliance inside a cabinet reads as ``on``.
- support levels: the floor holds level 0 (``|z_min - floor| < floor_support``); an object
  ``on`` / ``inside`` an object of level k has level k + 1; objects held by nothing (wall
  mounted) have no level.
- ``above`` / ``below``: only for objects held by nothing, against floor-standing objects whose
  footprint grown by ``hanging_xy`` contains the other's centre (both directions).
- horizontal relations, only between objects with the same supporter (the floor or the same
  anchor), bottoms within ``same_level_z`` and footprints within ``horizontal_range``:
  ``in front of`` / ``behind`` / ``to the left of`` / ``to the right of`` from the anchor's own
  facing (anchors with a front only), and ``adjacent to`` (surface distance < ``adjacent``) or
  ``close to`` (< ``close``).

All distances are metres; surface distances are between 2D footprints (see ``footprint_distance``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.box_pairs import overlapping_pairs
from storyteller.tools.footprint_geometry import centre_distances, polygon_distance, polygon_distances

if TYPE_CHECKING:  # networkx (0.1 s to import) is loaded by build_scene_graph, when a graph is built
    import networkx as nx

RELATIONS: tuple[str, ...] = (
    "on", "inside", "above", "below", "in front of", "behind",
    "to the left of", "to the right of", "adjacent to", "close to",
)  # fmt: skip
DIRECTIONAL_RELATIONS: tuple[str, ...] = (
    "in front of",
    "behind",
    "to the left of",
    "to the right of",
)

# Anchors whose "inside" is really a top surface, and (subject, anchor) label pairs meaning "on".
_SURFACE_LABELS = frozenset(
    {
        "table",
        "desk",
        "bed",
        "sofa",
        "couch",
        "bench",
        "counter",
        "bar_counter",
        "kitchen_cabinet",
        "shelf",
    }
)
_ON_PAIRS = frozenset(
    {("microwave", "cabinet"), ("coffee_maker", "cabinet"), ("coffee_machine", "cabinet"),
     ("toaster", "cabinet"), ("kettle", "cabinet")}
)  # fmt: skip


class RelationThresholds(BaseModel):
    """Thresholds of the scene graph, metres (defaults: the reference implementation's)."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    floor_support: float = Field(
        default=0.10, gt=0, description="Max |bottom - floor| for floor support."
    )
    support_xy: float = Field(default=0.2, ge=0, description="Footprint margin for on / inside.")
    support_z: float = Field(
        default=0.2, ge=0, description="Max gap between subject bottom and anchor top for on."
    )
    hanging_xy: float = Field(default=0.4, ge=0, description="Footprint margin for above / below.")
    same_level_z: float = Field(
        default=0.2, ge=0, description="Max bottom-height difference for horizontal relations."
    )
    horizontal_range: float = Field(
        default=2.0, gt=0, description="Max surface distance for horizontal relations."
    )
    directional_offset: float = Field(
        default=0.2, ge=0, description="Side margin of the directional strips."
    )
    adjacent: float = Field(
        default=0.3, gt=0, description="Surface distance below which objects are adjacent."
    )
    close: float = Field(
        default=1.0, gt=0, description="Surface distance below which objects are close."
    )


DEFAULT_THRESHOLDS = RelationThresholds()


# ----- footprint geometry (tools.footprint_geometry: the same floats one pair or many at once) ----
def footprint_distance(a: SceneObject, b: SceneObject) -> float:
    """Distance between the 2D footprints (oriented rectangles) of two objects, metres."""
    return polygon_distance(a.footprint(), b.footprint())


def vertical_gap(a: SceneObject, b: SceneObject) -> float:
    """Gap between the z ranges of two boxes, metres (0 when they overlap in height)."""
    return max(0.0, a.z_min - b.z_max, b.z_min - a.z_max)


def box_distance(a: SceneObject, b: SceneObject) -> float:
    """Surface distance between two oriented boxes (yaw-only rotation), metres.

    Computed as ``hypot(footprint distance, vertical gap)``: exact when the boxes are separated
    only horizontally or only vertically, and a close lower bound of the true distance otherwise
    (the closest footprint points and the closest heights need not belong to the same pair).
    """
    return float(np.hypot(footprint_distance(a, b), vertical_gap(a, b)))


def point_footprint_distance(obj: SceneObject, xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance from xy points (..., 2) to the object's footprint rectangle (0 inside), metres."""
    local = np.abs(obj.to_local(xy))
    dx = np.maximum(local[..., 0] - obj.width / 2.0, 0.0)
    dy = np.maximum(local[..., 1] - obj.depth / 2.0, 0.0)
    return np.hypot(dx, dy)


# ----- relations ------------------------------------------------------------------------------
def _vertical_contact(
    subject: SceneObject, anchor: SceneObject, t: RelationThresholds
) -> str | None:
    if not bool(anchor.contains_xy(subject.center_xy, margin=t.support_xy)):
        return None
    relation: str | None = None
    if abs(subject.z_min - anchor.z_max) <= t.support_z:
        relation = "on"
    elif anchor.z_min < subject.center[2] < anchor.z_max or (
        subject.z_max < anchor.z_max and subject.z_min > anchor.z_min
    ):
        relation = "inside"
    if relation == "inside" and (
        anchor.label in _SURFACE_LABELS or (subject.label, anchor.label) in _ON_PAIRS
    ):
        relation = "on"
    return relation


def directional_relation(subject: SceneObject, anchor: SceneObject, offset: float) -> str | None:
    """Where the subject's centre lies in the anchor's frame, or None (anchor without a front)."""
    if not anchor.has_facing:
        return None
    x, y = (float(v) for v in anchor.to_local(subject.center_xy))
    hw, hd = anchor.width / 2.0, anchor.depth / 2.0
    if x < -hw and abs(y) <= hd + offset:
        return "to the left of"
    if x > hw and abs(y) <= hd + offset:
        return "to the right of"
    if y > hd and abs(x) <= hw + offset:
        return "in front of"
    if y < -hd and abs(x) <= hw + offset:
        return "behind"
    return None


class SceneGraph:
    """Relations of one scene. ``graph`` nodes are object names with attributes ``label``,
    ``level`` (support level or None) and ``supporter`` (object name or None for the floor)."""

    def __init__(self, scene: Scene, thresholds: RelationThresholds, graph: nx.MultiDiGraph[str]):
        self.scene = scene
        self.thresholds = thresholds
        self.graph = graph

    def triples(self) -> list[tuple[str, str, str]]:
        """All relations as (subject, relation, anchor), in a deterministic order."""
        return [(s, str(d["relation"]), a) for s, a, d in self.graph.edges(data=True)]

    def relations_of(self, name: str) -> list[tuple[str, str]]:
        """(relation, anchor) pairs where ``name`` is the subject."""
        return [(str(d["relation"]), a) for _, a, d in self.graph.out_edges(name, data=True)]

    def subjects(self, relation: str, anchor: str) -> list[str]:
        """Objects that stand in ``relation`` to ``anchor``."""
        return [
            s for s, _, d in self.graph.in_edges(anchor, data=True) if d["relation"] == relation
        ]

    def supporter(self, name: str) -> str | None:
        """The object ``name`` stands on or in (None: the floor or nothing)."""
        value = self.graph.nodes[name]["supporter"]
        return None if value is None else str(value)

    def supported_by(self, name: str) -> list[str]:
        """Objects standing on or in ``name``."""
        return [n for n, d in self.graph.nodes(data=True) if d["supporter"] == name]

    def level(self, name: str) -> int | None:
        """Support level: 0 on the floor, k + 1 on an object of level k, None if held by nothing."""
        value = self.graph.nodes[name]["level"]
        return None if value is None else int(value)


def _levels(scene: Scene, on_floor: set[str], supporter: dict[str, str]) -> dict[str, int | None]:
    """Support level of every object: follow the supporter chain (iteratively: a stack of
    thousands of boxes is no recursion) to the floor (level 0), to an object held by nothing or
    to a cycle (both None)."""
    levels: dict[str, int | None] = {}
    for obj in scene.objects:
        path: list[str] = []
        on_path: set[str] = set()
        name = obj.name
        while name not in levels:
            if name in on_floor:
                levels[name] = 0
                break
            if name not in supporter or name in on_path:  # held by nothing, or a support cycle
                levels[name] = None
                break
            path.append(name)
            on_path.add(name)
            name = supporter[name]
        base = levels[name]
        for below, above in enumerate(reversed(path), start=1):
            if above != name:  # a cycle's entry point keeps its None
                levels[above] = None if base is None else base + below
    return levels


_INDEX_SLACK = 1e-6
"""Metres the index grows every box by beyond a relation's reach, so that rounding never makes
it skip a pair the exact test would accept (the index is only a filter)."""


def _footprint_boxes(
    objects: tuple[SceneObject, ...] | list[SceneObject], grow: float, margin: float = 0.0
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Axis-aligned (lo, hi) corners (N, 2) of the footprints grown by ``margin``, then by ``grow``."""
    if not objects:
        empty = np.zeros((0, 2))
        return empty, empty
    corners = np.stack([o.footprint(margin) for o in objects])
    pad = grow + _INDEX_SLACK
    return corners.min(axis=1) - pad, corners.max(axis=1) + pad


def _centre_boxes(
    objects: tuple[SceneObject, ...] | list[SceneObject],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    centres = np.array([o.center[:2] for o in objects], dtype=np.float64).reshape(-1, 2)
    return centres, centres


def build_scene_graph(
    scene: Scene, thresholds: RelationThresholds = DEFAULT_THRESHOLDS
) -> SceneGraph:
    """Compute every relation of ``scene`` (see the module docstring for the semantics).

    Only pairs of objects that the index (``storyteller.tools.box_pairs``) finds within a relation's reach
    are tested; the relations, node attributes and edge order are those of testing every pair
    (``benchmark/support/scene_graph_reference.py``).
    """
    import networkx as nx

    t = thresholds
    objects = scene.objects
    index = {o.name: i for i, o in enumerate(objects)}
    graph: nx.MultiDiGraph[str] = nx.MultiDiGraph()
    on_floor = {o.name for o in objects if abs(o.z_min - scene.floor_z) < t.floor_support}
    # (subject index, phase, anchor index, order within the pair, relation): sorted, this is the
    # order in which testing every pair adds the edges (a MultiDiGraph keeps insertion order).
    edges: list[tuple[int, int, int, int, str]] = []

    # support: the closest anchor top under the subject's bottom wins
    supporter: dict[str, str] = {}
    contact: dict[str, tuple[str, str]] = {}
    lifted = [o for o in objects if o.name not in on_floor]
    if lifted:
        ia, ib = overlapping_pairs(*_centre_boxes(lifted), *_footprint_boxes(objects, 0.0, t.support_xy))
        candidates: dict[str, list[tuple[float, str, str]]] = {}
        for i, j in zip(ia.tolist(), ib.tolist(), strict=True):
            subject, anchor = lifted[i], objects[j]
            if anchor.name == subject.name:
                continue
            relation = _vertical_contact(subject, anchor, t)
            if relation is not None:
                candidates.setdefault(subject.name, []).append(
                    (abs(subject.z_min - anchor.z_max), anchor.name, relation)
                )
        for subject in lifted:
            if subject.name in candidates:
                _, anchor_name, relation = min(candidates[subject.name])
                supporter[subject.name] = anchor_name
                contact[subject.name] = (relation, anchor_name)

    levels = _levels(scene, on_floor, supporter)
    for obj in objects:
        graph.add_node(
            obj.name, label=obj.label, level=levels[obj.name], supporter=supporter.get(obj.name)
        )
    for subject_name, (relation, anchor_name) in contact.items():
        edges.append((index[subject_name], 0, index[anchor_name], 0, relation))

    # above / below: objects held by nothing against floor-standing objects
    hanging = [o for o in objects if o.name not in on_floor and o.name not in supporter]
    grounded = [o for o in objects if o.name in on_floor]
    if hanging and grounded:
        pairs = overlapping_pairs(
            *_footprint_boxes(hanging, 0.0, t.hanging_xy), *_footprint_boxes(grounded, 0.0, t.hanging_xy)
        )
        for i, j in zip(*(p.tolist() for p in pairs), strict=True):
            for subject, anchor in ((hanging[i], grounded[j]), (grounded[j], hanging[i])):
                if not bool(anchor.contains_xy(subject.center_xy, margin=t.hanging_xy)):
                    continue
                if subject.z_min > anchor.z_max:
                    edges.append((index[subject.name], 1, index[anchor.name], 0, "above"))
                elif subject.z_max < anchor.z_min:
                    edges.append((index[subject.name], 1, index[anchor.name], 0, "below"))

    # horizontal relations within each group sharing a supporter (None = the floor)
    groups: dict[str | None, list[SceneObject]] = {}
    for obj in objects:
        if obj.name in on_floor:
            groups.setdefault(None, []).append(obj)
        elif obj.name in supporter:
            groups.setdefault(supporter[obj.name], []).append(obj)
    for members in groups.values():
        edges.extend(_horizontal_edges(members, index, t))

    for subject_index, _, anchor_index, _, relation in sorted(edges):
        graph.add_edge(objects[subject_index].name, objects[anchor_index].name, relation=relation)
    return SceneGraph(scene, t, graph)


def _circle_gap(a: SceneObject, b: SceneObject) -> float:
    """Lower bound of the footprint distance from the footprints' circumscribed circles."""
    centre = float(centre_distances(a.center_xy, b.center_xy))
    return centre - float(np.hypot(a.width, a.depth) + np.hypot(b.width, b.depth)) / 2.0


def _horizontal_edges(
    members: list[SceneObject], index: dict[str, int], t: RelationThresholds
) -> list[tuple[int, int, int, int, str]]:
    """The horizontal relations among ``members`` (one supporter), as sortable edge entries.

    The near pairs are measured together, each once: the level difference, the footprint
    distance and its cheap bound (``_circle_gap``, the same floats) are symmetric; only the
    directional relation depends on which object is the anchor."""
    out: list[tuple[int, int, int, int, str]] = []
    boxes = _footprint_boxes(members, t.horizontal_range / 2.0)
    ia, ib = overlapping_pairs(*boxes, *boxes)
    upper = ia < ib
    ia, ib = ia[upper], ib[upper]
    z_min = np.array([o.z_min for o in members])
    centres = np.array([o.center[:2] for o in members], dtype=np.float64).reshape(-1, 2)
    radius = np.array([np.hypot(o.width, o.depth) for o in members])
    near = np.abs(z_min[ia] - z_min[ib]) <= t.same_level_z
    gap = centre_distances(centres[ia], centres[ib]) - (radius[ia] + radius[ib]) / 2.0
    near &= ~(gap > t.horizontal_range)  # cheap rejection
    ia, ib = ia[near], ib[near]
    footprints = np.stack([o.footprint() for o in members]) if members else np.zeros((0, 4, 2))
    distances = polygon_distances(footprints[ia], footprints[ib])
    within = ~(distances > t.horizontal_range)
    for i, j, distance in zip(ia[within].tolist(), ib[within].tolist(), distances[within].tolist(), strict=True):
        first, second = members[i], members[j]
        nearness = "adjacent to" if distance < t.adjacent else "close to" if distance < t.close else None
        for subject, anchor in ((first, second), (second, first)):
            s, a = index[subject.name], index[anchor.name]
            direction = directional_relation(subject, anchor, t.directional_offset)
            if direction is not None:
                out.append((s, 2, a, 0, direction))
            if nearness is not None:
                out.append((s, 2, a, 1, nearness))
    return out

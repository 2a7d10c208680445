"""Frozen brute-force oracles of the scene graph and the region clusters: every pair of objects
tested, as ``storyteller.tools.scene_graph.build_scene_graph`` and ``storyteller.tools.clusters.cluster_objects`` did
before their spatial index (``storyteller.tools.box_pairs``). The fast builds must give the same relations,
node attributes, edge order and clusters (``tests/tools/test_scene_graph_index.py``); the scene
building benchmark (``benchmark/bench_scene_build.py``) times both.

The footprint distances are frozen here too, as they were written then (matrix products: they
may round differently from ``storyteller.tools.footprint_geometry`` in the last bit, which no relation
threshold meets on the scenes compared); the rules of one pair (``_vertical_contact``,
``directional_relation``) are the product's own.
"""

from __future__ import annotations

from typing import Any

import networkx as nx
import numpy as np
from numpy.typing import NDArray

from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.scene_graph import (
    DEFAULT_THRESHOLDS,
    RelationThresholds,
    SceneGraph,
    _vertical_contact,
    directional_relation,
    vertical_gap,
)


def _point_segment_distances(
    points: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64]
) -> NDArray[np.float64]:
    ab = b - a
    denom = float(ab @ ab)
    t = np.zeros(len(points)) if denom < 1e-18 else np.clip((points - a) @ ab / denom, 0.0, 1.0)
    proj = a + t[:, None] * ab
    distances: NDArray[np.float64] = np.linalg.norm(points - proj, axis=1)
    return distances


def _separated(p: NDArray[np.float64], q: NDArray[np.float64]) -> bool:
    for poly in (p, q):
        edges = np.roll(poly, -1, axis=0) - poly
        for e in edges:
            axis = np.array([-e[1], e[0]])
            if axis @ axis < 1e-18:
                continue
            pp, qq = p @ axis, q @ axis
            if pp.max() < qq.min() or qq.max() < pp.min():
                return True
    return False


def polygon_distance(p: NDArray[np.float64], q: NDArray[np.float64]) -> float:
    if not _separated(p, q):
        return 0.0
    best = np.inf
    for poly_a, poly_b in ((p, q), (q, p)):
        for i in range(len(poly_b)):
            d = _point_segment_distances(poly_a, poly_b[i], poly_b[(i + 1) % len(poly_b)])
            best = min(best, float(d.min()))
    return best


def footprint_distance(a: SceneObject, b: SceneObject) -> float:
    return polygon_distance(a.footprint(), b.footprint())


def box_distance(a: SceneObject, b: SceneObject) -> float:
    return float(np.hypot(footprint_distance(a, b), vertical_gap(a, b)))


def _circle_gap(a: SceneObject, b: SceneObject) -> float:
    centre = float(np.linalg.norm(a.center_xy - b.center_xy))
    return centre - float(np.hypot(a.width, a.depth) + np.hypot(b.width, b.depth)) / 2.0


def _levels(scene: Scene, on_floor: set[str], supporter: dict[str, str]) -> dict[str, int | None]:
    levels: dict[str, int | None] = {}

    def level_of(name: str, visiting: frozenset[str]) -> int | None:
        if name in levels:
            return levels[name]
        if name in on_floor:
            result: int | None = 0
        elif name not in supporter or name in visiting:
            result = None
        else:
            below = level_of(supporter[name], visiting | {name})
            result = None if below is None else below + 1
        levels[name] = result
        return result

    for obj in scene.objects:
        level_of(obj.name, frozenset())
    return levels


def brute_force_scene_graph(scene: Scene, thresholds: RelationThresholds = DEFAULT_THRESHOLDS) -> SceneGraph:
    t = thresholds
    objects = scene.objects
    graph: Any = nx.MultiDiGraph()
    on_floor = {o.name for o in objects if abs(o.z_min - scene.floor_z) < t.floor_support}
    supporter: dict[str, str] = {}
    contact: dict[str, tuple[str, str]] = {}
    for subject in objects:
        if subject.name in on_floor:
            continue
        candidates = []
        for anchor in objects:
            if anchor.name == subject.name:
                continue
            relation = _vertical_contact(subject, anchor, t)
            if relation is not None:
                candidates.append((abs(subject.z_min - anchor.z_max), anchor.name, relation))
        if candidates:
            _, anchor_name, relation = min(candidates)
            supporter[subject.name] = anchor_name
            contact[subject.name] = (relation, anchor_name)
    levels = _levels(scene, on_floor, supporter)
    for obj in objects:
        graph.add_node(obj.name, label=obj.label, level=levels[obj.name], supporter=supporter.get(obj.name))
    for subject_name, (relation, anchor_name) in contact.items():
        graph.add_edge(subject_name, anchor_name, relation=relation)
    hanging = [o for o in objects if o.name not in on_floor and o.name not in supporter]
    grounded = [o for o in objects if o.name in on_floor]
    for h in hanging:
        for g in grounded:
            for subject, anchor in ((h, g), (g, h)):
                if not bool(anchor.contains_xy(subject.center_xy, margin=t.hanging_xy)):
                    continue
                if subject.z_min > anchor.z_max:
                    graph.add_edge(subject.name, anchor.name, relation="above")
                elif subject.z_max < anchor.z_min:
                    graph.add_edge(subject.name, anchor.name, relation="below")
    groups: dict[str | None, list[SceneObject]] = {}
    for obj in objects:
        if obj.name in on_floor:
            groups.setdefault(None, []).append(obj)
        elif obj.name in supporter:
            groups.setdefault(supporter[obj.name], []).append(obj)
    for members in groups.values():
        for subject in members:
            for anchor in members:
                if subject.name == anchor.name or abs(subject.z_min - anchor.z_min) > t.same_level_z:
                    continue
                if _circle_gap(subject, anchor) > t.horizontal_range:
                    continue
                distance = footprint_distance(subject, anchor)
                if distance > t.horizontal_range:
                    continue
                direction = directional_relation(subject, anchor, t.directional_offset)
                if direction is not None:
                    graph.add_edge(subject.name, anchor.name, relation=direction)
                if distance < t.adjacent:
                    graph.add_edge(subject.name, anchor.name, relation="adjacent to")
                elif distance < t.close:
                    graph.add_edge(subject.name, anchor.name, relation="close to")
    return SceneGraph(scene, t, graph)


def brute_force_clusters(scene: Scene, eps: float = 1.0, min_samples: int = 2) -> list[list[str]]:
    from sklearn.cluster import DBSCAN

    objects = scene.objects
    names = scene.object_names
    if not names:
        return []
    n = len(objects)
    matrix = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            matrix[i, j] = matrix[j, i] = box_distance(objects[i], objects[j])
    labels = DBSCAN(eps=eps, min_samples=min_samples, metric="precomputed").fit_predict(matrix)
    clusters: dict[tuple[str, int], list[str]] = {}
    for index, (name, label) in enumerate(zip(names, labels, strict=True)):
        key = ("noise", index) if label < 0 else ("cluster", int(label))
        clusters.setdefault(key, []).append(name)
    return sorted(clusters.values(), key=lambda members: names.index(members[0]))

"""Text forms of a scene for LLM prompts: the scene graph as compact JSON, a plain object list
(for the ablations), and the region clusters. Numbers are rounded to centimetres; output is
deterministic for a given scene."""

from __future__ import annotations

import json

from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.scene_graph import SceneGraph


def _r(values: tuple[float, ...] | list[float]) -> list[float]:
    return [round(float(v), 2) + 0.0 for v in values]  # + 0.0 turns -0.0 into 0.0


def _object_entry(obj: SceneObject) -> dict[str, object]:
    entry: dict[str, object] = {"position": _r(obj.center), "size": _r(obj.size)}
    if obj.has_facing:
        entry["facing"] = _r(obj.facing)
    return entry


def scene_graph_json(graph: SceneGraph) -> str:
    """One JSON object keyed by object name: position [x, y, z] (box centre, m), size
    [width, depth, height] (m), facing [dx, dy] (objects with a front only), support level,
    and relations as "<relation> <anchor>" strings. Compact separators, one line."""
    out: dict[str, dict[str, object]] = {}
    for obj in graph.scene.objects:
        entry = _object_entry(obj)
        level = graph.level(obj.name)
        if level is not None:
            entry["level"] = level
        relations = [f"{relation} {anchor}" for relation, anchor in graph.relations_of(obj.name)]
        if relations:
            entry["relations"] = relations
        out[obj.name] = entry
    return json.dumps(out, separators=(",", ":"))


def object_list_text(scene: Scene) -> str:
    """One line per object: name, centre position and size, without any relation."""
    lines = []
    for obj in scene.objects:
        x, y, z = _r(obj.center)
        w, d, h = _r(obj.size)
        lines.append(f"{obj.name}: position [{x}, {y}, {z}], size [{w}, {d}, {h}]")
    return "\n".join(lines)


def clusters_text(clusters: list[list[str]]) -> str:
    """One line per region cluster: "region <k>: name, name, ..." (k from 1)."""
    return "\n".join(
        f"region {k}: {', '.join(members)}" for k, members in enumerate(clusters, start=1)
    )

"""Description ablations (Object List, Scene Graph): the scene's text without the describer.

Both are pure functions of the scene, so a run that uses them makes no describer call.
"""

from __future__ import annotations

from storyteller.agents.messages import SceneDescription
from storyteller.sim.scene.model import Scene
from storyteller.tools.scene_graph import SceneGraph, build_scene_graph
from storyteller.tools.scene_text import object_list_text, scene_graph_json


def object_list_description(scene: Scene) -> SceneDescription:
    """Ablation: a plain object list (names, positions, sizes) instead of the describer's text."""
    return SceneDescription(scene=scene.name, text=object_list_text(scene), source="object_list")


def scene_graph_description(scene: Scene, graph: SceneGraph | None = None) -> SceneDescription:
    """Ablation: the raw scene graph JSON instead of the describer's text."""
    text = scene_graph_json(graph or build_scene_graph(scene))
    return SceneDescription(scene=scene.name, text=text, source="scene_graph")

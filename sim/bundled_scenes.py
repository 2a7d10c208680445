"""Scenes shipped with the package (``sim/scenes/*.json``) and name-or-path resolution."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from sim.scene import Scene
from sim.scene_files import SceneFileError, load_scene, load_scene_json


def bundled_scene_names() -> list[str]:
    folder = resources.files("sim") / "scenes"
    return sorted(p.name[: -len(".json")] for p in folder.iterdir() if p.name.endswith(".json"))


def resolve_scene(spec: str | Path) -> Scene:
    """A bundled scene by name (e.g. ``home``) or a scene at a path (folder, JSON, mesh)."""
    text = str(spec)
    if text in bundled_scene_names():
        with resources.as_file(resources.files("sim") / "scenes" / f"{text}.json") as path:
            return load_scene_json(Path(path))
    path = Path(text)
    if not path.exists():
        names = ", ".join(bundled_scene_names()) or "none"
        raise SceneFileError(path, f"no such file or folder, and not a bundled scene (bundled: {names})")
    return load_scene(path)

"""Scenes shipped with the package (``sim/scene/scenes/*.json``) and name-or-path resolution.

The bundled scenes are generated from the layouts in ``storyteller.sim.scene.authoring``.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from storyteller.sim.scene.errors import SceneFileError

if TYPE_CHECKING:  # loading is imported when a scene is loaded: ``scene list`` needs no numpy
    from storyteller.sim.scene.model import Scene


def bundled_scene_names() -> list[str]:
    """Names of the bundled scenes, sorted (e.g. ``['home', 'office', 'restaurant']``)."""
    folder = resources.files("storyteller.sim.scene") / "scenes"
    return sorted(p.name[: -len(".json")] for p in folder.iterdir() if p.name.endswith(".json"))


def load_bundled_scene(name: str) -> Scene:
    """The bundled scene called ``name``; ``SceneFileError`` listing the names otherwise."""
    if name not in bundled_scene_names():
        names = ", ".join(bundled_scene_names()) or "none"
        raise SceneFileError(name, f"not a bundled scene (bundled: {names})")
    from storyteller.sim.scene.files import load_scene_json

    with resources.as_file(resources.files("storyteller.sim.scene") / "scenes" / f"{name}.json") as path:
        return load_scene_json(Path(path))


def resolve_scene(spec: str | Path) -> Scene:
    """A bundled scene by name (e.g. ``home``) or a scene at a path (folder, JSON, mesh).

    A bundled name wins over a file of the same name in the working directory.
    """
    text = str(spec)
    if isinstance(spec, str) and text in bundled_scene_names():
        return load_bundled_scene(text)
    path = Path(text)
    if not text.strip() or not path.exists():
        names = ", ".join(bundled_scene_names()) or "none"
        raise SceneFileError(
            path, f"no such file or folder, and not a bundled scene (bundled: {names})"
        )
    from storyteller.sim.scene.files import load_scene

    return load_scene(path)

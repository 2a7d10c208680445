"""Region clusters: groups of nearby objects found by DBSCAN on box-to-box surface distances.

The distance between two objects is ``tools.scene_graph.box_distance``: the distance between
their 2D footprints (oriented rectangles) combined with the gap between their height ranges,
``hypot(footprint distance, vertical gap)``, in metres. A coffee maker standing on a cabinet is
at distance 0 from it; two chairs 0.4 m apart are at 0.4.

scikit-learn (about 2 s to import) is imported by ``cluster_objects`` when it first runs, not
with this module, so that importing the planning stack (and the CLI) stays quick.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from sim.scene.model import Scene
from tools.scene_graph import box_distance


def distance_matrix(scene: Scene) -> NDArray[np.float64]:
    """Symmetric (N, N) matrix of box-to-box surface distances between the scene's objects, metres."""
    objects = scene.objects
    n = len(objects)
    matrix = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            matrix[i, j] = matrix[j, i] = box_distance(objects[i], objects[j])
    return matrix


def cluster_objects(scene: Scene, eps: float = 1.0, min_samples: int = 2) -> list[list[str]]:
    """Group objects into regions with DBSCAN (scikit-learn, ``metric="precomputed"``).

    ``eps`` is the neighbourhood radius in metres and ``min_samples`` counts the point itself.
    Noise points (objects with no cluster) are not dropped: each becomes a cluster of its own,
    so every object appears in exactly one cluster. Clusters list names in scene order and are
    ordered by their first member's position in the scene.
    """
    if eps <= 0 or not np.isfinite(eps):
        raise ValueError(f"eps must be a positive finite distance in metres, got {eps!r}")
    if min_samples < 1:
        raise ValueError(f"min_samples must be >= 1, got {min_samples!r}")
    names = scene.object_names
    if not names:
        return []
    from sklearn.cluster import DBSCAN

    labels = DBSCAN(eps=eps, min_samples=min_samples, metric="precomputed").fit_predict(
        distance_matrix(scene)
    )
    clusters: dict[tuple[str, int], list[str]] = {}
    for index, (name, label) in enumerate(zip(names, labels, strict=True)):
        key = ("noise", index) if label < 0 else ("cluster", int(label))
        clusters.setdefault(key, []).append(name)
    return sorted(clusters.values(), key=lambda members: names.index(members[0]))

"""Region clusters: groups of nearby objects found by DBSCAN on box-to-box surface distances.

The distance between two objects is ``storyteller.tools.scene_graph.box_distance``: the distance between
their 2D footprints (oriented rectangles) combined with the gap between their height ranges,
``hypot(footprint distance, vertical gap)``, in metres. A coffee maker standing on a cabinet is
at distance 0 from it; two chairs 0.4 m apart are at 0.4.

Only pairs within ``eps`` can be neighbours, so the distances go to DBSCAN as a sparse matrix
of the pairs the index (``storyteller.tools.box_pairs``) finds within reach: the clusters are those of the
full matrix (``benchmark/support/scene_graph_reference.py``), for work that grows with the objects
and their near pairs instead of with every pair.

scikit-learn (about 2 s to import) is imported by ``cluster_objects`` when it first runs, not
with this module, so that importing the planning stack (and the CLI) stays quick.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.scene.model import Scene
from storyteller.tools.box_pairs import overlapping_pairs
from storyteller.tools.footprint_geometry import polygon_distances
from storyteller.tools.scene_graph import box_distance

if TYPE_CHECKING:  # scipy.sparse is imported when a matrix is built
    from scipy.sparse import csr_matrix

_INDEX_SLACK = 1e-6
"""Metres beyond ``eps`` the index looks, so rounding never drops a pair within ``eps``."""


def distance_matrix(scene: Scene) -> NDArray[np.float64]:
    """Symmetric (N, N) matrix of box-to-box surface distances between the scene's objects, metres."""
    objects = scene.objects
    n = len(objects)
    matrix = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            matrix[i, j] = matrix[j, i] = box_distance(objects[i], objects[j])
    return matrix


def near_distance_matrix(scene: Scene, reach: float) -> csr_matrix:
    """Sparse (N, N) box-to-box distances: every pair within ``reach`` metres is stored (zeros
    too, explicitly), pairs further apart may be missing. Symmetric; the diagonal is empty."""
    from scipy.sparse import csr_matrix

    objects = scene.objects
    n = len(objects)
    if n == 0:
        return csr_matrix((0, 0))
    corners = np.stack([o.footprint() for o in objects])
    pad = reach / 2.0 + _INDEX_SLACK  # a footprint distance <= reach: grown boxes overlap
    lo, hi = corners.min(axis=1) - pad, corners.max(axis=1) + pad
    ia, ib = overlapping_pairs(lo, hi, lo, hi)
    upper = ia < ib
    rows, cols = ia[upper], ib[upper]
    z_lo = np.array([o.z_min for o in objects])
    z_hi = np.array([o.z_max for o in objects])
    # box_distance of each pair, computed for all of them at once (the same floats)
    gaps = np.maximum(np.maximum(0.0, z_lo[rows] - z_hi[cols]), z_lo[cols] - z_hi[rows])
    values = np.hypot(polygon_distances(corners[rows], corners[cols]), gaps)
    keep = values <= reach
    rows, cols, values = rows[keep], cols[keep], values[keep]
    matrix = csr_matrix(
        (np.concatenate([values, values]), (np.concatenate([rows, cols]), np.concatenate([cols, rows]))),
        shape=(n, n),
    )
    matrix.sort_indices()
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
        near_distance_matrix(scene, eps)
    )
    clusters: dict[tuple[str, int], list[str]] = {}
    for index, (name, label) in enumerate(zip(names, labels, strict=True)):
        key = ("noise", index) if label < 0 else ("cluster", int(label))
        clusters.setdefault(key, []).append(name)
    return sorted(clusters.values(), key=lambda members: names.index(members[0]))

"""Scene building benchmark: the scene graph and the region clusters through the spatial index
(``storyteller.tools.box_pairs``) against the brute-force builds that test every pair
(``benchmark/support/scene_graph_reference.py``), on dense random scenes.

A scene of ``--objects`` boxes (0.3-1.0 m, random yaw, 30% lifted onto or above others)
scattered over a square floor with ``--density`` boxes per square metre (the default, 4 per
m^2, is 400 boxes on 10 x 10 m, as many as the 89 KB scene of issue 22). Both builds run in this
process, one after the other (CPU time, ``time.process_time``; scikit-learn is imported before
timing), their outputs are checked equal, and the ratio is printed. ``--scaling`` also times the
indexed build at 4x and 8x the objects at the same density (it should grow about linearly).

Run: python -m storyteller.benchmark.bench_scene_build [--objects 400] [--density 4] [--seed 0] [--scaling]
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from functools import partial
from typing import TypeVar

import numpy as np

from storyteller.benchmark.support.scene_graph_reference import brute_force_clusters, brute_force_scene_graph
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.clusters import cluster_objects
from storyteller.tools.scene_graph import build_scene_graph

T = TypeVar("T")


def dense_scene(objects: int, density: float, seed: int) -> Scene:
    """``objects`` random boxes on a square floor holding ``density`` boxes per square metre."""
    rng = np.random.default_rng(seed)
    side = math.sqrt(objects / density)
    boxes = []
    for i in range(objects):
        w, d, h = rng.uniform(0.3, 1.0, 3)
        bottom = 0.0 if rng.random() > 0.3 else float(rng.uniform(0.3, 1.0))
        yaw = rng.uniform(0.0, 2.0 * math.pi)
        x, y = rng.uniform(0.0, side, 2)
        boxes.append(
            SceneObject(
                name=f"box_{i}", label="box", idx=i, center=(float(x), float(y), bottom + h / 2.0),
                size=(float(w), float(d), float(h)), facing=(math.cos(yaw), math.sin(yaw)), has_facing=True,
            )
        )
    return Scene(name="dense", bounds_min=(0.0, 0.0), bounds_max=(side, side), objects=tuple(boxes))


def cpu(fn: Callable[[], T]) -> tuple[T, float]:
    start = time.process_time()
    value = fn()
    return value, time.process_time() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--objects", type=int, default=400)
    parser.add_argument("--density", type=float, default=4.0, help="boxes per square metre")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scaling", action="store_true", help="also time 4x and 8x the objects (indexed only)")
    args = parser.parse_args()
    import sklearn.cluster  # noqa: F401  (its import is not part of either build)

    scene = dense_scene(args.objects, args.density, args.seed)
    size_kb = len(scene.model_dump_json(indent=2)) / 1000
    graph, t_graph = cpu(lambda: build_scene_graph(scene))
    clusters, t_clusters = cpu(lambda: cluster_objects(scene))
    old_graph, t_old_graph = cpu(lambda: brute_force_scene_graph(scene))
    old_clusters, t_old_clusters = cpu(lambda: brute_force_clusters(scene))
    assert list(graph.graph.edges(keys=True, data=True)) == list(old_graph.graph.edges(keys=True, data=True))
    assert list(graph.graph.nodes(data=True)) == list(old_graph.graph.nodes(data=True))
    assert clusters == old_clusters
    print(f"{args.objects} boxes, {args.density:g} per m^2 ({size_kb:.0f} KB of scene JSON), "
          f"{len(graph.triples())} relations, {len(clusters)} clusters; CPU seconds:")
    print(f"  scene graph  brute force {t_old_graph:7.2f}  indexed {t_graph:6.2f}  ratio {t_old_graph / t_graph:6.1f}x")
    print(f"  clusters     brute force {t_old_clusters:7.2f}  indexed {t_clusters:6.2f}  "
          f"ratio {t_old_clusters / t_clusters:6.1f}x")
    total_old, total_new = t_old_graph + t_old_clusters, t_graph + t_clusters
    print(f"  both         brute force {total_old:7.2f}  indexed {total_new:6.2f}  ratio {total_old / total_new:6.1f}x")
    if args.scaling:
        for factor in (4, 8):
            big = dense_scene(args.objects * factor, args.density, args.seed)
            _, t_g = cpu(partial(build_scene_graph, big))
            _, t_c = cpu(partial(cluster_objects, big))
            print(f"  indexed, {args.objects * factor} boxes: graph {t_g:.2f} s, clusters {t_c:.2f} s "
                  f"({(t_g + t_c) / total_new:.1f}x the {args.objects}-box time for {factor}x the boxes)")


if __name__ == "__main__":
    main()

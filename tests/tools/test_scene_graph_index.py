"""The scene graph and the region clusters built through the spatial index (``storyteller.tools.box_pairs``)
equal the brute-force builds that test every pair (``benchmark/support/scene_graph_reference.py``):
the same relations in the same order, the same node attributes, the same clusters, on the
bundled scenes, the reference scenes and random ones (hypothesis, derandomised). The index
itself returns exactly the overlapping pairs, and the batched footprint distances are the
one-pair ones.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from storyteller.benchmark.support.scene_graph_reference import brute_force_clusters, brute_force_scene_graph
from storyteller.sim.scene.bundled import bundled_scene_names, load_bundled_scene
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.box_pairs import overlapping_pairs
from storyteller.tools.clusters import cluster_objects
from storyteller.tools.footprint_geometry import polygon_distance, polygon_distances
from storyteller.tools.scene_graph import SceneGraph, build_scene_graph
from tests.support.reference import SCENES, reference_or_skip

SETTINGS = settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])


def graph_facts(graph: SceneGraph) -> tuple[list[Any], list[Any]]:
    """Everything a graph says, in its order: the nodes with attributes and the keyed edges."""
    nodes = [(n, d["label"], d["level"], d["supporter"]) for n, d in graph.graph.nodes(data=True)]
    edges = [(s, a, k, d["relation"]) for s, a, k, d in graph.graph.edges(keys=True, data=True)]
    return nodes, edges


def assert_same_as_brute_force(scene: Scene) -> None:
    assert graph_facts(build_scene_graph(scene)) == graph_facts(brute_force_scene_graph(scene))
    assert cluster_objects(scene) == brute_force_clusters(scene)


@pytest.mark.parametrize("name", bundled_scene_names())
def test_bundled_scenes_give_the_brute_force_graph_and_clusters(name: str) -> None:
    assert_same_as_brute_force(load_bundled_scene(name))


@pytest.mark.parametrize("name", ["House", "Office", "Restaurant"])
def test_reference_scenes_give_the_brute_force_graph_and_clusters(name: str) -> None:
    reference_or_skip()
    assert_same_as_brute_force(load_scene(SCENES / name))


# ----- random scenes ---------------------------------------------------------------------------
coord = st.floats(-4.0, 4.0, allow_nan=False).map(lambda v: round(v, 2))  # touching and exact gaps happen
size = st.sampled_from([0.0, 0.1, 0.3, 0.5, 1.0, 2.0]) | st.floats(0.05, 3.0)
angle = st.sampled_from([0.0, 90.0, 45.0, 180.0]) | st.floats(0.0, 360.0)
level = st.sampled_from([0.0, 0.0, 0.4, 0.8, 1.5]) | st.floats(0.0, 2.0)


@st.composite
def random_scenes(draw: st.DrawFn) -> Scene:
    n = draw(st.integers(0, 28))
    objects = []
    for i in range(n):
        a = np.radians(draw(angle))
        w, d, h = draw(size), draw(size), draw(size)
        bottom = draw(level)
        objects.append(
            SceneObject(
                name=f"box_{i}", label="box", idx=i,
                center=(draw(coord), draw(coord), bottom + h / 2.0), size=(w, d, h),
                facing=(float(np.cos(a)), float(np.sin(a))), has_facing=draw(st.booleans()),
            )
        )
    return Scene(name="random", bounds_min=(-5.0, -5.0), bounds_max=(5.0, 5.0), objects=tuple(objects))


@SETTINGS
@given(scene=random_scenes())
def test_random_scenes_give_the_brute_force_graph_and_clusters(scene: Scene) -> None:
    assert_same_as_brute_force(scene)


def test_a_dense_scene_gives_the_brute_force_graph_and_clusters() -> None:
    """Hundreds of relations per object neighbourhood, stacks and hanging boxes included."""
    rng = np.random.default_rng(7)
    objects = []
    for i in range(150):
        w, d, h = rng.uniform(0.2, 1.0, 3)
        bottom = 0.0 if rng.random() < 0.7 else float(rng.choice([0.4, 0.8, 2.0]))
        a = rng.uniform(0.0, 2.0 * np.pi)
        objects.append(
            SceneObject(name=f"box_{i}", label="box", idx=i, center=(*rng.uniform(0.0, 6.0, 2), bottom + h / 2),
                        size=(w, d, h), facing=(float(np.cos(a)), float(np.sin(a))), has_facing=True)
        )
    assert_same_as_brute_force(Scene(name="dense", bounds_min=(0, 0), bounds_max=(6, 6), objects=tuple(objects)))


# ----- the index and the batched distances -----------------------------------------------------
boxes = st.lists(
    st.tuples(coord, coord, st.sampled_from([0.0, 0.5, 1.0]) | st.floats(0.0, 9.0), st.floats(0.0, 3.0)),
    max_size=30,
)


def as_corners(spec: list[tuple[float, float, float, float]]) -> tuple[np.ndarray, np.ndarray]:
    lo = np.array([(x, y) for x, y, _, _ in spec], dtype=float).reshape(-1, 2)
    hi = lo + np.array([(w, h) for _, _, w, h in spec], dtype=float).reshape(-1, 2)
    return lo, hi


@settings(max_examples=150, deadline=None, derandomize=True)
@given(a=boxes, b=boxes)
def test_overlapping_pairs_are_the_brute_force_pairs(a: Any, b: Any) -> None:
    a_lo, a_hi = as_corners(a)
    b_lo, b_hi = as_corners(b)
    expected = [
        (i, j)
        for i in range(len(a_lo))
        for j in range(len(b_lo))
        if np.all(a_lo[i] <= b_hi[j]) and np.all(b_lo[j] <= a_hi[i])
    ]
    ia, ib = overlapping_pairs(a_lo, a_hi, b_lo, b_hi)
    assert list(zip(ia.tolist(), ib.tolist(), strict=True)) == expected


def test_batched_footprint_distances_are_the_one_pair_distances() -> None:
    rng = np.random.default_rng(3)
    objects = [
        SceneObject(name=f"box_{i}", label="box", idx=i, center=(*rng.uniform(-3, 3, 2), 0.5),
                    size=(*rng.uniform(0.0, 1.5, 2), 1.0), facing=tuple(rng.normal(size=2)))
        for i in range(40)
    ]
    p = np.stack([o.footprint() for o in objects])
    i, j = np.triu_indices(len(objects), k=1)
    batch = polygon_distances(p[i], p[j])
    one = [polygon_distance(p[a], p[b]) for a, b in zip(i, j, strict=True)]
    assert batch.tolist() == one
    assert (batch == 0).any() and (batch > 0).any()

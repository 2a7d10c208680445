"""Region clusters: DBSCAN on box-to-box surface distances."""

from __future__ import annotations

import numpy as np
import pytest

from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.clusters import cluster_objects, distance_matrix
from tests.support.reference import SCENES, requires_reference


def box(name: str, x: float, y: float, z: float = 0.4, size: float = 0.5) -> SceneObject:
    label, idx = name.rsplit("_", 1)
    return SceneObject(
        name=name, label=label, idx=int(idx), center=(x, y, z), size=(size, size, 0.8)
    )


def scene_of(*objects: SceneObject) -> Scene:
    return Scene(name="t", bounds_min=(-20.0, -20.0), bounds_max=(20.0, 20.0), objects=objects)


@requires_reference
def test_house_regions_match_the_description_areas() -> None:
    clusters = cluster_objects(load_scene(SCENES / "House"))
    as_sets = [set(c) for c in clusters]
    assert {
        "cabinet_1",
        "coffee_maker_1",
        "dishwasher_1",
        "fridge_1",
        "microwave_1",
    } in as_sets  # kitchen
    assert {"chair_1", "chair_3", "couch_1", "potted_plant_2", "table_3"} in as_sets  # lounge
    assert {"chair_2", "chair_4", "chair_5", "chair_6", "table_4", "toaster_1"} in as_sets  # dining
    assert len(clusters) == 4


@pytest.mark.parametrize("name", ["House", "Office", "Restaurant"])
@requires_reference
def test_every_object_in_exactly_one_cluster(name: str) -> None:
    scene = load_scene(SCENES / name)
    clusters = cluster_objects(scene)
    flat = [n for c in clusters for n in c]
    assert sorted(flat) == sorted(scene.object_names)


def test_chain_linking_and_noise_points_become_singletons() -> None:
    # a-b-c chained 0.9 m apart (surface), d alone 5 m away
    scene = scene_of(box("a_1", 0, 0), box("b_1", 1.4, 0), box("c_1", 2.8, 0), box("d_1", 9, 9))
    assert cluster_objects(scene) == [["a_1", "b_1", "c_1"], ["d_1"]]
    assert cluster_objects(scene, eps=0.5) == [["a_1"], ["b_1"], ["c_1"], ["d_1"]]
    assert cluster_objects(scene, eps=0.95, min_samples=3) == [["a_1", "b_1", "c_1"], ["d_1"]]


def test_stacked_objects_are_at_distance_zero() -> None:
    scene = scene_of(
        box("table_1", 0, 0, z=0.4, size=1.0),
        box("cup_1", 0, 0, z=0.85, size=0.1),
        box("lamp_1", 0, 0, z=2.5, size=0.2),
    )
    m = distance_matrix(scene)
    assert m[0, 1] == pytest.approx(0.0, abs=0.051)  # cup bottom 0.8 = table top 0.8
    assert m[0, 2] == pytest.approx(2.5 - 0.4 - 0.8, abs=1e-9)  # vertical gap only
    assert np.allclose(m, m.T) and np.all(np.diag(m) == 0)


def test_bad_parameters_and_empty_scene() -> None:
    scene = scene_of(box("a_1", 0, 0))
    with pytest.raises(ValueError):
        cluster_objects(scene, eps=0.0)
    with pytest.raises(ValueError):
        cluster_objects(scene, eps=float("nan"))
    with pytest.raises(ValueError):
        cluster_objects(scene, min_samples=0)
    assert cluster_objects(scene_of()) == []

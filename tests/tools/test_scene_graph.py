"""Scene graph: reference scenes, synthetic stacks, footprint geometry, text forms."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene, SceneObject, Vec2, Vec3
from storyteller.tools.scene_graph import (
    RELATIONS,
    RelationThresholds,
    SceneGraph,
    box_distance,
    build_scene_graph,
    footprint_distance,
    point_footprint_distance,
)
from storyteller.tools.scene_text import clusters_text, object_list_text, scene_graph_json
from tests.support.reference import SCENES, reference_or_skip, requires_reference


@pytest.fixture(scope="module", params=["House", "Office", "Restaurant"])
def ref_graph(request: pytest.FixtureRequest) -> SceneGraph:
    reference_or_skip()
    return build_scene_graph(load_scene(SCENES / request.param))


@pytest.fixture(scope="module")
def house() -> SceneGraph:
    reference_or_skip()
    return build_scene_graph(load_scene(SCENES / "House"))


def obj(
    name: str, center: Vec3, size: Vec3, facing: Vec2 = (0.0, 1.0), has_facing: bool = True, **kw: Any
) -> SceneObject:
    label, idx = name.rsplit("_", 1)
    return SceneObject(
        name=name,
        label=label,
        idx=int(idx),
        center=center,
        size=size,
        facing=facing,
        has_facing=has_facing,
        **kw,
    )


def scene_of(*objects: SceneObject) -> Scene:
    return Scene(name="t", bounds_min=(-10.0, -10.0), bounds_max=(10.0, 10.0), objects=objects)


# ----- reference scenes: what their descriptions state ---------------------------------------
def test_house_support_relations(house: SceneGraph) -> None:
    triples = set(house.triples())
    for t in [
        ("coffee_maker_1", "on", "cabinet_1"),
        ("microwave_1", "on", "cabinet_1"),
        ("toaster_1", "on", "table_4"),
        ("tv_1", "on", "table_1"),
        ("loudspeaker_1", "on", "table_1"),
        ("dvd_player_1", "on", "table_1"),
        ("record_player_1", "on", "table_2"),
    ]:
        assert t in triples
    assert house.supporter("coffee_maker_1") == "cabinet_1"
    assert house.supporter("cabinet_1") is None
    assert sorted(house.supported_by("table_1")) == ["dvd_player_1", "loudspeaker_1", "tv_1"]


def test_house_horizontal_relations_from_description(house: SceneGraph) -> None:
    triples = set(house.triples())
    for t in [
        ("dishwasher_1", "to the left of", "cabinet_1"),
        ("fridge_1", "to the right of", "cabinet_1"),
        ("microwave_1", "to the right of", "coffee_maker_1"),
        ("coffee_maker_1", "adjacent to", "microwave_1"),
        ("table_3", "in front of", "couch_1"),
        ("table_3", "in front of", "chair_1"),
        ("table_3", "in front of", "chair_3"),
        ("loudspeaker_1", "in front of", "tv_1"),
        ("tv_1", "behind", "loudspeaker_1"),
        ("chair_2", "adjacent to", "table_4"),
        ("potted_plant_2", "adjacent to", "couch_1"),
        ("table_2", "adjacent to", "table_1"),
    ]:
        assert t in triples, t


@requires_reference
def test_office_and_restaurant_support_from_description() -> None:
    office = set(build_scene_graph(load_scene(SCENES / "Office")).triples())
    for i, table in [(1, 3), (2, 1), (3, 2), (4, 6), (5, 7), (6, 11), (7, 5), (8, 8)]:
        assert (f"laptop_{i}", "on", f"table_{table}") in office
    assert ("bookshelf_2", "on", "cabinet_3") in office
    restaurant = set(build_scene_graph(load_scene(SCENES / "Restaurant")).triples())
    for name in [
        "bar_logo_1",
        "bottles_7",
        "bottles_8",
        "bottles_9",
        "wine_rack_1",
        "wine_rack_11",
    ]:
        assert (name, "on", "bar_counter_1") in restaurant
    for i in (1, 2, 3):
        assert (f"plate_{i}", "on", "table_1") in restaurant
    assert ("laptop_1", "inside", "reception_desk_1") in restaurant


def test_reference_graph_invariants(ref_graph: SceneGraph) -> None:
    g = ref_graph
    horizontal = {
        "in front of",
        "behind",
        "to the left of",
        "to the right of",
        "adjacent to",
        "close to",
    }
    for s, rel, a in g.triples():
        assert rel in RELATIONS and s != a
        if rel in horizontal:  # only between objects with the same supporter and level
            assert g.supporter(s) == g.supporter(a)
            assert g.level(s) == g.level(a)
        if rel in ("on", "inside"):
            assert g.supporter(s) == a
            below = g.level(a)
            assert below is not None and g.level(s) == below + 1
        if rel in ("in front of", "behind", "to the left of", "to the right of"):
            assert g.scene.by_name[a].has_facing
    for o in g.scene.objects:
        level = g.level(o.name)
        assert level is None or level >= 0


# ----- synthetic scenes ---------------------------------------------------------------------
def test_stack_levels_and_hanging_object() -> None:
    table = obj("table_1", (0, 0, 0.4), (1.0, 1.0, 0.8), has_facing=False)
    box = obj("box_1", (0, 0, 0.9), (0.4, 0.4, 0.2))
    cup = obj("cup_1", (0.05, 0, 1.05), (0.1, 0.1, 0.1))
    lamp = obj("lamp_1", (0.1, 0.1, 2.2), (0.3, 0.3, 0.2))  # held by nothing, above the table
    g = build_scene_graph(scene_of(table, box, cup, lamp))
    assert (g.level("table_1"), g.level("box_1"), g.level("cup_1"), g.level("lamp_1")) == (
        0,
        1,
        2,
        None,
    )
    triples = set(g.triples())
    assert {
        ("box_1", "on", "table_1"),
        ("cup_1", "on", "box_1"),
        ("lamp_1", "above", "table_1"),
        ("table_1", "below", "lamp_1"),
    } <= triples
    # cup and box have different supporters: no horizontal relation between them
    assert not [t for t in triples if {t[0], t[2]} == {"cup_1", "box_1"} and t[1] not in ("on",)]


def test_directions_follow_the_anchor_facing() -> None:
    # anchor faces +x: its front is +x, its right is -y, its left is +y
    anchor = obj("cabinet_1", (0, 0, 0.5), (1.0, 0.5, 1.0), facing=(1.0, 0.0))
    front = obj("chair_1", (1.0, 0, 0.4), (0.4, 0.4, 0.8))
    right = obj("chair_2", (0, -1.2, 0.4), (0.4, 0.4, 0.8))
    left = obj("chair_3", (0, 1.2, 0.4), (0.4, 0.4, 0.8))
    back = obj("chair_4", (-0.9, 0, 0.4), (0.4, 0.4, 0.8))
    triples = set(build_scene_graph(scene_of(anchor, front, right, left, back)).triples())
    assert ("chair_1", "in front of", "cabinet_1") in triples
    assert ("chair_2", "to the right of", "cabinet_1") in triples
    assert ("chair_3", "to the left of", "cabinet_1") in triples
    assert ("chair_4", "behind", "cabinet_1") in triples
    assert ("chair_1", "adjacent to", "cabinet_1") not in triples  # 0.55 m apart
    assert ("chair_1", "close to", "cabinet_1") in triples


def test_thresholds_are_configurable_and_frozen() -> None:
    a = obj("chair_1", (0, 0, 0.4), (0.4, 0.4, 0.8))
    b = obj("chair_2", (1.0, 0, 0.4), (0.4, 0.4, 0.8))
    scene = scene_of(a, b)
    assert ("chair_1", "close to", "chair_2") in build_scene_graph(scene).triples()
    wide = RelationThresholds(adjacent=0.7)
    assert ("chair_1", "adjacent to", "chair_2") in build_scene_graph(scene, wide).triples()
    assert build_scene_graph(scene, RelationThresholds(horizontal_range=0.5)).triples() == []
    with pytest.raises(ValidationError):
        RelationThresholds(adjacent=-1.0)
    with pytest.raises(ValidationError):
        RelationThresholds.model_validate({"unknown": 1.0})
    with pytest.raises(ValidationError):
        wide.__setattr__("adjacent", 0.1)  # assigning to a frozen field on purpose: pydantic must refuse


# ----- geometry -----------------------------------------------------------------------------
boxes = st.tuples(
    st.floats(-3, 3),
    st.floats(-3, 3),
    st.floats(0.1, 2),
    st.floats(0.1, 2),
    st.floats(0, 2 * np.pi),
)


def _box(i: int, spec: tuple[float, float, float, float, float]) -> SceneObject:
    x, y, w, d, yaw = spec
    return obj(
        f"box_{i}", (x, y, 0.5), (w, d, 1.0), facing=(float(np.cos(yaw)), float(np.sin(yaw)))
    )


def _boundary(o: SceneObject, n: int = 200) -> np.ndarray:
    c = o.footprint()
    t = np.linspace(0, 1, n, endpoint=False)[:, None]
    return np.concatenate([c[i] + t * (c[(i + 1) % 4] - c[i]) for i in range(4)])


@settings(max_examples=60, deadline=None)
@given(boxes, boxes)
def test_footprint_distance_matches_brute_force(
    a_spec: tuple[float, float, float, float, float], b_spec: tuple[float, float, float, float, float]
) -> None:
    a, b = _box(1, a_spec), _box(2, b_spec)
    d = footprint_distance(a, b)
    assert d == pytest.approx(footprint_distance(b, a), abs=1e-9)
    pa, pb = _boundary(a), _boundary(b)
    brute = float(np.min(np.linalg.norm(pa[:, None] - pb[None], axis=2)))
    inside = bool(a.contains_xy(b.center_xy)) or bool(b.contains_xy(a.center_xy))
    if d == 0.0:
        # overlapping footprints: boundaries cross or one contains the other
        assert brute < 0.05 or inside
    else:
        assert d <= brute + 1e-9 and brute - d < 0.03
    # point distance agrees with the polygon distance for a point-sized box
    p = np.array([[a_spec[0], a_spec[1]]])
    assert float(point_footprint_distance(b, p)[0]) == pytest.approx(
        footprint_distance(obj("dot_1", (a_spec[0], a_spec[1], 0.5), (0.0, 0.0, 1.0)), b), abs=1e-9
    )


def test_box_distance_adds_the_vertical_gap() -> None:
    low = obj("box_1", (0, 0, 0.5), (1, 1, 1))
    high = obj("box_2", (0, 0, 2.0), (1, 1, 1))  # 0.5 m above
    side = obj("box_3", (2.0, 0, 2.0), (1, 1, 1))  # 1 m to the side and 0.5 m above
    assert box_distance(low, high) == pytest.approx(0.5)
    assert box_distance(low, side) == pytest.approx(np.hypot(1.0, 0.5))


# ----- text forms ---------------------------------------------------------------------------
def test_text_forms(house: SceneGraph) -> None:
    data = json.loads(scene_graph_json(house))
    assert set(data) == set(house.scene.object_names)
    assert "on cabinet_1" in data["coffee_maker_1"]["relations"]
    assert data["coffee_maker_1"]["level"] == 1
    assert "facing" not in data["table_3"] and "facing" in data["fridge_1"]
    assert scene_graph_json(house) == scene_graph_json(
        build_scene_graph(house.scene)
    )  # deterministic
    lines = object_list_text(house.scene).splitlines()
    assert len(lines) == len(house.scene.objects) and lines[0].startswith("cabinet_1: position [")
    assert "relations" not in object_list_text(house.scene) and "cabinet_1" not in lines[1]
    assert clusters_text([["a_1", "b_1"], ["c_1"]]) == "region 1: a_1, b_1\nregion 2: c_1"

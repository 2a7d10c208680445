"""The bundled scenes: generated from their layouts, plausible, and usable by every character."""

from __future__ import annotations

import itertools
from importlib import resources

import numpy as np
import pytest

from storyteller.sim.paths.nav_grid import build_nav_grid
from storyteller.sim.scene.authoring import LAYOUTS, build_scene, scene_json
from storyteller.sim.scene.bundled import bundled_scene_names, load_bundled_scene
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.clusters import cluster_objects
from storyteller.tools.scene_graph import build_scene_graph, point_footprint_distance

NAMES = ["home", "office", "restaurant"]
SEAT_LABELS = {"chair", "armchair", "office_chair", "couch", "bench"}


@pytest.fixture(scope="module", params=NAMES)
def scene(request: pytest.FixtureRequest) -> Scene:
    return load_bundled_scene(request.param)


def test_names() -> None:
    assert bundled_scene_names() == NAMES


@pytest.mark.parametrize("name", NAMES)
def test_shipped_json_is_what_the_layout_builds(name: str) -> None:
    shipped = (resources.files("storyteller.sim.scene") / "scenes" / f"{name}.json").read_text(encoding="utf-8")
    assert shipped == scene_json(build_scene(LAYOUTS[name])), "run: python -m storyteller.sim.scene.authoring"


def test_size_and_bounds(scene: Scene) -> None:
    assert 20 <= len(scene.objects) <= 50
    assert scene.floor_z == 0.0 and scene.bounds_min == (0.0, 0.0)
    assert scene.nav.cell_size == pytest.approx(0.3)
    lo, hi = np.array(scene.bounds_min), np.array(scene.bounds_max)
    for obj in scene.objects:
        corners = obj.footprint()
        assert (corners >= lo - 1e-9).all() and (corners <= hi + 1e-9).all(), obj.name
        assert obj.z_min >= -1e-9 and obj.height > 0 and min(obj.size) > 0, obj.name


def test_labels_cover_the_reference_actions() -> None:
    """Every object a reference action label needs exists in some bundled scene."""
    labels = set().union(*(set(load_bundled_scene(n).labels) for n in NAMES))
    needed = {
        "coffee_maker", "fridge", "microwave", "toaster", "dishwasher", "cabinet", "tv", "laptop",
        "bookshelf", "white_board", "water_dispenser", "bar_counter", "record_player", "table",
        "chair", "couch", "plate", "desk", "monitor", "reception_desk", "stool", "dvd_player",
        "loudspeaker", "wine_rack", "bottle", "book",
    }  # fmt: skip
    assert needed <= labels, sorted(needed - labels)


def _footprints_overlap(a: SceneObject, b: SceneObject, tol: float = 1e-3) -> bool:
    """Separating-axis test on the two footprints (touching is not overlapping)."""
    pa, pb = a.footprint(), b.footprint()
    for poly in (pa, pb):
        for k in range(4):
            edge = poly[(k + 1) % 4] - poly[k]
            normal = np.array([-edge[1], edge[0]]) / np.linalg.norm(edge)
            sa, sb = pa @ normal, pb @ normal
            if sa.max() <= sb.min() + tol or sb.max() <= sa.min() + tol:
                return False
    return True


def test_nothing_overlaps(scene: Scene) -> None:
    for a, b in itertools.combinations(scene.objects, 2):
        shared_height = min(a.z_max, b.z_max) - max(a.z_min, b.z_min)
        assert not (shared_height > 1e-3 and _footprints_overlap(a, b)), (a.name, b.name)


def test_supported_objects_stand_on_their_supporter(scene: Scene) -> None:
    graph = build_scene_graph(scene)
    for obj in scene.objects:
        if obj.z_min < 0.05:
            continue
        supporter = graph.supporter(obj.name)
        assert supporter is not None, f"{obj.name} floats"
        base = scene.get(supporter)
        assert obj.z_min == pytest.approx(base.z_max, abs=1e-6)
        assert base.contains_xy(obj.footprint(), margin=1e-6).all(), (obj.name, supporter)


@pytest.mark.parametrize(
    ("name", "triples"),
    [
        (
            "home",
            [
                ("coffee_maker_1", "on", "cabinet_1"),
                ("microwave_1", "on", "cabinet_2"),
                ("tv_1", "on", "tv_stand_1"),
            ],
        ),
        (
            "office",
            [
                ("coffee_maker_1", "on", "cabinet_2"),
                ("laptop_1", "on", "desk_4"),
                ("tv_1", "on", "cabinet_1"),
            ],
        ),
        (
            "restaurant",
            [("bottle_1", "on", "bar_counter_1"), ("coffee_maker_1", "on", "cabinet_1")],
        ),
    ],
)
def test_support_relations(name: str, triples: list[tuple[str, str, str]]) -> None:
    found = set(build_scene_graph(load_bundled_scene(name)).triples())
    assert set(triples) <= found


def test_seats(scene: Scene) -> None:
    seats = [o for o in scene.objects if o.is_seat]
    assert len(seats) >= 4
    for obj in scene.objects:
        if obj.label in SEAT_LABELS:
            assert obj.is_seat and obj.has_facing, obj.name
            assert 0.4 <= obj.sit_offset_vertical <= 0.5, obj.name
            assert 0.0 <= obj.sit_offset_horizontal <= 0.2, obj.name
        elif obj.label == "stool":
            assert obj.sit_offset_vertical == pytest.approx(obj.height)
        else:
            assert not obj.is_seat, obj.name


def test_every_seat_has_free_floor_in_front(scene: Scene) -> None:
    """The strip just in front of a seat is not inside any other floor object."""
    for seat in (o for o in scene.objects if o.is_seat and o.has_facing):
        f = np.asarray(seat.facing)
        for along in (-0.3, 0.0, 0.3):
            point = seat.center_xy + f * (seat.depth / 2 + 0.08) + seat.right * along * seat.width
            for other in scene.objects:
                if other is not seat and other.z_min < 0.05:
                    assert not other.contains_xy(point), (seat.name, other.name)


def test_chairs_face_their_tables(scene: Scene) -> None:
    """A chair's facing ray meets the nearest table or desk within 0.3 m of its front edge."""
    tables = [o for o in scene.objects if o.label in {"table", "desk"}]
    for chair in (o for o in scene.objects if o.label in {"chair", "office_chair"}):
        f = np.asarray(chair.facing)
        hits = [t for t in tables if t.contains_xy(chair.center_xy + f * (chair.depth / 2 + 0.3))]
        assert hits, chair.name


def test_everything_is_reachable(scene: Scene) -> None:
    """One walkable area holds (almost) all free cells, and reaches every object and seat."""
    grid = build_nav_grid(scene)
    main = grid.component == grid.main_component
    assert main.sum() >= 0.95 * grid.free.sum()
    centers = grid.centers(np.argwhere(main))
    for obj in scene.objects:
        if (
            obj.is_seat and obj.has_facing
        ):  # from the front edge of the seat (a body stands up there)
            f, r = np.asarray(obj.facing), obj.right
            edge = obj.center_xy + f * obj.depth / 2
            ends = [edge - r * obj.width / 2, edge + r * obj.width / 2]
            t = np.clip(((centers - ends[0]) @ (ends[1] - ends[0])) / max(obj.width**2, 1e-9), 0, 1)
            dist = np.linalg.norm(
                centers - (ends[0] + t[:, None] * (ends[1] - ends[0])), axis=1
            ).min()
            assert dist <= 0.9, (obj.name, dist)
        else:
            dist = point_footprint_distance(obj, centers).min()
            assert dist <= 1.1, (obj.name, dist)


def test_functional_areas(scene: Scene) -> None:
    groups = [c for c in cluster_objects(scene) if len(c) >= 3]
    assert 2 <= len(groups) <= 6

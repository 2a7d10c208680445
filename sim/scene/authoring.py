"""The bundled scenes (``sim/scene/scenes/*.json``), written as compact layouts.

Each scene is a list of ``Item`` rows: label, centre xy, size (width across the facing, depth
along it, height), facing in degrees from +x (``None``: the object has no front), and
optionally the object it stands on. Indices are given per label in row order (``chair_1``,
``chair_2``...). Objects on a supporter start at the supporter's top; the rest stand on the
floor (z = 0). Seats get their seat offsets from ``SEATS``.

The JSON files are generated from these layouts (``python -m storyteller.sim.scene.authoring``); a test
checks that the shipped JSON equals what the layouts build, that nothing overlaps, that
supported objects lie on their supporter and that every seat and appliance is reachable.

Layout conventions: x to the right, y up the page (the top-down plot), floor rectangle from
(0, 0). Furniture sizes are ordinary ones (dining table 0.75 m high, chair seat 0.45 m,
counter 0.9 m, bar counter 1.05 m, bar stool 0.75 m); chairs stand with their front edge about
0.12-0.2 m from the table edge, as if pulled out to be sat on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from storyteller.sim.scene.model import NavHints, Scene, SceneObject

# label -> (seat height above the object's bottom in metres (None: the top of the object),
# seat point offset along the facing as a fraction of the depth)
SEATS: dict[str, tuple[float | None, float]] = {
    "chair": (0.45, 0.1),
    "armchair": (0.42, 0.1),
    "office_chair": (0.47, 0.05),
    "couch": (0.42, 0.1),
    "bench": (0.45, 0.0),
    "stool": (None, 0.0),
}
NAV = NavHints(cell_size=0.3, body_radius=0.25)


@dataclass(frozen=True)
class Item:
    """One object of a layout. Lengths in metres, ``facing`` in degrees from +x."""

    label: str
    x: float
    y: float
    w: float
    d: float
    h: float
    facing: float | None = None
    on: str | None = None


@dataclass(frozen=True)
class Layout:
    name: str
    size: tuple[float, float]
    items: tuple[Item, ...]


N, S, E, W = 90.0, -90.0, 0.0, 180.0  # facing +y, -y, +x, -x

HOME = Layout(
    "home",
    (8.0, 8.0),
    (
        # kitchen along the bottom wall: fridge, counters with appliances, dishwasher
        Item("fridge", 0.45, 0.38, 0.8, 0.72, 1.8, N),
        Item("cabinet", 1.95, 0.32, 1.9, 0.62, 0.9, N),
        Item("dishwasher", 3.22, 0.32, 0.6, 0.62, 0.88, N),
        Item("cabinet", 4.16, 0.32, 1.2, 0.62, 0.9, N),
        Item("coffee_maker", 1.3, 0.36, 0.25, 0.3, 0.38, N, on="cabinet_1"),
        Item("toaster", 1.85, 0.38, 0.3, 0.2, 0.2, N, on="cabinet_1"),
        Item("microwave", 4.16, 0.38, 0.5, 0.38, 0.3, N, on="cabinet_2"),
        # dining table with four chairs
        Item("table", 2.2, 2.6, 1.6, 0.9, 0.75),
        Item("chair", 1.8, 1.74, 0.48, 0.52, 0.95, N),
        Item("chair", 2.6, 1.74, 0.48, 0.52, 0.95, N),
        Item("chair", 1.8, 3.46, 0.48, 0.52, 0.95, S),
        Item("chair", 2.6, 3.46, 0.48, 0.52, 0.95, S),
        Item("plate", 1.8, 2.35, 0.26, 0.26, 0.03, None, on="table_1"),
        Item("plate", 2.6, 2.85, 0.26, 0.26, 0.03, None, on="table_1"),
        # living room: couch and armchair around a coffee table, TV on a stand, music corner
        Item("couch", 4.0, 5.5, 2.1, 0.9, 0.85, N),
        Item("table", 4.0, 6.7, 1.1, 0.6, 0.42),
        Item("armchair", 2.4, 6.7, 0.85, 0.85, 0.9, E),
        Item("tv_stand", 4.0, 7.63, 1.6, 0.5, 0.5, S),
        Item("tv", 4.0, 7.8, 1.2, 0.08, 0.7, S, on="tv_stand_1"),
        Item("dvd_player", 4.45, 7.54, 0.36, 0.26, 0.07, S, on="tv_stand_1"),
        Item("book", 3.75, 6.7, 0.22, 0.16, 0.04, None, on="table_2"),
        Item("bookshelf", 0.18, 6.5, 1.0, 0.34, 1.9, E),
        Item("table", 6.9, 7.55, 0.6, 0.45, 0.6),
        Item("record_player", 6.9, 7.55, 0.42, 0.34, 0.12, S, on="table_3"),
        Item("loudspeaker", 7.6, 7.7, 0.25, 0.3, 1.0, S),
        Item("loudspeaker", 2.6, 7.7, 0.25, 0.3, 1.0, S),
        Item("potted_plant", 7.55, 5.2, 0.5, 0.5, 1.2),
        Item("potted_plant", 0.35, 4.4, 0.45, 0.45, 0.9),
        Item("floor_lamp", 5.45, 5.3, 0.35, 0.35, 1.6),
        # home-office nook: desk, chair, laptop
        Item("desk", 7.45, 2.2, 1.2, 0.6, 0.75, W),
        Item("chair", 6.65, 2.2, 0.5, 0.52, 0.95, E),
        Item("laptop", 7.4, 2.2, 0.34, 0.25, 0.24, W, on="desk_1"),
    ),
)

OFFICE = Layout(
    "office",
    (10.8, 8.0),
    (
        # open workspace: two rows of three desks, chairs facing the desks
        *(Item("desk", x, 0.6, 1.4, 0.7, 0.75, N) for x in (1.0, 2.6, 4.2)),
        *(Item("desk", x, 3.6, 1.4, 0.7, 0.75, S) for x in (1.0, 2.6, 4.2)),
        *(Item("office_chair", x, 1.36, 0.6, 0.56, 1.0, S) for x in (1.0, 2.6, 4.2)),
        *(Item("office_chair", x, 2.84, 0.6, 0.56, 1.0, N) for x in (1.0, 2.6, 4.2)),
        *(
            Item("monitor", x, 0.5, 0.55, 0.18, 0.45, N, on=f"desk_{k}")
            for k, x in enumerate((1.0, 2.6, 4.2), 1)
        ),
        *(
            Item("laptop", x, 3.6, 0.34, 0.25, 0.24, S, on=f"desk_{k}")
            for k, x in enumerate((1.0, 2.6, 4.2), 4)
        ),
        # meeting room: table for six, TV on a low cabinet, mobile whiteboard
        Item("table", 8.2, 2.2, 2.2, 1.0, 0.75),
        *(Item("chair", x, 1.27, 0.5, 0.52, 0.9, N) for x in (7.5, 8.2, 8.9)),
        *(Item("chair", x, 3.13, 0.5, 0.52, 0.9, S) for x in (7.5, 8.2, 8.9)),
        Item("cabinet", 6.35, 2.2, 1.6, 0.45, 0.6, E),
        Item("tv", 6.32, 2.2, 1.4, 0.08, 0.8, E, on="cabinet_1"),
        Item("white_board", 10.45, 2.2, 1.5, 0.5, 1.9, W),
        # break area: kitchenette along the top wall, lounge, a small table for two
        Item("fridge", 0.45, 7.6, 0.7, 0.7, 1.8, S),
        Item("cabinet", 2.0, 7.68, 2.2, 0.62, 0.9, S),
        Item("coffee_maker", 1.4, 7.7, 0.25, 0.3, 0.38, S, on="cabinet_2"),
        Item("microwave", 2.5, 7.7, 0.5, 0.38, 0.3, S, on="cabinet_2"),
        Item("water_dispenser", 3.5, 7.78, 0.35, 0.35, 1.2, S),
        Item("bookshelf", 5.2, 7.82, 1.2, 0.34, 1.9, S),
        Item("couch", 8.0, 7.5, 2.0, 0.9, 0.85, S),
        Item("table", 8.0, 6.3, 1.0, 0.55, 0.42),
        Item("table", 3.0, 5.6, 0.8, 0.8, 0.75),
        Item("chair", 2.17, 5.6, 0.5, 0.52, 0.9, E),
        Item("chair", 3.83, 5.6, 0.5, 0.52, 0.9, W),
        Item("potted_plant", 10.4, 7.6, 0.5, 0.5, 1.3),
        Item("potted_plant", 0.35, 4.8, 0.45, 0.45, 1.1),
    ),
)

RESTAURANT = Layout(
    "restaurant",
    (11.0, 9.5),
    (
        # dining room: two tables for four, two tables for two
        Item("table", 1.8, 2.4, 0.9, 0.9, 0.75),
        Item("table", 4.8, 2.4, 0.9, 0.9, 0.75),
        Item("table", 1.8, 5.3, 0.8, 0.8, 0.75),
        Item("table", 4.8, 5.3, 0.8, 0.8, 0.75),
        *(
            Item("chair", tx + dx, ty + dy, 0.45, 0.5, 0.9, f)
            for tx, ty in ((1.8, 2.4), (4.8, 2.4))
            for dx, dy, f in ((0.0, -0.82, N), (0.0, 0.82, S), (-0.82, 0.0, E), (0.82, 0.0, W))
        ),
        *(
            Item("chair", tx + dx, 5.3, 0.45, 0.5, 0.9, f)
            for tx in (1.8, 4.8)
            for dx, f in ((-0.77, E), (0.77, W))
        ),
        Item("plate", 1.8, 2.1, 0.27, 0.27, 0.03, None, on="table_1"),
        Item("plate", 1.8, 2.7, 0.27, 0.27, 0.03, None, on="table_1"),
        Item("plate", 4.5, 2.4, 0.27, 0.27, 0.03, None, on="table_2"),
        Item("plate", 5.1, 2.4, 0.27, 0.27, 0.03, None, on="table_2"),
        # bar along the top wall: counter with stools, back bar with wine rack and coffee machine
        Item("bar_counter", 8.0, 7.8, 3.6, 0.7, 1.05, S),
        *(Item("stool", x, 7.2, 0.4, 0.4, 0.75) for x in (6.8, 7.6, 8.4, 9.2)),
        Item("bottle", 9.4, 7.95, 0.08, 0.08, 0.3, None, on="bar_counter_1"),
        Item("bottle", 9.55, 7.95, 0.08, 0.08, 0.3, None, on="bar_counter_1"),
        Item("wine_rack", 8.0, 9.25, 2.4, 0.4, 1.9, S),
        Item("cabinet", 10.7, 8.2, 1.2, 0.5, 0.9, W),
        Item("coffee_maker", 10.72, 8.45, 0.3, 0.3, 0.4, W, on="cabinet_1"),
        # entrance: reception desk with the till, a bench to wait on, plants
        Item("reception_desk", 8.4, 1.5, 1.8, 0.6, 1.1, W),
        Item("cash_register", 8.45, 1.2, 0.35, 0.3, 0.2, W, on="reception_desk_1"),
        Item("bench", 10.55, 3.2, 1.4, 0.45, 0.45, W),
        Item("potted_plant", 0.4, 0.4, 0.55, 0.55, 1.4),
        Item("potted_plant", 0.4, 9.1, 0.55, 0.55, 1.4),
        Item("potted_plant", 10.6, 0.4, 0.55, 0.55, 1.4),
    ),
)

LAYOUTS: dict[str, Layout] = {layout.name: layout for layout in (HOME, OFFICE, RESTAURANT)}


def _unit(degrees: float) -> tuple[float, float]:
    a = math.radians(degrees)
    return (round(math.cos(a), 9) + 0.0, round(math.sin(a), 9) + 0.0)


def build_scene(layout: Layout) -> Scene:
    """The ``Scene`` a layout describes."""
    counts: dict[str, int] = {}
    objects: dict[str, SceneObject] = {}
    for item in layout.items:
        counts[item.label] = counts.get(item.label, 0) + 1
        idx = counts[item.label]
        bottom = objects[item.on].z_max if item.on is not None else 0.0
        seat_v, seat_h = 0.0, 0.0
        if item.label in SEATS:
            rule_v, seat_h = SEATS[item.label]
            seat_v = item.h if rule_v is None else rule_v
        obj = SceneObject(
            name=f"{item.label}_{idx}",
            label=item.label,
            idx=idx,
            center=(item.x, item.y, round(bottom + item.h / 2.0, 6)),
            size=(item.w, item.d, item.h),
            facing=_unit(item.facing if item.facing is not None else N),
            has_facing=item.facing is not None,
            sit_offset_horizontal=seat_h,
            sit_offset_vertical=seat_v,
        )
        objects[obj.name] = obj
    return Scene(
        name=layout.name,
        bounds_min=(0.0, 0.0),
        bounds_max=layout.size,
        objects=tuple(objects.values()),
        nav=NAV,
    )


def scene_json(scene: Scene) -> str:
    """The exact text of a bundled scene file."""
    return scene.model_dump_json(indent=2) + "\n"


def write_bundled_scenes(folder: Path) -> list[Path]:
    """Write every layout as ``<folder>/<name>.json``; returns the paths written."""
    paths = []
    for layout in LAYOUTS.values():
        path = folder / f"{layout.name}.json"
        path.write_text(scene_json(build_scene(layout)), encoding="utf-8")
        paths.append(path)
    return paths


if __name__ == "__main__":  # pragma: no cover - regenerates the package data
    for written in write_bundled_scenes(Path(__file__).resolve().parent / "scenes"):
        print(written)

"""Typed scene model: instance-segmented objects as oriented boxes on a z-up floor.

Conventions used everywhere in the project:

- metres, z up, the floor at ``floor_z`` (0 for every bundled and reference scene);
- an object's ``facing`` is the unit xy direction its front points to (``has_facing`` tells
  whether the object really has a front; tables and plants usually do not);
- ``size = (width, depth, height)``: width across the facing, depth along it, height along z;
- ``center`` is the centre of the box (so its bottom is ``center.z - height / 2``);
- the object's own right is the facing turned clockwise: ``(fy, -fx)``; left is ``(-fy, fx)``.

Bounds (a scene may come from anyone, and every later step is paid per object and per cell):
at most ``MAX_SCENE_OBJECTS`` objects, labels of at most ``MAX_LABEL_CHARS`` characters and
indices below ``MAX_OBJECT_INDEX``, finite coordinates within ``MAX_COORDINATE`` metres, and a
floor that the navigation grid covers with at most ``MAX_NAV_CELLS`` cells of ``nav.cell_size``
(counted here, before any grid is allocated). A scene outside them is a validation error.
"""

from __future__ import annotations

import math
import re
from functools import cached_property
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

NAME_PATTERN = re.compile(r"^(?P<label>[a-z][a-z0-9_]*?)_(?P<idx>\d+)$")

MAX_SCENE_OBJECTS = 500
"""Objects a scene *file* may hold (the bundled and reference scenes hold 23-51; checked by the
scene and mesh readers). Every object is checked against the navigation grid and described to
the planner: 2,000 objects spread over their floor cost ``scene inspect`` 43 s (500: about 5 s)."""
MAX_BUILT_SCENE_OBJECTS = 2_000
"""Objects a scene the program builds itself may hold (``storyteller.benchmark.crowd_scenario.tiled``: the
"Office x16" of the crowd benchmark has 816); the model's own bound."""
MAX_LABEL_CHARS = 64
"""Characters of an object label (``coffee_maker``); a name adds ``_<idx>``."""
MAX_OBJECT_INDEX = 999_999
"""Largest instance index within a label."""
MAX_SCENE_NAME_CHARS = 128
MAX_COORDINATE = 100_000.0
"""Metres: every coordinate and size of a scene lies within +-this (100 km)."""
FLOOR_STANDING_M = 0.10
"""Metres: furniture whose bottom is this close to the floor stands on it (an obstacle to a body's
feet, and to a body sitting beside it)."""
MAX_NAV_CELLS = 100_000
"""Cells of the navigation grid over the floor (``storyteller.sim.paths.nav_grid`` refuses more too): a
95 m square at the default 0.3 m (the bundled scenes need about 700-3,300). Building a grid costs
tens of microseconds per cell: a 590 m floor's 3.9 million took 24 s and 2.3 GB."""

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]


class SceneObject(BaseModel):
    """One object instance. Immutable; derived geometry is computed on demand."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    name: str = Field(description="Unique object name, '<label>_<idx>', e.g. 'chair_3'.")
    label: str = Field(
        max_length=MAX_LABEL_CHARS, description="Object category, lower snake case, e.g. 'coffee_maker'."
    )
    idx: int = Field(ge=0, le=MAX_OBJECT_INDEX, description="Instance index within the label.")
    center: Vec3 = Field(description="Box centre [x, y, z] in metres.")
    size: Vec3 = Field(description="[width, depth, height] in metres; width across the facing.")
    facing: Vec2 = Field(default=(0.0, 1.0), description="Unit xy direction of the object's front.")
    has_facing: bool = Field(default=False, description="Whether the object has a meaningful front.")
    sit_offset_horizontal: float = Field(
        default=0.0, description="Seat point offset along the facing, as a fraction of depth."
    )
    sit_offset_vertical: float = Field(
        default=0.0, description="Seat height above the object's bottom, in metres (0: not a seat)."
    )
    interactive: bool = Field(default=True, description="Whether characters may use the object.")

    @field_validator("size")
    @classmethod
    def _size_not_negative(cls, value: Vec3) -> Vec3:
        if min(value) < 0.0:
            raise ValueError(f"every size component must be >= 0, got {list(value)}")
        return value

    @field_validator("center", "size")
    @classmethod
    def _within_reach(cls, value: Vec3) -> Vec3:
        return _within_coordinates(value)

    @field_validator("facing")
    @classmethod
    def _facing_unit(cls, value: Vec2) -> Vec2:
        norm = math.hypot(*value)
        if norm < 1e-6:
            raise ValueError("facing must be a non-zero xy vector")
        if abs(norm - 1.0) <= 1e-12:  # already unit: keep the exact floats (JSON round-trips)
            return (float(value[0]), float(value[1]))
        if math.isinf(norm):  # finite numbers whose length overflows ([1.7e308, 1.7e308]): halved, same direction
            value = (value[0] / 2.0, value[1] / 2.0)
            norm = math.hypot(*value)
        return (value[0] / norm, value[1] / norm)

    @model_validator(mode="after")
    def _name_matches_label(self) -> SceneObject:
        if self.name != f"{self.label}_{self.idx}":
            raise ValueError(
                f"name must be '<label>_<idx>' = '{self.label}_{self.idx}', got '{self.name[:80]}'"
            )
        return self

    # ----- derived geometry -------------------------------------------------------------
    @property
    def width(self) -> float:
        return self.size[0]

    @property
    def depth(self) -> float:
        return self.size[1]

    @property
    def height(self) -> float:
        return self.size[2]

    @property
    def z_min(self) -> float:
        return self.center[2] - self.size[2] / 2.0

    @property
    def z_max(self) -> float:
        return self.center[2] + self.size[2] / 2.0

    @property
    def center_xy(self) -> NDArray[np.float64]:
        return np.array(self.center[:2], dtype=np.float64)

    @property
    def right(self) -> NDArray[np.float64]:
        """The object's own right in the xy plane (facing turned clockwise)."""
        return np.array([self.facing[1], -self.facing[0]], dtype=np.float64)

    @property
    def yaw(self) -> float:
        """Angle of the facing from +x, radians."""
        return math.atan2(self.facing[1], self.facing[0])

    def footprint(self, margin: float = 0.0) -> NDArray[np.float64]:
        """The 4 xy corners of the box bottom (counter-clockwise), grown by ``margin``."""
        f = np.array(self.facing, dtype=np.float64)
        r = self.right
        hw = self.size[0] / 2.0 + margin
        hd = self.size[1] / 2.0 + margin
        c = self.center_xy
        return np.array([c - r * hw - f * hd, c + r * hw - f * hd, c + r * hw + f * hd, c - r * hw + f * hd])

    def to_local(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Points (..., 2) in the object's frame: [:, 0] along its right, [:, 1] along its facing."""
        d = np.asarray(xy, dtype=np.float64) - self.center_xy
        return np.stack([d @ self.right, d @ np.array(self.facing, dtype=np.float64)], axis=-1)

    def contains_xy(self, xy: NDArray[np.float64], margin: float = 0.0) -> NDArray[np.bool_]:
        """Whether xy points (..., 2) lie inside the footprint grown by ``margin``."""
        local = self.to_local(xy)
        return (np.abs(local[..., 0]) <= self.size[0] / 2.0 + margin) & (
            np.abs(local[..., 1]) <= self.size[1] / 2.0 + margin
        )

    @property
    def is_seat(self) -> bool:
        return self.sit_offset_vertical > 0.0

    def seat_point(self) -> NDArray[np.float64]:
        """Where a seated pelvis goes (xy): centre + facing * depth * sit offset."""
        return self.center_xy + np.array(self.facing) * self.size[1] * self.sit_offset_horizontal


_Coords = TypeVar("_Coords", Vec2, Vec3)


def _within_coordinates(value: _Coords) -> _Coords:
    if any(abs(v) > MAX_COORDINATE for v in value):
        raise ValueError(f"every number must lie within +-{MAX_COORDINATE:g} metres, got {list(value)}")
    return value


class NavHints(BaseModel):
    """Optional navigation-grid settings carried by a scene file (reference ``grid_map.json``)."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    cell_size: float = Field(default=0.3, gt=0.0)
    body_radius: float | None = Field(default=None, gt=0.0)
    # Reference-grid cell overrides, as [i, j] integer pairs in the reference grid's indexing.
    occupied: tuple[tuple[int, int], ...] = Field(default=(), max_length=MAX_NAV_CELLS)
    unoccupied: tuple[tuple[int, int], ...] = Field(default=(), max_length=MAX_NAV_CELLS)
    grid_origin: Vec2 = (0.0, 0.0)

    @field_validator("grid_origin")
    @classmethod
    def _within_reach(cls, value: Vec2) -> Vec2:
        return _within_coordinates(value)


def nav_cell_bound(bounds_min: Vec2, bounds_max: Vec2, cell_size: float) -> float:
    """An upper bound of the cells a navigation grid of ``cell_size`` metres needs over the floor
    rectangle (two more per axis than the rectangle holds: a grid aligned with a reference grid
    starts up to 1.5 cells before the floor). Infinite when the count overflows a float."""
    nx = (bounds_max[0] - bounds_min[0]) / cell_size
    ny = (bounds_max[1] - bounds_min[1]) / cell_size
    if not (math.isfinite(nx) and math.isfinite(ny)):
        return math.inf
    return float(math.ceil(nx) + 2) * float(math.ceil(ny) + 2)


class Scene(BaseModel):
    """A whole scene: named objects plus the walkable floor rectangle."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    format: str = Field(default="storyteller-scene/1", pattern=r"^storyteller-scene/1$")
    name: str = Field(min_length=1, max_length=MAX_SCENE_NAME_CHARS)
    floor_z: float = Field(default=0.0, ge=-MAX_COORDINATE, le=MAX_COORDINATE)
    bounds_min: Vec2 = Field(description="Floor rectangle lower corner [x, y].")
    bounds_max: Vec2 = Field(description="Floor rectangle upper corner [x, y].")
    objects: tuple[SceneObject, ...] = Field(max_length=MAX_BUILT_SCENE_OBJECTS)
    nav: NavHints = NavHints()

    @field_validator("bounds_min", "bounds_max")
    @classmethod
    def _within_reach(cls, value: Vec2) -> Vec2:
        return _within_coordinates(value)

    @model_validator(mode="after")
    def _check(self) -> Scene:
        seen: set[str] = set()
        for obj in self.objects:
            if obj.name in seen:
                raise ValueError(f"duplicate object name '{obj.name}'")
            seen.add(obj.name)
        if self.bounds_max[0] <= self.bounds_min[0] or self.bounds_max[1] <= self.bounds_min[1]:
            raise ValueError("bounds_max must be greater than bounds_min on x and y")
        cells = nav_cell_bound(self.bounds_min, self.bounds_max, self.nav.cell_size)
        if cells > MAX_NAV_CELLS:
            raise ValueError(
                f"the floor needs about {cells:.3g} navigation cells of {self.nav.cell_size:g} m "
                f"(at most {MAX_NAV_CELLS:,} allowed): use a larger nav.cell_size or a smaller floor"
            )
        return self

    @cached_property
    def by_name(self) -> dict[str, SceneObject]:
        return {o.name: o for o in self.objects}

    def get(self, name: str) -> SceneObject:
        """The object called ``name``; raises KeyError listing close names otherwise."""
        try:
            return self.by_name[name]
        except KeyError:
            raise KeyError(name) from None

    @property
    def object_names(self) -> list[str]:
        return [o.name for o in self.objects]

    @property
    def labels(self) -> list[str]:
        return sorted({o.label for o in self.objects})

"""What event programs see of the characters (``WorldView``) and what they produce (``CharacterPlan``).

``world_view_from_reference_case`` reads a reference benchmark test case: its ``current_states``
(who is where, doing what) and ``planning_history`` (which events are ongoing / looping /
completed). Positions there are text ("sit on chair_6", "adjacent to coffee_maker_1"); a seat
puts the character on the seat slot, any other area is turned into one concrete point with the
project's own sampler, seeded by the character's name, so the same file always gives the same
world. Positions are metres in the scene frame; facings are unit xy vectors.
"""

from __future__ import annotations

import math
import re
import zlib
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools import areas
from storyteller.tools.errors import UnsatisfiableAreaError
from storyteller.tools.position_sampling import Constraints, FloorMap, Placement, sample_position

Point = tuple[float, float]


class CharacterState(BaseModel):
    """One character as the planner sees it."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    name: str = Field(min_length=1)
    position: Point | None = Field(
        default=None, description="Current xy (m); None: not placed yet."
    )
    facing: Point | None = Field(default=None, description="Unit xy direction the character faces.")
    action: str = Field(default="idle", description="Current action label.")
    busy: bool = Field(default=False, description="Inside an ongoing, non-interruptible event.")
    target_position: Point | None = Field(
        default=None, description="Where the character is walking to."
    )
    seat: str | None = Field(default=None, description="Object the character sits or lies on.")
    area: str | None = Field(
        default=None, description="Area text of the current position, e.g. 'sit on chair_6'."
    )


class WorldView(BaseModel):
    """All characters plus the objects they use (object name -> character name)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    characters: tuple[CharacterState, ...] = ()
    objects_in_use: dict[str, str] = Field(default_factory=dict)
    busy_objects: Literal["refuse", "wait"] = Field(
        default="refuse",
        description="A plan giving a character an object another one uses alone (tools.object_use): "
        "refused with ObjectInUseError, or the character waits there (idle, facing it).",
    )

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.characters]

    def character(self, name: str) -> CharacterState | None:
        return next((c for c in self.characters if c.name == name), None)

    def points_to_avoid(
        self, exclude: set[str] | frozenset[str] = frozenset()
    ) -> tuple[Point, ...]:
        """Positions and targets of the characters not in ``exclude``."""
        points: list[Point] = []
        for c in self.characters:
            if c.name in exclude:
                continue
            points += [p for p in (c.position, c.target_position) if p is not None]
        return tuple(points)


class CharacterPlan(BaseModel):
    """The outcome of an event program for one character."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    character: str
    action: str = Field(description="Target action label.")
    position: Point = Field(description="Target xy (m): where the pelvis goes.")
    facing: Point = Field(description="Unit xy direction to face at the target.")
    area: str = Field(description="Short text of the area the position was drawn from.")
    seat: str | None = Field(default=None, description="Seat object, when sitting.")


class ReferenceCaseError(ValueError):
    """A reference test case that cannot be read. ``str()`` names the field."""


_AREA_TEXT = re.compile(
    r"^(?P<rel>sit on|lie on|adjacent to|close to|in front of|behind|to the left of|to the right of|inside)"
    r" (?P<a>[a-z][a-z0-9_]*)$"
    r"|^(?P<rel2>between|aligned with) (?P<b1>[a-z][a-z0-9_]*) and (?P<b2>[a-z][a-z0-9_]*)$"
)


def area_from_text(text: str, scene: Scene) -> areas.Area:
    """An area from reference text such as "adjacent to coffee_maker_1" or "sit on chair_6"."""
    m = _AREA_TEXT.match(text.strip())
    if m is None:
        raise ReferenceCaseError(f"unknown position expression '{text}'")

    def obj(name: str) -> SceneObject:
        if name not in scene.by_name:
            raise ReferenceCaseError(
                f"position '{text}' names an object '{name}' the scene does not have"
            )
        return scene.by_name[name]

    if m.group("rel2"):
        a, b = obj(m.group("b1")), obj(m.group("b2"))
        return areas.between(a, b) if m.group("rel2") == "between" else areas.aligned_with(a, b)
    rel, anchor = m.group("rel"), obj(m.group("a"))
    if rel in ("sit on", "lie on"):
        return areas.to_sit_on(anchor)
    if rel == "adjacent to":
        return areas.adjacent_to(anchor)
    if rel in ("close to", "inside"):
        return areas.close_to(anchor)
    return areas.directional(anchor, rel)


def _unit(v: NDArray[np.float64]) -> Point | None:
    n = float(np.hypot(v[0], v[1]))
    if not math.isfinite(n) or n < 1e-6:
        return None
    return (float(v[0] / n), float(v[1] / n))


def _strings(value: Any, where: str) -> list[str]:
    if value is None:
        return []
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ReferenceCaseError(f"{where}: expected a list of strings, got {value!r}")
    return value


def _place(
    area: areas.Area, scene: Scene, floor: FloorMap, avoid: tuple[Point, ...], seed: int
) -> Placement | None:
    """Sample the area; if it cannot hold the character (e.g. "in front of" a desk that faces a
    wall), fall back to "close to" its first anchor; None if that fails too."""
    candidates = [area]
    if area.anchors and not area.seats:
        candidates.append(areas.close_to(scene.by_name[area.anchors[0]]))
    for candidate in candidates:
        try:
            return sample_position(
                candidate, floor, Constraints(avoid=avoid), np.random.default_rng(seed)
            )
        except UnsatisfiableAreaError:
            continue
    return None


def world_view_from_reference_case(data: dict[str, Any], scene: Scene) -> WorldView:
    """The world of a reference test case (see the module docstring)."""
    if not isinstance(data, dict):
        raise ReferenceCaseError("expected a JSON object with 'current_states'")
    states = data.get("current_states")
    history = data.get("planning_history", [])
    if not isinstance(states, list):
        raise ReferenceCaseError("field 'current_states': expected a list")
    if not isinstance(history, list):
        raise ReferenceCaseError("field 'planning_history': expected a list")

    # latest event state per character, and its position text
    last_event: dict[str, tuple[str, list[str]]] = {}
    for i, event in enumerate(history):
        if not isinstance(event, dict):
            raise ReferenceCaseError(f"planning_history[{i}]: expected an object")
        for j, detail in enumerate(event.get("details", []) or []):
            if not isinstance(detail, dict) or not isinstance(detail.get("character"), str):
                raise ReferenceCaseError(
                    f"planning_history[{i}].details[{j}]: expected an object with 'character'"
                )
            where = f"planning_history[{i}].details[{j}].position"
            last_event[detail["character"]] = (
                str(event.get("state", "")),
                _strings(detail.get("position"), where),
            )

    floor = FloorMap(scene)
    placed: list[Point] = []
    raw: list[dict[str, Any]] = []
    for i, state in enumerate(states):
        if (
            not isinstance(state, dict)
            or not isinstance(state.get("name"), str)
            or not state["name"]
        ):
            raise ReferenceCaseError(
                f"current_states[{i}]: expected an object with a non-empty 'name'"
            )
        name = state["name"]
        texts = _strings(state.get("position"), f"current_states[{i}].position")
        event_state, event_texts = last_event.get(name, ("", []))
        if not texts and event_state in ("ongoing", "looping"):
            texts = event_texts
        looks = _strings(state.get("orientation"), f"current_states[{i}].orientation")
        action = state.get("current_action") or "idle"
        if not isinstance(action, str):
            raise ReferenceCaseError(f"current_states[{i}].current_action: expected a string")
        busy = str(state.get("state", "idle")) != "idle" and event_state != "looping"
        entry: dict[str, Any] = {"name": name, "action": action, "busy": busy, "position": None, "facing": None,
                                 "seat": None, "area": texts[0] if texts else None, "look": None}  # fmt: skip
        if texts:
            area = area_from_text(texts[0], scene)
            placement = _place(area, scene, floor, tuple(placed), zlib.crc32(name.encode()))
            if placement is not None:
                entry["position"] = placement.position
                entry["seat"] = placement.seat
                entry["facing"] = placement.seat_facing
                placed.append(placement.position)
                if placement.seat is None and area.focus is not None:
                    entry["facing"] = _unit(np.subtract(area.focus, placement.position))
        for look in looks:
            if look.startswith("look at "):
                entry["look"] = look[len("look at ") :].strip()
        raw.append(entry)

    positions = {e["name"]: e["position"] for e in raw}
    characters = []
    in_use: dict[str, str] = {}
    for e in raw:
        look, pos = e.pop("look"), e["position"]
        if look and pos is not None and e["seat"] is None:
            target = (
                scene.by_name[look].center[:2] if look in scene.by_name else positions.get(look)
            )
            if target is not None:
                e["facing"] = _unit(np.subtract(target, pos)) or e["facing"]
        characters.append(CharacterState(**e))
        if e["seat"] is not None:
            in_use.setdefault(e["seat"], e["name"])  # a couch may hold several; keep the first
        elif e["busy"] and e["area"]:
            for anchor in area_from_text(e["area"], scene).anchors:
                in_use.setdefault(anchor, e["name"])
    return WorldView(characters=tuple(characters), objects_in_use=in_use)

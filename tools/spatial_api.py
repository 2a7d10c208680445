"""The spatial API that event programs (``parse_event()``) call.

Objects are passed and returned as name strings (``"chair_3"``); areas are ``storyteller.tools.areas.Area``
values; characters are handles from ``get_character(name)``. Distances are metres. The handles
only record what the program asks for; ``SpatialAPI.resolve(seed)`` turns the records into
``CharacterPlan``s after the program has finished, so a failing program changes nothing.

Every mistake raises a ``storyteller.tools.errors.ToolError`` whose message is written for the LLM that
wrote the program (unknown names come with "did you mean" suggestions).
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal, TypeVar

import numpy as np

from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools import areas
from storyteller.tools.areas import Area
from storyteller.tools.character_states import CharacterPlan, CharacterState, WorldView
from storyteller.tools.errors import (
    PROGRAM_LINE,
    BlockedPositionError,
    ObjectInUseError,
    ToolArgumentError,
    UnknownActionError,
    UnknownCharacterError,
    UnknownObjectError,
    UnsatisfiableAreaError,
    did_you_mean,
)
from storyteller.tools.object_use import use_conflicts, users_of_objects
from storyteller.tools.position_sampling import Constraints, FloorMap, Placement, sample_position
from storyteller.tools.scene_graph import (
    SceneGraph,
    box_distance,
    build_scene_graph,
    point_footprint_distance,
)
from storyteller.tools.value_text import show

Point = tuple[float, float]
ASSOCIATED_DISTANCE = 0.3  # m: objects this close (box to box) are associated
CLOSE_DISTANCE = 1.0  # m: box-to-box distance for get_objects_close_to
MAX_NAME_CHARS = 40
"""Longest character name or action label a program may invent (when none are given)."""
_F = TypeVar("_F", bound=Callable[..., Any])
MAX_NEW_CHARACTERS = 12
"""Distinct characters a program may create when the world names none (no states given)."""


class CharacterHandle:
    """A character in an event program. Setters record the request; nothing moves until the
    whole program has run."""

    sandbox_attributes: ClassVar[frozenset[str]] = frozenset(
        {"name", "set_position", "set_orientation", "set_target_action"}
    )

    def __init__(self, api: SpatialAPI, name: str):
        self._api = api
        self._name = name

    @property
    def name(self) -> str:
        """The character's name."""
        return self._name

    def set_position(self, area: Any) -> None:
        """Where the character stands or sits: an area from a get_area_* function.

        An [x, y] point in metres is accepted too. Raises UnsatisfiableAreaError at once if no free spot of the area is left, and
        BlockedPositionError if [x, y] is not free floor (inside or within 0.25 m of floor
        furniture, or of the scene edge). An [x, y] within 0.5 m of another character's
        position or target is refused when the plans are made (the error names this line)."""
        target = self._api._position_target(area, self._name)
        record = self._api._record(self._name)
        record.position = target
        record.position_line = PROGRAM_LINE.get()

    def set_orientation(self, target: Any) -> None:
        """The object or character the character looks at.

        An Area or an [x, y] point is accepted too."""
        self._api._record(self._name).orientation = self._api._orientation_target(target)

    def set_target_action(self, label: Any) -> None:
        """The action label the character performs there (one of the action labels)."""
        self._api._record(self._name).action = self._api._action(label)

    def __repr__(self) -> str:
        return f"<character {self._name}>"


ApiKind = Literal["character", "query", "area", "seat_area", "area_operation"]
"""character: get_character; query: facts about objects; area: an Area built on object names;
seat_area: the Area of a seat's places; area_operation: an Area built from other Areas."""

_API_MARKS: dict[str, tuple[ApiKind, bool]] = {}
"""Method name -> (kind, listed), filled by :func:`api_function` as the class is defined."""


def api_function(kind: ApiKind, *, listed: bool = False) -> Callable[[_F], _F]:
    """Mark a SpatialAPI method as callable from event programs.

    ``listed``: also shown to the event-parser model (the prompt lists a few functions, which
    keeps a small model's prompt short; the program grammar offers only listed area functions).
    Every marked function may be called."""

    def mark(fn: _F) -> _F:
        _API_MARKS[fn.__name__] = (kind, listed)
        return fn

    return mark


@dataclass(frozen=True)
class ApiFunction:
    """One API function as a prompt or a grammar names it."""

    name: str
    kind: ApiKind
    listed: bool
    parameters: tuple[str, ...]
    """As written in a call: ``object``, ``label=None``, ``*more``."""
    returns: str
    summary: str
    """The docstring's first paragraph, on one line."""

    @property
    def call(self) -> str:
        """``get_area_between(object_1, object_2)``."""
        return f"{self.name}({', '.join(self.parameters)})"

    @property
    def signature(self) -> str:
        """``get_closest_object(anchor, label=None) -> str``."""
        return f"{self.call} -> {self.returns}"


def _parameters(fn: Callable[..., Any]) -> list[inspect.Parameter]:
    return [p for p in inspect.signature(fn).parameters.values() if p.name != "self"]


def _parameter_text(p: inspect.Parameter) -> str:
    if p.kind is inspect.Parameter.VAR_POSITIONAL:
        return f"*{p.name}"
    return p.name if p.default is inspect.Parameter.empty else f"{p.name}={p.default!r}"


def _summary(fn: Callable[..., Any]) -> str:
    return " ".join((inspect.getdoc(fn) or "").split("\n\n", 1)[0].split())


def _describe(name: str, fn: Callable[..., Any]) -> ApiFunction:
    kind, listed = _API_MARKS[name]
    params = _parameters(fn)
    returns = inspect.signature(fn).return_annotation
    return ApiFunction(
        name=name,
        kind=kind,
        listed=listed,
        parameters=tuple(_parameter_text(p) for p in params),
        returns=returns if isinstance(returns, str) else getattr(returns, "__name__", str(returns)),
        summary=_summary(fn),
    )


def handle_methods() -> tuple[ApiFunction, ...]:
    """The methods of a character handle a program may call (``c.set_position(area)``...), in
    the order CharacterHandle defines them."""
    return tuple(
        ApiFunction(
            name=name,
            kind="character",
            listed=True,
            parameters=tuple(_parameter_text(p) for p in _parameters(member)),
            returns="None",
            summary=_summary(member),
        )
        for name, member in vars(CharacterHandle).items()
        if name in CharacterHandle.sandbox_attributes and inspect.isfunction(member)
    )


@dataclass
class _Record:
    position: Area | Point | None = None
    orientation: str | Area | Point | None = None
    action: str | None = None
    position_line: int | None = None
    """Program line of the set_position call (for errors found when the plans are made)."""


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


class SpatialAPI:
    """Spatial queries, areas and character handles over one scene and one world view."""

    def __init__(
        self,
        scene: Scene,
        graph: SceneGraph | None = None,
        world: WorldView | None = None,
        action_labels: Sequence[str] | None = None,
        *,
        allow_new_characters: bool | None = None,
    ):
        self.scene = scene
        self.graph = graph if graph is not None else build_scene_graph(scene)
        self.world = world if world is not None else WorldView()
        self.action_labels = list(action_labels) if action_labels is not None else None
        # With no known characters (no states given) any name may be used.
        self.allow_new_characters = (
            not self.world.characters if allow_new_characters is None else allow_new_characters
        )
        self._floor = FloorMap(scene)
        self._records: dict[str, _Record] = {}
        self._handles: dict[str, CharacterHandle] = {}

    # ----- what the sandbox exposes ---------------------------------------------------------
    def namespace(self) -> dict[str, Callable[..., Any]]:
        """Name -> function for every API function an event program may call."""
        return {f.name: getattr(self, f.name) for f in self.functions()}

    @classmethod
    def functions(cls) -> tuple[ApiFunction, ...]:
        """Every function an event program may call, in the order the class defines them."""
        return tuple(_describe(name, member) for name, member in vars(cls).items() if name in _API_MARKS)

    # ----- argument checks ------------------------------------------------------------------
    def _object(self, name: Any, func: str) -> SceneObject:
        if not isinstance(name, str):
            raise ToolArgumentError(
                f"{func}() expects an object name string like 'chair_1', got {show(name)}"
            )
        obj = self.scene.by_name.get(name)
        if obj is not None:
            return obj
        if name in self.world.names:
            raise UnknownObjectError(f"{func}(): '{name}' is a character, not an object")
        hint = did_you_mean(name, self.scene.object_names)
        raise UnknownObjectError(
            f"unknown object '{name}';{hint}"
            if hint
            else f"unknown object '{name}' (not in this scene)"
        )

    def _label(self, label: Any, func: str) -> str | None:
        if label is None:
            return None
        if not isinstance(label, str):
            raise ToolArgumentError(
                f"{func}() expects label to be a string like 'chair' or None, got {show(label)}"
            )
        if label not in self.scene.labels:
            hint = did_you_mean(label, self.scene.labels)
            raise UnknownObjectError(
                f"unknown label '{label}';{hint}"
                if hint
                else f"unknown label '{label}'; labels: {', '.join(self.scene.labels)}"
            )
        return label

    def _filter(self, names: list[str], label: str | None) -> list[str]:
        return [n for n in names if label is None or self.scene.by_name[n].label == label]

    def _character_name(self, name: Any, func: str) -> str:
        if not isinstance(name, str) or not name:
            raise ToolArgumentError(f"{func}() expects a character name string, got {show(name)}")
        if name in self.world.names:
            return name
        if self.allow_new_characters:
            if len(name) > MAX_NAME_CHARS or not name.isprintable():
                raise ToolArgumentError(
                    f"{func}() expects a short one-line character name "
                    f"(at most {MAX_NAME_CHARS} characters), got {show(name, 40)}"
                )
            new = {n for n in self._handles if n not in self.world.names}
            if name not in new and len(new) >= MAX_NEW_CHARACTERS:
                raise ToolArgumentError(
                    f"{func}('{name}'): a program may use at most {MAX_NEW_CHARACTERS} "
                    "characters; reuse the handles you already have"
                )
            return name
        if name in self.scene.by_name:
            raise UnknownCharacterError(f"'{name}' is an object, not a character")
        hint = did_you_mean(name, self.world.names)
        known = ", ".join(self.world.names)
        raise UnknownCharacterError(
            f"unknown character '{name}';{hint}"
            if hint
            else f"unknown character '{name}'; characters: {known}"
        )

    def _point(self, value: Any, func: str) -> Point:
        if (
            not isinstance(value, list | tuple)
            or len(value) != 2
            or not all(_is_number(v) for v in value)
        ):
            raise ToolArgumentError(
                f"{func}() expects an Area or [x, y] in metres, got {show(value)}"
            )
        try:
            x, y = float(value[0]), float(value[1])
        except OverflowError:
            raise ToolArgumentError(f"{func}() got a number too large for a position") from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ToolArgumentError(f"{func}() got a non-finite position [{x}, {y}]")
        (x0, y0), (x1, y1) = self.scene.bounds_min, self.scene.bounds_max
        if not (x0 <= x <= x1 and y0 <= y <= y1):
            raise ToolArgumentError(
                f"{func}(): [{x:.2f}, {y:.2f}] is outside the scene ({x0:.1f}..{x1:.1f}, {y0:.1f}..{y1:.1f})"
            )
        return (x, y)

    def _area(self, value: Any, func: str) -> Area:
        if not isinstance(value, Area):
            raise ToolArgumentError(
                f"{func}() expects Area values from get_area_* functions, got {show(value)}"
            )
        return value

    def _position_target(self, value: Any, name: str) -> Area | Point:
        if not isinstance(value, Area):
            return self._free_point(self._point(value, "set_position"), name)
        # fail at the program line that asked for an impossible area (others' plans aside)
        moving = {*self._records, name}
        taken = frozenset(o for o, who in self.world.objects_in_use.items() if who not in moving)
        constraints = Constraints(avoid=self.world.points_to_avoid(moving), taken_objects=taken)
        sample_position(value, self._floor, constraints, np.random.default_rng(0))
        return value

    def _free_point(self, point: Point, name: str) -> Point:
        """``point`` if a standing character fits there (free floor), else BlockedPositionError."""
        if bool(self._floor.free(np.array([point]))[0]):
            return point
        where = f"position [{point[0]:.2f}, {point[1]:.2f}] for {name}"
        xy = np.array([point])
        hits = sorted(
            (float(point_footprint_distance(o, xy)[0]), o.name) for o in self._floor.obstacles
        )
        r = self._floor.body_radius
        inside = [n for d, n in hits if d <= 0.0]
        near = [n for d, n in hits if 0.0 < d < r]
        if inside:
            problem = f"is inside {' and '.join(inside[:3])}"
        elif near:
            problem = (
                f"is within {r:.2f} m of {' and '.join(near[:3])} "
                f"(a standing character needs {r:.2f} m of free floor around it)"
            )
        else:
            problem = f"is within {r:.2f} m of the edge of the scene"
        hint = (
            f"; use an area such as get_area_close_to('{(inside or near)[0]}')"
            if (inside or near)
            else ""
        )
        raise BlockedPositionError(f"{where} {problem}{hint}")

    def _orientation_target(self, value: Any) -> str | Area | Point:
        if isinstance(value, Area):
            return value
        if isinstance(value, str):
            if value in self.scene.by_name or value in self.world.names or value in self._records:
                return value
            hint = did_you_mean(value, [*self.scene.object_names, *self.world.names])
            raise UnknownObjectError(
                f"unknown object or character '{value}';{hint}"
                if hint
                else f"unknown object or character '{value}'"
            )
        if isinstance(value, CharacterHandle):
            return value.name
        return self._point(value, "set_orientation")

    def _action(self, label: Any) -> str:
        if not isinstance(label, str) or not label:
            raise ToolArgumentError(
                f"set_target_action() expects an action label string, got {show(label)}"
            )
        if self.action_labels is None and (len(label) > MAX_NAME_CHARS or not label.isprintable()):
            raise ToolArgumentError(
                f"set_target_action() expects a short one-line action label "
                f"(at most {MAX_NAME_CHARS} characters), got {show(label, 40)}"
            )
        if self.action_labels is not None and label not in self.action_labels:
            hint = did_you_mean(label, self.action_labels)
            raise UnknownActionError(
                f"unknown action '{label}';{hint}"
                if hint
                else f"unknown action '{label}'; available: {', '.join(self.action_labels)}"
            )
        return label

    def _record(self, name: str) -> _Record:
        return self._records.setdefault(name, _Record())

    # ----- characters -----------------------------------------------------------------------
    @api_function("character", listed=True)
    def get_character(self, name: str) -> CharacterHandle:
        """The handle of the character called ``name`` (the same handle on every call)."""
        name = self._character_name(name, "get_character")
        if name not in self._handles:
            self._handles[name] = CharacterHandle(self, name)
        return self._handles[name]

    # ----- object queries -------------------------------------------------------------------
    @api_function("query")
    def get_object_supporting(self, anchor: str) -> str | None:
        """The object that ``anchor`` stands on or in; None if it stands on the floor."""
        return self.graph.supporter(self._object(anchor, "get_object_supporting").name)

    @api_function("query")
    def get_objects_supported_by(self, anchor: str, label: str | None = None) -> list[str]:
        """Objects standing on or in ``anchor`` (optionally only those with ``label``)."""
        obj = self._object(anchor, "get_objects_supported_by")
        return self._filter(
            self.graph.supported_by(obj.name), self._label(label, "get_objects_supported_by")
        )

    def _related(self, anchor: str, label: str | None, relation: str, func: str) -> list[str]:
        obj = self._object(anchor, func)
        return self._filter(self.graph.subjects(relation, obj.name), self._label(label, func))

    @api_function("query")
    def get_objects_in_front_of(self, anchor: str, label: str | None = None) -> list[str]:
        """Objects in front of ``anchor`` (its own front), on the same support level, within 2 m."""
        return self._related(anchor, label, "in front of", "get_objects_in_front_of")

    @api_function("query")
    def get_objects_behind(self, anchor: str, label: str | None = None) -> list[str]:
        """Objects behind ``anchor`` (opposite its front), on the same support level, within 2 m."""
        return self._related(anchor, label, "behind", "get_objects_behind")

    @api_function("query")
    def get_objects_left_of(self, anchor: str, label: str | None = None) -> list[str]:
        """Objects to the left of ``anchor`` (its own left), on the same support level, within 2 m."""
        return self._related(anchor, label, "to the left of", "get_objects_left_of")

    @api_function("query")
    def get_objects_right_of(self, anchor: str, label: str | None = None) -> list[str]:
        """Objects to the right of ``anchor`` (its own right), on the same support level, within 2 m."""
        return self._related(anchor, label, "to the right of", "get_objects_right_of")

    def _by_distance(self, obj: SceneObject, limit: float, label: str | None) -> list[str]:
        pairs = [(box_distance(obj, o), o.name) for o in self.scene.objects if o.name != obj.name]
        return self._filter([n for d, n in sorted(pairs) if d < limit], label)

    @api_function("query", listed=True)
    def get_objects_close_to(self, anchor: str, label: str | None = None) -> list[str]:
        """Objects whose box is less than 1.0 m from ``anchor``'s box, nearest first."""
        obj = self._object(anchor, "get_objects_close_to")
        return self._by_distance(obj, CLOSE_DISTANCE, self._label(label, "get_objects_close_to"))

    @api_function("query")
    def get_objects_associated_with(self, anchor: str, label: str | None = None) -> list[str]:
        """Objects used together with ``anchor``: what it stands on, what stands on it, and objects
        whose box is less than 0.3 m away (e.g. the chairs of a table), nearest first."""
        obj = self._object(anchor, "get_objects_associated_with")
        label = self._label(label, "get_objects_associated_with")
        names = self._by_distance(obj, ASSOCIATED_DISTANCE, None)
        support = [self.graph.supporter(obj.name), *self.graph.supported_by(obj.name)]
        names += [n for n in support if n is not None and n not in names]
        return self._filter(names, label)

    @api_function("query")
    def get_objects_between(
        self, anchor_1: str, anchor_2: str, label: str | None = None
    ) -> list[str]:
        """Objects whose centre lies between the two anchors' centres, <= 0.5 m off the line."""
        a = self._object(anchor_1, "get_objects_between")
        b = self._object(anchor_2, "get_objects_between")
        label = self._label(label, "get_objects_between")
        if a.name == b.name:
            raise ToolArgumentError("get_objects_between() needs two different objects")
        area = areas.between(a, b)
        others = [o for o in self.scene.objects if o.name not in (a.name, b.name)]
        if not others:
            return []
        inside = area.contains(np.array([o.center[:2] for o in others]))
        return self._filter([o.name for o, ok in zip(others, inside, strict=True) if ok], label)

    @api_function("query", listed=True)
    def get_closest_object(self, anchor: str, label: str | None = None) -> str:
        """The object whose box is nearest to ``anchor``'s box (optionally with ``label``)."""
        obj = self._object(anchor, "get_closest_object")
        label = self._label(label, "get_closest_object")
        names = self._by_distance(obj, math.inf, label)
        if not names:
            raise ToolArgumentError(f"get_closest_object(): no other object with label '{label}'")
        return names[0]

    @api_function("query")
    def get_distance_between(self, object_1: str, object_2: str) -> float:
        """Distance between the two objects' boxes in metres (0 when they touch)."""
        a = self._object(object_1, "get_distance_between")
        b = self._object(object_2, "get_distance_between")
        return round(box_distance(a, b), 3)

    @api_function("query", listed=True)
    def is_object_occupied(self, object: str) -> bool:
        """Whether a character sits on or uses ``object`` (including earlier lines of this program)."""
        obj = self._object(object, "is_object_occupied")
        if (
            obj.name in self.world.objects_in_use
            and self.world.objects_in_use[obj.name] not in self._records
        ):
            return True
        if obj.name in users_of_objects(self.world.characters, self.scene, skip=self._records):
            return True  # a coffee maker, a whiteboard... used by a character this program does not move
        for record in self._records.values():
            if (
                isinstance(record.position, Area)
                and record.position.seats
                and obj.name in record.position.anchors
            ):
                return True
        return False

    @api_function("query")
    def is_object_of_label(self, object: str, label: str) -> bool:
        """Whether ``object`` has the label ``label`` (e.g. is_object_of_label('chair_3', 'chair'))."""
        obj = self._object(object, "is_object_of_label")
        if not isinstance(label, str):
            raise ToolArgumentError(
                f"is_object_of_label() expects a label string, got {show(label)}"
            )
        return obj.label == label

    # ----- areas ----------------------------------------------------------------------------
    @api_function("area", listed=True)
    def get_area_to_interact_with(self, object: str) -> Area:
        """Where to use ``object``: a seat's seat; else <= 0.6 m from it (further if it stands deep
        on furniture: reached from the furniture's edge), on its front side if it has one."""
        obj = self._object(object, "get_area_to_interact_with")
        supporter = self.graph.supporter(obj.name)
        return areas.to_interact_with(obj, self.scene.by_name[supporter] if supporter else None)

    @api_function("seat_area", listed=True)
    def get_area_to_sit_on(self, object: str) -> Area:
        """The seat of a chair, stool, couch or sofa (a couch has one place per 0.6 m of width)."""
        obj = self._object(object, "get_area_to_sit_on")
        if not obj.is_seat:
            seats = [o.name for o in self.scene.objects if o.is_seat]
            raise ToolArgumentError(
                f"{obj.name} is not a seat; seats: {', '.join(seats) or 'none'}"
            )
        return areas.to_sit_on(obj)

    @api_function("area", listed=True)
    def get_area_adjacent_to(self, object: str) -> Area:
        """Floor within 0.5 m of ``object``'s footprint."""
        return areas.adjacent_to(self._object(object, "get_area_adjacent_to"))

    @api_function("area", listed=True)
    def get_area_close_to(self, object: str) -> Area:
        """Floor within 1.0 m of ``object``'s footprint."""
        return areas.close_to(self._object(object, "get_area_close_to"))

    def _directional(self, name: Any, relation: str, func: str) -> Area:
        obj = self._object(name, func)
        if not obj.has_facing:
            raise ToolArgumentError(
                f"{obj.name} has no front, so '{relation}' is undefined; use get_area_adjacent_to or get_area_close_to"
            )
        return areas.directional(obj, relation)

    @api_function("area", listed=True)
    def get_area_in_front_of(self, object: str) -> Area:
        """Floor in front of ``object``: up to 1.5 m out from its front face, as wide as that face."""
        return self._directional(object, "in front of", "get_area_in_front_of")

    @api_function("area", listed=True)
    def get_area_behind(self, object: str) -> Area:
        """Floor behind ``object``: up to 1.5 m out from its back face, as wide as that face."""
        return self._directional(object, "behind", "get_area_behind")

    @api_function("area", listed=True)
    def get_area_left_of(self, object: str) -> Area:
        """Floor on ``object``'s own left: up to 1.5 m out from its left side, as long as that side."""
        return self._directional(object, "to the left of", "get_area_left_of")

    @api_function("area", listed=True)
    def get_area_right_of(self, object: str) -> Area:
        """Floor on ``object``'s own right: up to 1.5 m out from its right side, as long as that side."""
        return self._directional(object, "to the right of", "get_area_right_of")

    def _pair(self, object_1: Any, object_2: Any, func: str) -> tuple[SceneObject, SceneObject]:
        a, b = self._object(object_1, func), self._object(object_2, func)
        if float(np.linalg.norm(a.center_xy - b.center_xy)) < 1e-6:
            raise ToolArgumentError(
                f"{func}() needs two objects at different places, got {a.name} and {b.name}"
            )
        return a, b

    @api_function("area", listed=True)
    def get_area_between(self, object_1: str, object_2: str) -> Area:
        """Floor between the two objects' centres, <= 0.5 m off the line joining them."""
        return areas.between(*self._pair(object_1, object_2, "get_area_between"))

    @api_function("area")
    def get_area_aligned_with(self, object_1: str, object_2: str) -> Area:
        """Floor on the line through both objects' centres (<= 0.5 m off it), from one centre
        distance before the first to one centre distance past the second."""
        return areas.aligned_with(*self._pair(object_1, object_2, "get_area_aligned_with"))

    @api_function("area_operation", listed=True)
    def get_intersected_area(self, area_1: Area, area_2: Area, *more: Area) -> Area:
        """The part common to all given areas."""
        result = self._area(area_1, "get_intersected_area")
        for other in (area_2, *more):
            result = result.intersect(self._area(other, "get_intersected_area"))
        return result

    @api_function("area_operation")
    def get_union_area(self, area_1: Area, area_2: Area, *more: Area) -> Area:
        """Every point of any of the given areas."""
        result = self._area(area_1, "get_union_area")
        for other in (area_2, *more):
            result = result.union(self._area(other, "get_union_area"))
        return result

    # ----- turning the records into plans ---------------------------------------------------
    def resolve(self, seed: int) -> list[CharacterPlan]:
        """Sample a position and facing for every character the program touched, in the order
        they were first touched. Raises ToolError subclasses (never a partial result), among
        them ObjectInUseError when a plan gives a character an object another one is using
        alone (``storyteller.tools.object_use``)."""
        planned = set(self._records)
        floor = self._floor
        # (point, whose) pairs every later placement keeps MIN_SEPARATION from
        occupied: list[tuple[Point, str]] = [
            (p, f"{c.name}'s {what}")
            for c in self.world.characters
            if c.name not in planned
            for p, what in ((c.position, "position"), (c.target_position, "target"))
            if p is not None
        ]
        for name, rec in self._records.items():  # touched, but staying where they are
            state = self.world.character(name)
            if rec.position is None and state is not None and state.position is not None:
                occupied.append((state.position, f"{name}'s position"))
        # explicit [x, y] targets, kept clear of by every area placement
        fixed = {
            name: (rec.position, rec.position_line)
            for name, rec in self._records.items()
            if rec.position is not None and not isinstance(rec.position, Area)
        }
        taken = {o for o, who in self.world.objects_in_use.items() if who not in planned}
        group: list[Point] = []
        group_seats: set[str] = set()
        placed: dict[str, tuple[Placement, str, Area | None]] = {}
        for i, (name, record) in enumerate(self._records.items()):
            rng = np.random.default_rng([seed & 0xFFFFFFFF, i])
            avoid = [p for p, _ in occupied]
            if isinstance(record.position, Area):
                area = record.position
                avoid += [p for n, (p, _) in fixed.items() if n != name and n not in placed]
                try:
                    placement = sample_position(
                        area,
                        floor,
                        Constraints(
                            avoid=tuple(avoid), group=tuple(group), taken_objects=frozenset(taken),
                            taken_by_group=frozenset(group_seats),
                        ),
                        rng,
                    )
                except UnsatisfiableAreaError as err:
                    raise UnsatisfiableAreaError(f"{name}: {err.feedback}") from None
                text = area.description
            elif record.position is not None:
                self._check_separation(name, record, occupied)
                placement, text, area = (
                    Placement(record.position),
                    f"[{record.position[0]:.2f}, {record.position[1]:.2f}]",
                    None,
                )
            else:
                state = self.world.character(name)
                if state is None or state.position is None:
                    raise ToolArgumentError(
                        f"{name} has no position: call set_position(...) with an area"
                    )
                placement, text, area = (
                    Placement(state.position, state.seat, state.facing if state.seat else None),
                    state.area or "current position",
                    None,
                )
            placed[name] = (placement, text, area)
            occupied.append((placement.position, f"{name}'s planned position"))
            group.append(placement.position)
            if placement.seat is not None:
                taken.add(placement.seat)
                group_seats.add(placement.seat)

        plans = []
        for name, record in self._records.items():
            placement, text, area = placed[name]
            action = record.action or self._default_action(name)
            plans.append(
                CharacterPlan(
                    character=name,
                    action=action,
                    position=placement.position,
                    facing=self._facing(name, record, placement, area, placed),
                    area=text,
                    seat=placement.seat,
                )
            )
        conflicts = use_conflicts(plans, self.world.characters, self.scene)
        if conflicts and self.world.busy_objects == "refuse":  # one object, one user: refused before anything is applied
            first = conflicts[0]
            raise ObjectInUseError(f"{first.character}: {first.message}", line=self._records[first.character].position_line)
        waiting = {c.character: c.obj for c in conflicts}
        return [self._waiting(p, waiting[p.character]) if p.character in waiting else p for p in plans]

    def _waiting(self, plan: CharacterPlan, obj: str) -> CharacterPlan:
        """``plan`` turned into waiting for ``obj`` where it was placed: idle, facing the object
        (seated: on its seat, facing as the seat does)."""
        self._default_action(plan.character)  # "idle" must be an offered label
        if plan.seat is not None:
            return plan.model_copy(update={"action": "idle"})
        c = self.scene.by_name[obj].center
        v = np.subtract((c[0], c[1]), plan.position)
        n = float(np.hypot(*v))
        facing = (float(v[0] / n), float(v[1] / n)) if n > 1e-6 else plan.facing
        return plan.model_copy(update={"action": "idle", "facing": facing})

    def _check_separation(
        self, name: str, record: _Record, occupied: list[tuple[Point, str]]
    ) -> None:
        """An explicit [x, y] must keep MIN_SEPARATION from every other character."""
        point = record.position
        assert point is not None and not isinstance(point, Area)
        limit = Constraints().min_separation
        for other, whose in occupied:
            d = math.hypot(point[0] - other[0], point[1] - other[1])
            if d < limit:
                raise BlockedPositionError(
                    f"position [{point[0]:.2f}, {point[1]:.2f}] for {name} is {d:.2f} m from "
                    f"{whose} [{other[0]:.2f}, {other[1]:.2f}]; characters stand at least "
                    f"{limit:.1f} m apart (pick another point or use an area)",
                    line=record.position_line,
                )

    def _default_action(self, name: str) -> str:
        if self.action_labels is None or "idle" in self.action_labels:
            return "idle"
        raise UnknownActionError(
            f"{name} has no action: call set_target_action(...) with one of {', '.join(self.action_labels)}"
        )

    def _facing(
        self,
        name: str,
        record: _Record,
        placement: Placement,
        area: Area | None,
        placed: dict[str, tuple[Placement, str, Area | None]],
    ) -> Point:
        if placement.seat_facing is not None:
            return placement.seat_facing
        here = np.array(placement.position)
        targets: list[Point | None] = [self._orientation_point(record.orientation, name, placed)]
        if area is not None:
            targets.append(area.focus)
        for target in targets:
            if target is not None:
                v = np.subtract(target, here)
                n = float(np.hypot(*v))
                if n > 1e-6:
                    return (float(v[0] / n), float(v[1] / n))
        state: CharacterState | None = self.world.character(name)
        return state.facing if state is not None and state.facing is not None else (0.0, 1.0)

    def _orientation_point(
        self,
        target: str | Area | Point | None,
        name: str,
        placed: dict[str, tuple[Placement, str, Area | None]],
    ) -> Point | None:
        if target is None:
            return None
        if isinstance(target, Area):
            if target.focus is not None:
                return target.focus
            return (
                (target.hint[0] + target.hint[2]) / 2.0,
                (target.hint[1] + target.hint[3]) / 2.0,
            )
        if isinstance(target, str):
            if target in self.scene.by_name:
                c = self.scene.by_name[target].center
                return (c[0], c[1])
            if target in placed and target != name:
                return placed[target][0].position
            state = self.world.character(target)
            return state.position if state is not None else None
        return target

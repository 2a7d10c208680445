"""Commands the story planner sends to the simulation, and what the simulation reports back.

Commands (frozen pydantic models, ``kind`` tags the union):

- ``AssignEvent(event_id, assignments)``: one story event; every ``Assignment`` sends one
  character to ``target_xy`` (metres, the pelvis ground point), facing ``facing_xy`` (a unit xy
  direction) to do ``action`` (an action label of ``storyteller.sim.motion.action_labels``), optionally seated on
  the scene object ``seat`` whose seat is ``seat_height`` metres above the floor. ``partners``
  name the other characters the action is done with (a partner action faces them); ``focus``
  names the scene object a standing action uses (faced from wherever the character ends up,
  and reached: ``storyteller.sim.world.facing``).
- ``ReleaseCharacters(characters)``: stop whatever looping action the characters are doing;
  they stand up / step back and become idle.

Reports (``StepOutput`` per frame): events that completed, events that became *looping*
(every member is either done or acting a looping action, so the narrator may reuse them),
typed failures (``EventFailure``: no path, busy, stuck...), and who is available.

``AssignEvent.from_plans`` converts the planning side's per-character plans (objects with
``character``, ``action``, ``position``, ``facing``, ``seat`` and ``area`` attributes, i.e.
``storyteller.tools.character_states.CharacterPlan``) without importing them: ``sim`` never imports
``tools``; it names each standing plan's object with ``storyteller.sim.world.facing.focus_object``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Annotated, Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from storyteller.sim.motion.action_labels import UnknownActionLabelError, database_key
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.facing import focus_object

Point = tuple[float, float]

FailureReason = Literal["no_path", "busy", "stuck", "unknown_character", "unknown_seat", "unknown_object"]


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


class Assignment(_Frozen):
    """One character's part in an event."""

    character: str = Field(min_length=1, description="Character name.")
    action: str = Field(description="Action label, e.g. 'drink' or 'chat'.")
    target_xy: Point = Field(description="Where the pelvis goes (x, y), metres.")
    facing_xy: Point = Field(description="Unit xy direction to face while acting.")
    seat: str | None = Field(default=None, description="Scene object sat on, or None (standing).")
    seat_height: float | None = Field(
        default=None, ge=0.0, le=1.5, description="Seat height above the floor (m); None: from the scene."
    )
    partners: tuple[str, ...] = Field(default=(), description="Characters the action is done with.")
    focus: str | None = Field(
        default=None, description="Scene object a standing action uses (faced and reached), or None."
    )

    @field_validator("facing_xy")
    @classmethod
    def _unit_facing(cls, value: Point) -> Point:
        norm = math.hypot(*value)
        if norm < 1e-6:
            raise ValueError("facing_xy must be a non-zero xy direction")
        return (value[0] / norm, value[1] / norm)

    @model_validator(mode="after")
    def _known_action(self) -> Assignment:
        try:
            database_key(self.action, seated=self.seat is not None)
        except UnknownActionLabelError as exc:
            raise ValueError(str(exc)) from None
        if self.character in self.partners:
            raise ValueError(f"character {self.character!r} cannot be its own partner")
        return self

    @property
    def facing_angle(self) -> float:
        """World yaw (radians from +x toward +y) of ``facing_xy``."""
        return math.atan2(self.facing_xy[1], self.facing_xy[0])


class PlanLike(Protocol):
    """Who does what where, read of a planner's plan (``tools.character_states.CharacterPlan``;
    read-only, so frozen models fit). ``tools.object_use`` reads no more of it."""

    @property
    def character(self) -> str: ...
    @property
    def action(self) -> str: ...
    @property
    def position(self) -> Point: ...


class _AssignedPlan(PlanLike, Protocol):
    """What :meth:`AssignEvent.from_plans` reads of a plan."""

    @property
    def facing(self) -> Point: ...
    @property
    def seat(self) -> str | None: ...
    @property
    def area(self) -> str: ...


class AssignEvent(_Frozen):
    """A story event: every listed character goes to its target and acts."""

    kind: Literal["assign_event"] = "assign_event"
    event_id: str = Field(min_length=1)
    assignments: tuple[Assignment, ...] = Field(min_length=1)

    @model_validator(mode="after")
    def _unique_characters(self) -> AssignEvent:
        names = [a.character for a in self.assignments]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"characters assigned twice in event {self.event_id!r}: {dup}")
        return self

    @property
    def characters(self) -> tuple[str, ...]:
        return tuple(a.character for a in self.assignments)

    @classmethod
    def from_plans(cls, event_id: str, plans: Sequence[_AssignedPlan], scene: Scene | None = None) -> AssignEvent:
        """An event from planner output (``CharacterPlan``-like objects).

        Every character's partners are the other characters of the event; a seat's height
        is read from ``scene`` (bottom of the object + its vertical sit offset) and a standing
        plan's object from ``storyteller.sim.world.facing.focus_object`` when ``scene`` is given.
        """
        names = [p.character for p in plans]
        out = []
        for p in plans:
            height = focus = None
            if p.seat is not None and scene is not None and p.seat in scene.by_name:
                obj = scene.by_name[p.seat]
                height = obj.z_min - scene.floor_z + obj.sit_offset_vertical
            elif p.seat is None and scene is not None:
                focus = focus_object(scene, p.action, p.position, p.area)
            out.append(
                Assignment(
                    character=p.character,
                    action=p.action,
                    target_xy=(float(p.position[0]), float(p.position[1])),
                    facing_xy=(float(p.facing[0]), float(p.facing[1])),
                    seat=p.seat,
                    seat_height=height,
                    partners=tuple(n for n in names if n != p.character),
                    focus=focus,
                )
            )
        return cls(event_id=event_id, assignments=tuple(out))


class ReleaseCharacters(_Frozen):
    """Stop the characters' looping actions; they become idle (standing up if seated)."""

    kind: Literal["release"] = "release"
    characters: tuple[str, ...] = Field(min_length=1)


Command = Annotated[AssignEvent | ReleaseCharacters, Field(discriminator="kind")]


class EventFailure(_Frozen):
    """An event that cannot go on, and why (one sentence in ``message``)."""

    event_id: str
    character: str
    reason: FailureReason
    message: str


class StepOutput(_Frozen):
    """What one world step reports. ``frame`` is the frame just produced (0-based)."""

    frame: int = Field(ge=0)
    completed_events: tuple[str, ...] = ()
    looping_events: tuple[str, ...] = Field(default=(), description="Events that became looping this frame.")
    started_events: tuple[str, ...] = Field(default=(), description="Events whose members all arrived this frame.")
    failures: tuple[EventFailure, ...] = ()
    available: tuple[str, ...] = Field(default=(), description="Characters the narrator may use now.")

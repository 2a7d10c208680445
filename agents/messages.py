"""Typed messages of the planning agents (what crosses the LLM and graph boundaries).

All are frozen pydantic models with ``extra="forbid"``. ``Field(description=...)`` texts are
what an LLM sees in a JSON schema, so they are written for it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field

from storyteller.tools.character_states import CharacterPlan

__all__ = [
    "CharacterPlan",
    "CharacterSoFar",
    "CharacterStatus",
    "EarlierEvents",
    "Event",
    "EventState",
    "HistoryEntry",
    "NarratorOutput",
    "ParsedEvent",
    "PlannedCharacter",
    "PlanningFailure",
    "SceneDescription",
    "ToolPlan",
]

EventState = Literal["ongoing", "looping", "completed", "failed"]
"""ongoing: its characters are busy; looping: they keep acting but may be given a new event
(interruptible); completed: finished, its characters are free; failed: it could not be planned
or carried out (its characters are free, and the instruction part it was for is still open)."""

MAX_EVENT_CHARACTERS = 6
MAX_ACTIVITY_CHARS = 160
MAX_REASONING_CHARS = 160


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


class Event(_Frozen):
    """One event proposed by the narrator: who takes part and what they do together."""

    characters: tuple[str, ...] = Field(
        default=(),
        max_length=MAX_EVENT_CHARACTERS,
        description="Names of the free characters taking part; empty means wait.",
    )
    activity: str = Field(
        default="",
        max_length=MAX_ACTIVITY_CHARS,
        description="What they do, in one short sentence naming objects, e.g. 'sit on chair_2 and read'.",
    )

    @property
    def is_wait(self) -> bool:
        """An empty event: nothing new happens until some character becomes free."""
        return not self.characters


class NarratorOutput(_Frozen):
    """The narrator's structured reply."""

    reasoning: str = Field(
        default="", max_length=MAX_REASONING_CHARS, description="One short sentence: why this event now."
    )
    event: Event


class HistoryEntry(_Frozen):
    """A past event as the narrator sees it."""

    index: int = Field(ge=0, description="Order of the event in the story, from 0.")
    characters: tuple[str, ...]
    activity: str
    state: EventState
    part: str = Field(
        default="", description="The instruction part the event was planned for (exactly as the narrator was "
        "shown it); empty when it carried out none.",
    )


class CharacterSoFar(_Frozen):
    """One character's part in the events the narrator's history leaves out."""

    name: str
    events: int = Field(ge=1, description="How many of those events name it.")
    last_activity: str = Field(description="The activity of the latest of them.")


class EarlierEvents(_Frozen):
    """The events older than the narrator's history window, summarised: how many, and per
    character (in order of first appearance) how many it took part in and the latest one's
    activity. Deterministic: a function of the events and their order only."""

    count: int = Field(ge=1, description="Events left out.")
    characters: tuple[CharacterSoFar, ...] = ()

    @staticmethod
    def fold(earlier: EarlierEvents | None, events: Iterable[tuple[Sequence[str], str]]) -> EarlierEvents | None:
        """``earlier`` with ``events`` ((characters, activity), oldest first, all newer than
        the ones it holds) left out too; None when there is nothing left out."""
        count = earlier.count if earlier is not None else 0
        seen = {c.name: (c.events, c.last_activity) for c in earlier.characters} if earlier is not None else {}
        for names, activity in events:
            count += 1
            for name in names:
                seen[name] = (seen.get(name, (0, ""))[0] + 1, activity)
        if count == 0:
            return None
        return EarlierEvents(
            count=count,
            characters=tuple(CharacterSoFar(name=n, events=k, last_activity=a) for n, (k, a) in seen.items()),
        )


class CharacterStatus(_Frozen):
    """What the planner knows of one character between events."""

    name: str
    busy: bool = Field(default=False, description="Taking part in an ongoing event.")
    action: str = Field(default="idle", description="Current action label.")
    position: tuple[float, float] | None = Field(default=None, description="[x, y] in metres.")
    facing: tuple[float, float] | None = Field(default=None, description="Unit [dx, dy].")
    event_index: int | None = Field(default=None, description="Event the character is busy with.")
    seat: str | None = Field(default=None, description="Seat object the character sits on.")


class ToolPlan(Protocol):
    """What an event-program runner returns per character: the fields of
    :class:`~tools.character_states.CharacterPlan` that :meth:`PlannedCharacter.from_tool_plan`
    reads (a runner may return its own objects with the same fields)."""

    @property
    def character(self) -> str: ...
    @property
    def action(self) -> str | None: ...
    @property
    def area(self) -> str | None: ...
    @property
    def position(self) -> Sequence[float]: ...
    @property
    def facing(self) -> Sequence[float]: ...
    @property
    def seat(self) -> str | None: ...


class PlannedCharacter(_Frozen):
    """The event parser's result for one character: a copy of the tool's
    :class:`~tools.character_states.CharacterPlan` (kept as our own type so checkpoints and
    story logs do not depend on the tool's model)."""

    character: str
    action: str = Field(description="Action label the character performs on arrival.")
    area: str = Field(default="", description="Readable description of the target area.")
    position: tuple[float, float] = Field(description="Sampled target [x, y] in metres.")
    facing: tuple[float, float] = Field(description="Unit [dx, dy] the character faces there.")
    seat: str | None = Field(default=None, description="Seat object, when sitting.")

    @classmethod
    def from_tool_plan(cls, plan: ToolPlan) -> PlannedCharacter:
        """Copy a ``storyteller.tools.event_program.CharacterPlan`` (or any object with the same fields)."""
        position = tuple(float(v) for v in plan.position)
        facing = tuple(float(v) for v in plan.facing)
        return cls(
            character=str(plan.character),
            action=str(plan.action) if plan.action is not None else "idle",
            area=str(plan.area or ""),
            position=(position[0], position[1]),
            facing=(facing[0], facing[1]),
            seat=plan.seat,
        )


class ParsedEvent(_Frozen):
    """An event with its per-character plans and the program that produced them."""

    index: int = Field(ge=0)
    event: Event
    plans: tuple[PlannedCharacter, ...]
    program: str = Field(default="", description="The parse_event() source that was run.")
    narrator_attempts: int = Field(default=1, ge=0)
    parser_attempts: int = Field(default=1, ge=0)
    part: str = Field(default="", description="The instruction part the event carries out (empty: none).")


class SceneDescription(_Frozen):
    """A scene description as the narrator and parser read it."""

    scene: str
    text: str
    source: Literal["describer", "object_list", "scene_graph"] = "describer"
    repaired: bool = Field(
        default=False,
        description="True when the describer's last answer still missed or repeated objects and "
        "the text was completed deterministically from the clusters.",
    )
    attempts: int = Field(default=0, ge=0)


class PlanningFailure(_Frozen):
    """A step that used up its retries; the story goes on with the next step."""

    index: int
    node: Literal["describer", "narrator", "event_parser", "planner"]
    attempts: int
    feedback: str
    event: Event | None = Field(default=None, description="The narrator's event, when the parser failed on it.")
    part: str = Field(default="", description="The instruction part that event was for (empty: none).")

"""State and run-scoped dependencies of the planning graph.

:class:`PlanningState` is what the checkpointer stores after every node: small and bounded
(the roster, a window of recent events, the current step's pending replies and retry turns).
The full story (every planned event) grows without bound, so it lives outside the state in a
:class:`~storyteller.orchestrator.planning.checkpoints.StoryLog`, reached through :class:`PlanningDeps` (the
graph's runtime context) together with the LLM port, the scene and the world view provider.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field

from storyteller.agents.bystanders import Choice, object_areas, scene_choices
from storyteller.agents.describer import DescriberInput, describer_input_from_scene
from storyteller.agents.event_parser import ProgramRunner
from storyteller.agents.history import HISTORY_WINDOW
from storyteller.agents.llm_port import LLMPort, TraceRecorder
from storyteller.agents.messages import (
    CharacterStatus,
    EarlierEvents,
    Event,
    HistoryEntry,
    ParsedEvent,
    PlanningFailure,
    SceneDescription,
)
from storyteller.agents.object_states import unsettled_labels
from storyteller.agents.prompt_templates import BENCHMARK_TAGS, PromptLibrary
from storyteller.agents.retry_feedback import Turn
from storyteller.orchestrator.llm.trace_writer import TraceSink
from storyteller.orchestrator.planning.checkpoints import StoryLog
from storyteller.sim.scene.model import Scene
from storyteller.tools.character_states import WorldView
from storyteller.tools.scene_graph import SceneGraph


class RetryTurn(BaseModel):
    """A rejected reply and its feedback (the serialisable form of ``agents.retry_feedback.Turn``)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    reply: str
    feedback: str
    error: str = Field(default="", description="The rejection's error type, e.g. UnsatisfiableAreaError.")

    def as_turn(self) -> Turn:
        return Turn(reply=self.reply, feedback=self.feedback)


class PlanningState(BaseModel):
    """Checkpointed state of one planning run (one langgraph thread)."""

    model_config = ConfigDict(extra="forbid")

    instruction: str = ""
    instruction_since: int = Field(
        default=0, ge=0, description="First step planned under the instruction (it can change mid-story): "
        "earlier events never count as its parts done.",
    )
    events_target: int = Field(default=1, ge=0, description="Planning steps to run (K).")
    step: int = Field(default=0, ge=0, description="Steps finished so far (events, waits or failures).")
    description: SceneDescription | None = None
    roster: tuple[CharacterStatus, ...] = ()
    recent: tuple[HistoryEntry, ...] = Field(default=(), description=f"The last {HISTORY_WINDOW} events (``agents.history``).")
    earlier: EarlierEvents | None = Field(
        default=None, description="The events before ``recent``, summarised for the narrator (None: there are none)."
    )
    busy_until: dict[str, int] = Field(
        default_factory=dict, description="Character -> step at which its current event completes."
    )
    # The describer (first step only; each call and each check is its own node):
    describer_reply: str | None = None
    describer_seq: int | None = None
    describer_turns: tuple[RetryTurn, ...] = ()
    # The current step:
    sim_frame: int | None = Field(
        default=None,
        description="Simulation frame of the world snapshot this step plans from; it goes into "
        "every request as trace metadata (not the request hash). None without a simulation "
        "(``storyteller plan``).",
    )
    step_trace_seqs: tuple[int, ...] = Field(
        default=(), description="Trace seqs of this step's narrator and event-parser attempts."
    )
    narrator_reply: str | None = None
    narrator_seq: int | None = Field(default=None, description="Trace seq of ``narrator_reply``.")
    narrator_turns: tuple[RetryTurn, ...] = ()
    event: Event | None = None
    part: str = Field(default="", description="The instruction part ``event`` carries out (empty: none).")
    narrator_attempts: int = 0
    parser_reply: str | None = None
    parser_seq: int | None = Field(default=None, description="Trace seq of ``parser_reply``.")
    parser_turns: tuple[RetryTurn, ...] = ()
    seat: str | None = Field(
        default=None, description="The seat chosen for the step's event before its program "
        "(``orchestrator.planning.seat_node``); None: the event got no seat choice.",
    )
    action: str | None = Field(
        default=None, description="The action chosen for the step's event before its program when its words name "
        "none (``orchestrator.planning.action_node``); None: the label ranker's suggestion stands.",
    )
    parsed: ParsedEvent | None = None
    failure: PlanningFailure | None = None
    llm_calls: int = Field(default=0, description="LLM calls made by this thread (for tests and reports).")

    @property
    def free(self) -> list[str]:
        return [c.name for c in self.roster if not c.busy]


class StepProgress(Protocol):
    """Where a running step reports to a story session (``orchestrator.session.runtime``):
    every LLM call's latency, and the narrator's accepted event (its characters) as soon as it
    is known, so a session can plan the next event for the characters still free."""

    def llm_call(self, node: str, latency_s: float) -> None:
        """An LLM call of the step returned (or failed) after ``latency_s`` seconds."""

    def claim(self, characters: Sequence[str], activity: str, part: str = "") -> None:
        """The step's event is decided: these characters take part (before any program runs),
        for instruction ``part`` (empty: none)."""


class WorldProvider(Protocol):
    """Supplies the spatial API's view of the characters for the event program.

    ``world_view`` returns what ``tools.event_program.run_event_program`` takes as
    ``world``; ``seats_in_use`` names the seats taken (for the parser's prompt).
    """

    def world_view(self, roster: Sequence[CharacterStatus]) -> WorldView: ...

    def seats_in_use(self, roster: Sequence[CharacterStatus]) -> list[str]: ...


@dataclass
class PlanningDeps:
    """Run-scoped dependencies, passed as the graph's context (never module globals)."""

    port: LLMPort
    scene: Scene
    world: WorldProvider
    story: StoryLog
    action_labels: tuple[str, ...]
    prompts: PromptLibrary = field(default_factory=PromptLibrary)
    tags: tuple[str, ...] = BENCHMARK_TAGS
    seed: int = 0
    max_retries: int = 3
    busy_for_events: int = 0
    """Without a simulation: an event stays ongoing for this many further steps (0: completed at once)."""
    describer_model: str = "unknown"
    describer_mode: Literal["objects", "regions"] = "objects"
    """regions: the describer names numbered clusters instead of listing every object (small models)."""
    description_cache: Path | None = None
    scene_graph: SceneGraph | None = None
    """The scene graph handed to event programs (None: the tools build it)."""
    runner: ProgramRunner | None = None
    """Runs event programs (None: ``storyteller.tools.event_program.run_event_program``)."""
    program_grammar: bool = False
    """Decode event programs under storyteller.agents.program_grammar (local llama.cpp models)."""
    trace: TraceSink | None = None
    """Where parsed outputs are recorded (None: the port's ``.trace``, if it has one)."""
    progress: StepProgress | None = None
    """The current step's progress sink (a session sets one per step; None: nobody listens)."""
    _describer_input: DescriberInput | None = field(default=None, init=False, repr=False)
    _everyday: tuple[tuple[Choice, ...], dict[str, int]] | None = field(default=None, init=False, repr=False)

    def trace_sink(self) -> TraceRecorder | None:
        return self.trace if self.trace is not None else self.port.trace

    def labels_now(self, recent: Sequence[HistoryEntry]) -> tuple[str, ...]:
        """The action labels an event may take after ``recent``: without the switch or door
        label that would set a state the story already holds (:mod:`storyteller.agents.object_states`)."""
        return unsettled_labels(self.action_labels, recent, [o.label for o in self.scene.objects])

    def describer_input(self) -> DescriberInput:
        """The describer's input for the scene (built once per run)."""
        if self._describer_input is None:
            self._describer_input = describer_input_from_scene(self.scene, mode=self.describer_mode)
        return self._describer_input

    def everyday(self) -> tuple[tuple[Choice, ...], dict[str, int]]:
        """The scene's everyday activities for bystanders and its object areas (the describer's
        clusters), built once per run (``storyteller.agents.bystanders``)."""
        if self._everyday is None:
            areas = object_areas(self.scene, self.describer_input().clusters)
            self._everyday = (scene_choices(self.scene, self.action_labels, areas, self.prompts), areas)
        return self._everyday

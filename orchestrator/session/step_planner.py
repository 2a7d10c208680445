"""The planning graph driven one step at a time from a running simulation.

``storyteller plan`` runs the graph for K steps on its own; a story session instead asks for
one step whenever characters become available. Each step starts a new run of a langgraph
thread with the simulation's roster and event history as input (the checkpointed state keeps
the scene description and the step counter), so a killed session resumes on the same thread
without repeating finished LLM calls. The request's frame goes into the state
(``sim_frame``), and so does the request's instruction (the latest one, see
``storyteller.orchestrator.session.instruction_queue``) with the first step planned under it, so every LLM request
of the step carries it as trace metadata, and :meth:`GraphStepPlanner.trace_seqs` tells the
session which trace records produced a step.

Overlapping steps: a langgraph thread runs one step at a time, so steps in flight together run
on *lanes*: lane 0 is the run's thread itself (with one step at a time, the only lane: the
same thread, checkpoints and requests as ever), lane ``j`` the thread ``<thread>/lane<j>``,
which starts with lane 0's scene description (a step beside another is only asked once that
one's narrator answered, so the description exists). Every step gets its own world view
(the request's targets and seats) and its own ``deps.progress``; all lanes record into the one
story log. Looking a step up in the story log is a dictionary lookup (its in-memory index), so a
step costs the planner the same at step 500 as at step 10. On resume, a step cut mid-way is found on the lane whose checkpoint holds it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import AsyncIterator
from typing import Any, Literal, Protocol

import anyio
from langchain_core.runnables import RunnableConfig
from langgraph.types import Durability, StateSnapshot

from storyteller.agents.messages import Event, SceneDescription
from storyteller.orchestrator.planning.checkpoints import StoryLog
from storyteller.orchestrator.planning.graph import recursion_limit
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState, StepProgress
from storyteller.orchestrator.session.roster import RosterWorld
from storyteller.orchestrator.session.session_types import Outcome, PlanningRequest


class StepGraph(Protocol):
    """What :class:`GraphStepPlanner` uses of a compiled planning graph
    (:data:`~orchestrator.planning.graph.CompiledPlanningGraph`): a thread's state, and a run
    streamed to its end. Tests and the planner benchmark pass stand-ins that record outcomes."""

    async def aget_state(self, config: RunnableConfig) -> StateSnapshot: ...

    def astream(
        self, start: dict[str, Any] | None, /, *, config: RunnableConfig, context: PlanningDeps,
        durability: Durability, stream_mode: Literal["updates"],
    ) -> AsyncIterator[object]: ...


class GraphStepPlanner:
    """``StepPlanner`` over a compiled planning graph and its story log; ``lanes``: steps it
    may run at once (the session's ``planners``)."""

    def __init__(self, graph: StepGraph, deps: PlanningDeps, thread_id: str, *, lanes: int = 1) -> None:
        if not isinstance(deps.world, RosterWorld):
            raise TypeError("GraphStepPlanner needs deps.world to be a RosterWorld")
        if lanes < 1:
            raise ValueError(f"lanes must be at least 1, got {lanes}")
        self.graph = graph
        self.deps = deps
        self.thread_id = thread_id
        self.lanes = lanes
        self.story: StoryLog = deps.story
        self._busy: set[int] = set()
        self._choosing: anyio.Lock | None = None  # one lane choice at a time (resumed steps come together)

    @property
    def world(self) -> RosterWorld:
        assert isinstance(self.deps.world, RosterWorld)
        return self.deps.world

    def lane_thread(self, lane: int) -> str:
        return self.thread_id if lane == 0 else f"{self.thread_id}/lane{lane}"

    def _config(self, lane: int = 0) -> RunnableConfig:
        return {
            "configurable": {"thread_id": self.lane_thread(lane)},
            "recursion_limit": recursion_limit(1, self.deps.max_retries),
        }

    def trace_seqs(self, index: int) -> tuple[int, ...]:
        """Trace seqs of the narrator and event-parser attempts behind step ``index``."""
        return self.story.trace_seqs(index)

    async def _lane_for(self, index: int) -> tuple[int, StateSnapshot]:
        """The lane to run step ``index`` on and its state: the one holding it cut mid-way, else
        the first free lane."""
        free: list[tuple[int, StateSnapshot]] = []
        for lane in range(self.lanes):
            if lane in self._busy:
                continue
            snapshot = await self.graph.aget_state(self._config(lane))
            if snapshot.next and snapshot.values.get("step") == index:
                return lane, snapshot
            free.append((lane, snapshot))
        if not free:
            raise RuntimeError(f"planning step {index}: all {self.lanes} lanes are busy")
        return free[0]

    async def _description(self) -> SceneDescription | None:
        values = (await self.graph.aget_state(self._config(0))).values
        described = values.get("description") if values else None
        if isinstance(described, dict):
            return SceneDescription.model_validate(described)
        return described if isinstance(described, SceneDescription) else None

    async def plan(self, request: PlanningRequest, progress: StepProgress | None = None) -> Outcome:
        if self.story.recorded(request.index):  # finished before a restart: never call the LLM again
            return self.story.outcome(request.index)
        if self._choosing is None:
            self._choosing = anyio.Lock()
        async with self._choosing:
            lane, snapshot = await self._lane_for(request.index)
            self._busy.add(lane)
        try:
            return await self._run(lane, snapshot, request, progress)
        finally:
            self._busy.discard(lane)

    async def _run(self, lane: int, snapshot: StateSnapshot, request: PlanningRequest, progress: StepProgress | None) -> Outcome:
        world = self.world if self.lanes == 1 else RosterWorld()  # one step at a time: the run's own view
        world.targets = dict(request.targets)
        world.seats = dict(request.objects_in_use)
        deps = dataclasses.replace(self.deps, world=world, progress=progress)
        start: dict[str, Any] | None
        if not snapshot.values:
            start = PlanningState(
                instruction=request.instruction,
                instruction_since=request.instruction_since,
                events_target=request.index + 1,
                step=request.index,
                roster=request.roster,
                recent=request.history,
                earlier=request.earlier,
                sim_frame=request.frame,
                description=await self._description() if lane > 0 else None,
            ).model_dump()
        elif snapshot.next:
            start = None  # a step was cut off mid-way: finish it from its checkpoint
            event = snapshot.values.get("event")
            if isinstance(event, dict):
                event = Event.model_validate(event)
            if progress is not None and isinstance(event, Event) and not event.is_wait:  # as the narrator's check did
                progress.claim(event.characters, event.activity, str(snapshot.values.get("part") or ""))
        else:
            start = {
                "instruction": request.instruction,
                "instruction_since": request.instruction_since,
                "events_target": request.index + 1,
                "roster": [c.model_dump() for c in request.roster],
                "recent": [h.model_dump() for h in request.history],
                "earlier": request.earlier.model_dump() if request.earlier is not None else None,
                "sim_frame": request.frame,
            }
            if snapshot.values.get("step") != request.index:  # a lane that skipped the steps of others
                start["step"] = request.index
        async for _ in self.graph.astream(
            start, config=self._config(lane), context=deps, durability="sync", stream_mode="updates"
        ):
            pass
        if not self.story.recorded(request.index):
            raise RuntimeError(f"planning step {request.index} ended without recording an outcome")
        return self.story.outcome(request.index)

"""The planning graph driven one step at a time from a running simulation.

``storyteller plan`` runs the graph for K steps on its own; a story session instead asks for
one step whenever characters become available. Each step starts a new run of the same
langgraph thread with the simulation's roster and event history as input (the checkpointed
state keeps the scene description and the step counter), so a killed session resumes on the
same thread without repeating finished LLM calls. The request's frame goes into the state
(``sim_frame``), and so does the request's instruction (the latest one, see
``orchestrator.session.runtime``) with the first step planned under it, so every LLM request of the step carries it as trace metadata, and
:meth:`GraphStepPlanner.trace_seqs` tells the session which trace records produced a step.
"""

from __future__ import annotations

from typing import Any

from orchestrator.planning.checkpoints import StoryLog
from orchestrator.planning.graph import recursion_limit
from orchestrator.planning.state import PlanningDeps, PlanningState
from orchestrator.session.roster import RosterWorld
from orchestrator.session.runtime import Outcome, PlanningRequest


class GraphStepPlanner:
    """``StepPlanner`` over a compiled planning graph and its story log."""

    def __init__(self, graph: Any, deps: PlanningDeps, thread_id: str) -> None:
        if not isinstance(deps.world, RosterWorld):
            raise TypeError("GraphStepPlanner needs deps.world to be a RosterWorld")
        self.graph = graph
        self.deps = deps
        self.thread_id = thread_id
        self.story: StoryLog = deps.story

    @property
    def world(self) -> RosterWorld:
        assert isinstance(self.deps.world, RosterWorld)
        return self.deps.world

    def _config(self) -> dict[str, Any]:
        return {
            "configurable": {"thread_id": self.thread_id},
            "recursion_limit": recursion_limit(1, self.deps.max_retries),
        }

    def trace_seqs(self, index: int) -> tuple[int, ...]:
        """Trace seqs of the narrator and event-parser attempts behind step ``index``."""
        return self.story.trace_seqs(index)

    async def plan(self, request: PlanningRequest) -> Outcome:
        config = self._config()
        recorded = dict(self.story.outcomes())
        if request.index in recorded:  # finished before a restart: never call the LLM again
            return recorded[request.index]
        self.world.targets = dict(request.targets)
        self.world.seats = dict(request.objects_in_use)
        snapshot = await self.graph.aget_state(config)
        start: dict[str, Any] | None
        if not snapshot.values:
            start = PlanningState(
                instruction=request.instruction,
                instruction_since=request.instruction_since,
                events_target=request.index + 1,
                step=request.index,
                roster=request.roster,
                recent=request.history,
                sim_frame=request.frame,
            ).model_dump()
        elif snapshot.next:
            start = None  # a step was cut off mid-way: finish it from its checkpoint
        else:
            start = {
                "instruction": request.instruction,
                "instruction_since": request.instruction_since,
                "events_target": request.index + 1,
                "roster": [c.model_dump() for c in request.roster],
                "recent": [h.model_dump() for h in request.history],
                "sim_frame": request.frame,
            }
        async for _ in self.graph.astream(
            start, config=config, context=self.deps, durability="sync", stream_mode="updates"
        ):
            pass
        outcomes = dict(self.story.outcomes())
        if request.index not in outcomes:
            raise RuntimeError(f"planning step {request.index} ended without recording an outcome")
        return outcomes[request.index]

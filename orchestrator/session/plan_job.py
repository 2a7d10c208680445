"""The ``plan`` job: K planning steps of one graph thread, without a simulation.

Without a simulation nothing "finishes" by itself, so the story advances by steps: each
planned event moves its characters to their sampled positions and keeps them busy for
``busy_events`` further steps (0: the event counts as completed as soon as it is planned).
Characters start idle at free floor points sampled with the seed
(:func:`~storyteller.orchestrator.session.roster.initial_roster`), unless the caller hands over a roster,
a story so far, a world view and a description (the planning benchmark does, per test case).

:func:`run_plan` is the one way the planning graph is driven for K steps:
``storyteller plan`` and ``python -m storyteller.benchmark.planning_benchmark`` both call it, so the
benchmark measures the graph the product runs, request for request. The thread is
checkpointed in SQLite (``runs_db``; ``":memory:"`` for a throwaway run); resuming a thread
never repeats its finished LLM calls.

Event programs run in an OS-limited worker process
(:class:`~storyteller.orchestrator.sandbox_worker.WorkerRunner`) started for the run and stopped when it
ends, unless the caller hands over a ``runner`` (it then owns it) or asks for
``in_process_programs`` (``storyteller.tools.event_program.run_event_program`` in this process). Both give
the same plans for the same program, seed and world.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from langchain_core.runnables import RunnableConfig

from storyteller.agents.event_parser import ProgramRunner, scene_action_labels
from storyteller.agents.llm_port import LLMPort
from storyteller.agents.messages import (
    CharacterStatus,
    HistoryEntry,
    ParsedEvent,
    PlanningFailure,
    SceneDescription,
)
from storyteller.agents.prompt_templates import BENCHMARK_TAGS, PromptLibrary
from storyteller.orchestrator.planning.ablation_graph import Ablation, compile_graph
from storyteller.orchestrator.planning.checkpoints import StoryLog, open_checkpointer
from storyteller.orchestrator.planning.graph import recursion_limit
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState, WorldProvider
from storyteller.orchestrator.session.port_setup import describer_mode_for
from storyteller.orchestrator.session.roster import RosterWorld, initial_roster
from storyteller.sim.scene.model import Scene
from storyteller.tools.scene_graph import SceneGraph

StepOutcome = ParsedEvent | PlanningFailure | None


@dataclass(frozen=True)
class PlanResult:
    """Every step's outcome, in order, and the scene description the thread planned with."""

    outcomes: list[tuple[int, StepOutcome]]
    description: SceneDescription | None


async def run_plan(
    *,
    scene: Scene,
    port: LLMPort,
    instruction: str,
    events: int,
    seed: int,
    runs_db: Path | str,
    thread_id: str,
    characters: int = 2,
    roster: Sequence[CharacterStatus] | None = None,
    history: Sequence[HistoryEntry] = (),
    world: WorldProvider | None = None,
    description: SceneDescription | None = None,
    action_labels: Sequence[str] | None = None,
    scene_graph: SceneGraph | None = None,
    describer_model: str = "unknown",
    description_cache: Path | None = None,
    busy_events: int = 0,
    max_retries: int = 3,
    prompts: PromptLibrary | None = None,
    tags: tuple[str, ...] = BENCHMARK_TAGS,
    on_outcome: Callable[[int, StepOutcome], None] | None = None,
    ablation: Ablation | None = None,
    program_grammar: bool = False,
    runner: ProgramRunner | None = None,
    in_process_programs: bool = False,
) -> PlanResult:
    """Run (or resume) the planning graph for one thread.

    A fresh thread starts from ``roster`` (default: ``characters`` idle characters placed with
    ``seed``), the story ``history`` and ``description`` (None: the graph describes the scene);
    event programs see ``world`` (default: :class:`RosterWorld`) and may use ``action_labels``
    (default: the scene's). ``on_outcome(index, outcome)`` is called for each step as it is
    recorded, in order, including steps recorded before a resume. ``ablation`` picks the
    planner and the scene description (default: the full method with the describer).
    ``runner`` runs the event programs (the caller closes it; None: a worker process for this
    run, or in this process with ``in_process_programs``).
    Raises :class:`~storyteller.orchestrator.session.roster.StartPositionError` when the characters do
    not fit on the floor.
    """
    from storyteller.orchestrator.sandbox_worker import WorkerRunner

    own_runner = WorkerRunner() if runner is None and not in_process_programs else None
    ablation = ablation or Ablation()
    thread_id = ablation.thread_id(thread_id)
    story = StoryLog(runs_db, thread_id)
    deps = PlanningDeps(
        port=port,
        scene=scene,
        world=world or RosterWorld(),
        story=story,
        action_labels=tuple(action_labels) if action_labels is not None else scene_action_labels(scene),
        prompts=prompts or PromptLibrary(),
        tags=tags,
        seed=seed,
        max_retries=max_retries,
        busy_for_events=busy_events,
        describer_model=describer_model,
        describer_mode=describer_mode_for(describer_model),
        description_cache=description_cache,
        scene_graph=scene_graph,
        program_grammar=program_grammar,
        runner=runner if runner is not None else own_runner,
    )
    config: RunnableConfig = {"configurable": {"thread_id": thread_id}, "recursion_limit": recursion_limit(events, max_retries)}
    try:
        described = await _run_thread(
            runs_db, ablation, config, deps, _outcome_feed(story, on_outcome),
            fresh=lambda: _fresh_state(scene, instruction, events, roster, characters, seed, history, description),
        )
        return PlanResult(outcomes=story.outcomes(), description=described)
    finally:
        story.close()
        if own_runner is not None:
            own_runner.close()


def _fresh_state(
    scene: Scene, instruction: str, events: int, roster: Sequence[CharacterStatus] | None, characters: int,
    seed: int, history: Sequence[HistoryEntry], description: SceneDescription | None,
) -> dict[str, Any]:
    """The first state of a new thread (``roster`` None: ``characters`` idle characters placed
    with ``seed``; raises :class:`~storyteller.orchestrator.session.roster.StartPositionError` when they do
    not fit on the floor)."""
    return PlanningState(
        instruction=instruction,
        events_target=events,
        roster=tuple(roster) if roster is not None else initial_roster(scene, characters, seed),
        recent=tuple(history),
        description=description,
    ).model_dump()


def _outcome_feed(story: StoryLog, on_outcome: Callable[[int, StepOutcome], None] | None) -> Callable[[], None]:
    """A function that hands ``on_outcome`` the outcomes ``story`` recorded since its last call, in order."""
    printed = 0

    def flush() -> None:
        nonlocal printed
        outcomes = story.outcomes()
        for idx, outcome in outcomes[printed:]:
            if on_outcome is not None:
                on_outcome(idx, outcome)
        printed = len(outcomes)

    return flush


async def _run_thread(
    runs_db: Path | str, ablation: Ablation, config: RunnableConfig, deps: PlanningDeps, flush: Callable[[], None],
    *, fresh: Callable[[], dict[str, Any]],
) -> SceneDescription | None:
    """Run the thread of ``config`` to its end, checkpointed in ``runs_db``: resumed where it
    stopped, or started from ``fresh()``; ``flush()`` after every node and once at the end.
    Returns the scene description the thread planned with."""
    async with open_checkpointer(runs_db) as saver:
        graph = compile_graph(ablation, saver)
        snapshot = await graph.aget_state(config)
        start = None if snapshot.values else fresh()  # None: resume the interrupted thread
        async for _ in graph.astream(start, config=config, context=deps, durability="sync", stream_mode="updates"):
            flush()
        final = await graph.aget_state(config)
    flush()
    described = final.values.get("description")
    if isinstance(described, dict):
        described = SceneDescription.model_validate(described)
    return described

"""Run one ``parse_event()`` program against the spatial API and return the characters' plans.

The program runs in ``storyteller.tools.sandbox`` (never Python's ``exec``); the spatial API only records
what the program asks for, and the records become ``CharacterPlan``s after the program has
finished without error. A failure raises a ``storyteller.tools.errors.EventProgramError`` subclass and
leaves nothing behind.

The program's time budget (``Budget.wall_time``) covers the placement too: the run and the
sampling of positions together must finish within it on the injected clock, or the result
is refused with ``BudgetExceededError``. Sampling is pure Python that cannot be interrupted
in-process; the worker process (``storyteller.orchestrator.sandbox_worker``) adds the hard wall-clock kill.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from storyteller.sim.scene.model import Scene
from storyteller.tools.character_states import CharacterPlan, WorldView
from storyteller.tools.errors import EventProgramError
from storyteller.tools.sandbox import Budget, BudgetExceededError
from storyteller.tools.sandbox.runner import DEFAULT_CLOCK
from storyteller.tools.scene_graph import SceneGraph
from storyteller.tools.spatial_api import SpatialAPI

__all__ = ["CharacterPlan", "run_event_program"]


def run_event_program(
    scene: Scene,
    source: str,
    world: WorldView,
    *,
    seed: int,
    action_labels: Sequence[str] | None = None,
    graph: SceneGraph | None = None,
    budget: Budget | None = None,
    clock: Callable[[], float] = DEFAULT_CLOCK,
) -> list[CharacterPlan]:
    """Run ``source`` (defining ``parse_event()``) and sample every touched character's plan.

    ``seed`` makes the sampled positions reproducible; ``action_labels`` (None: any label)
    restricts ``set_target_action``; ``graph`` saves rebuilding the scene graph; ``budget``
    and ``clock`` bound the run and the placement together.
    """
    from storyteller.tools.sandbox import execute  # the sandbox is the only way programs run

    budget = budget or Budget()
    api = SpatialAPI(scene, graph, world, action_labels)  # set-up (scene graph, floor map): not the program's time
    start = clock()
    execute(source, api.namespace(), entry="parse_event", budget=budget, clock=clock)
    plans = api.resolve(seed)
    if clock() - start > budget.wall_time:
        raise BudgetExceededError(
            f"the program and the placement of its characters took longer than "
            f"{budget.wall_time:g} s; ask for fewer or simpler placements"
        )
    if not plans:
        raise EventProgramError(
            "parse_event() did not position any character: call get_character(name).set_position(...)"
        )
    return plans

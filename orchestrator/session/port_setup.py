"""Opening and closing the LLM port of a job from its run config.

:func:`open_port` builds the port a ``plan`` / ``run`` job or the planning benchmark talks to
(the embedded model by default; ``record`` writes a trace, ``replay`` serves one) and names
the describer's model, which picks the describer's mode (:func:`describer_mode_for`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from storyteller.agents.llm_port import LLMPort, NodeName


def describer_mode_for(model: str) -> Literal["objects", "regions"]:
    """Small embedded models name numbered regions; API models list every object."""
    return "regions" if model.startswith("local/") else "objects"


PLANNER_NODES: dict[str, frozenset[NodeName]] = {
    "event": frozenset({"narrator", "event_parser"}),
    "direct": frozenset({"narrator", "event_parser"}),
    "unified": frozenset({"planner"}),
}
"""The nodes that place characters under each ``--planner`` (the describer is shared)."""


class ReplayPlannerError(ValueError):
    """A replayed trace was recorded with another planner: none of this planner's nodes is in it."""


def open_port(
    config_path: Path | None, record: Path | None, replay: Path | None, *, unanswered: Literal["miss", "wait"] = "miss",
    planner: str = "event",
) -> tuple[LLMPort, str]:
    """The LLM port from the run config (embedded model by default) and the describer's model
    (``unanswered``: see :class:`storyteller.orchestrator.llm.replay.ReplayClient`; ``"wait"`` for a story session).

    A ``replay`` trace that holds requests, none of them of a node ``planner`` asks, is a
    :class:`ReplayPlannerError` before anything runs (the run would stop at its first miss)."""
    from storyteller.orchestrator.llm.config import load_config
    from storyteller.orchestrator.llm.replay import ReplayClient, build_llm_port

    config = load_config(config_path)
    port = build_llm_port(config, record=record, replay=replay, unanswered=unanswered)
    if isinstance(port, ReplayClient):
        recorded = port.recorded_nodes()
        wanted = PLANNER_NODES.get(planner, frozenset())
        placing = recorded - {"describer"}
        if placing and wanted and placing.isdisjoint(wanted):
            port.close()
            raise ReplayPlannerError(
                f"--replay {replay}: recorded with another planner (nodes {', '.join(sorted(recorded))}); "
                f"--planner {planner} asks {', '.join(sorted(wanted))}")
    return port, config.node("describer").model

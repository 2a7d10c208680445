"""Opening and closing the LLM port of a job from its run config.

:func:`open_port` builds the port a ``plan`` / ``run`` job or the planning benchmark talks to
(the embedded model by default; ``record`` writes a trace, ``replay`` serves one) and names
the describer's model, which picks the describer's mode (:func:`describer_mode_for`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from agents.llm_port import LLMPort


def describer_mode_for(model: str) -> Literal["objects", "regions"]:
    """Small embedded models name numbered regions; API models list every object."""
    return "regions" if model.startswith("local/") else "objects"


def open_port(
    config_path: Path | None, record: Path | None, replay: Path | None, *, unanswered: Literal["miss", "wait"] = "miss"
) -> tuple[LLMPort, str]:
    """The LLM port from the run config (embedded model by default) and the describer's model
    (``unanswered``: see :class:`orchestrator.llm.replay.ReplayClient`; ``"wait"`` for a story session)."""
    from orchestrator.llm.config import load_config
    from orchestrator.llm.replay import build_llm_port

    config = load_config(config_path)
    return build_llm_port(config, record=record, replay=replay, unanswered=unanswered), config.node("describer").model

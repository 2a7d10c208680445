"""The closed sets a user picks a planning method from (``--planner``, ``--description``).

Kept apart from the graph modules so the command line can name them without importing
langgraph.
"""

from __future__ import annotations

from typing import Literal

PlannerKind = Literal["event", "unified", "direct"]
"""``event``: narrator + event parser (the paper's method); ``unified``: one call, "w/o Event";
``direct``: coordinates instead of areas, "Direct Inference"."""

DescriptionKind = Literal["describer", "object-list", "scene-graph"]
"""Where the scene description comes from: the describer, or (ablations) a plain object list
or the raw scene graph."""

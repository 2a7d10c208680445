"""How simulated time relates to the wall clock while planning runs (``--pace``).

Kept apart from the runtime so the command line can name it without importing the simulation.
"""

from __future__ import annotations

from typing import Literal

Pace = Literal["lockstep", "realtime", "fast", "offline"]
"""``lockstep``: the simulation waits for the planner (results land at the frame they were
asked for); ``realtime``: the simulation runs at wall-clock speed (times ``--speed``) while the
planner thinks; ``fast``: the simulation runs as fast as it can; ``offline``: simulated time
advances during each LLM call by the call's latency (as measured, as recorded in a replayed
trace, or ``--offline-latency S``), so a result lands at its request frame plus its calls'
latency whatever the machine's speed."""

MIN_SPEED = 0.05
"""Slowest realtime pace, simulated seconds per wall second (``--speed``, ``run.json``, a viewer's control)."""
MAX_SPEED = 16.0
"""Fastest realtime pace a viewer's control may set (beyond it ``--pace fast`` is the same story)."""
MAX_RUN_SPEED = 1000.0
"""Fastest realtime pace of a run's own ``--speed`` (and of ``run.json``, which resume and replay follow)."""

"""How simulated time relates to the wall clock while planning runs (``--pace``).

Kept apart from the runtime so the command line can name it without importing the simulation.
"""

from __future__ import annotations

from typing import Literal

Pace = Literal["lockstep", "realtime", "fast"]
"""``lockstep``: the simulation waits for the planner (results land at the frame they were
asked for); ``realtime``: the simulation runs at wall-clock speed (times ``--speed``) while the
planner thinks; ``fast``: the simulation runs as fast as it can."""

"""Where two partners stand for an action they do together: at a distance that fits it.

The planner samples each member's point on its own (areas, a 0.5 m keep-out between members),
so two people who chat may be sent 0.5 m or 2.5 m apart, and two who shake hands further apart
than two arms reach. ``spaced`` moves the two points of a standing pair doing the same partner
action along the line between them, about their midpoint, to the action's distance
(``PARTNER_DISTANCE_M``: exactly for a handshake or a hug, whose hands or bodies must meet;
into a conversational range for the others), when both new points have room for a body and
are walked onto from a free cell of the grid; otherwise the points stay as planned. The facing
is the world's business (``storyteller.sim.world.facing``: partners turn to each other before they act).

Pure geometry on the navigation grid; deterministic.
"""

from __future__ import annotations

import numpy as np

from storyteller.sim.motion.action_labels import action_spec
from storyteller.sim.paths.nav_grid import NavGrid
from storyteller.sim.world.events import AssignEvent, Assignment

PARTNER_DISTANCE_M: dict[str, tuple[float, float]] = {
    "handshake": (0.65, 0.65),  # right hands meet with the elbows a little bent (arm 0.51 m)
    "hug": (0.5, 0.5),  # as close as two bodies may stand (two body radii)
}
"""(least, most) metres between two partners' pelvises for an action; others ``TALK_DISTANCE_M``."""
TALK_DISTANCE_M = (0.9, 1.5)
"""A conversation's range (personal distance, Hall's 0.45-1.2 m, to the near social distance)."""


def partner_distance(action: str) -> tuple[float, float]:
    """(least, most) metres between two partners doing ``action``."""
    return PARTNER_DISTANCE_M.get(action, TALK_DISTANCE_M)


def spaced(grid: NavGrid, cmd: AssignEvent) -> AssignEvent:
    """``cmd`` with the points of a standing pair doing the same partner action moved to the
    action's distance (see the module docstring); ``cmd`` itself when nothing moves."""
    if len(cmd.assignments) != 2:
        return cmd
    a, b = cmd.assignments
    if not _pair(a, b):
        return cmd
    pa, pb = np.asarray(a.target_xy, dtype=float), np.asarray(b.target_xy, dtype=float)
    gap = float(np.linalg.norm(pb - pa))
    lo, hi = partner_distance(a.action)
    want = min(max(gap, lo), hi)
    if gap < 1e-6 or abs(want - gap) < 1e-6:
        return cmd
    mid, u = (pa + pb) / 2.0, (pb - pa) / gap
    na, nb = mid - u * want / 2.0, mid + u * want / 2.0
    for old, new in ((pa, na), (pb, nb)):
        if not grid.is_free_xy(new):
            return cmd
        cell = grid.entry_cell(new)
        if cell is None or grid.component[cell] != grid.component[grid.nearest_free_cell(old)]:
            return cmd
    moved = (a.model_copy(update={"target_xy": (float(na[0]), float(na[1]))}),
             b.model_copy(update={"target_xy": (float(nb[0]), float(nb[1]))}))
    return cmd.model_copy(update={"assignments": moved})


def _pair(a: Assignment, b: Assignment) -> bool:
    """Two standing members doing the same partner action with each other."""
    if a.seat is not None or b.seat is not None or a.action != b.action:
        return False
    if action_spec(a.action).family != "partner":
        return False
    return b.character in a.partners and a.character in b.partners

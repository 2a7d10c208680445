"""What to do when windowed cooperative A* finds nothing: change who plans first.

Two levels, both deterministic:

- within one planning call, ``failed_first``: agents whose search failed plan again first
  (with a doubled window), the others adapt around them (``PathPlanner.plan``);
- across calls, ``PriorityKeeper``: an agent that failed or made no progress towards its goal
  for ``stall_steps`` steps gets a priority boost that lasts until it arrives, so that the
  others make way for it instead of the order flipping back and forth (the corridor swap:
  two agents facing each other in a corridor with a side pocket). A search that failed but was
  planned again by a repair pass (the agent moves on) boosts once; a search that left the agent
  waiting, and stalling, raise the boost each time; among equal boosts the latest given plans
  first. Agents standing on their goal plan last, so they step aside for passers-by and come
  back. (When a repaired failure raised the boost every time, two agents passing each other
  with room to spare cornered each other in turn: the one cornered went first at the next
  replan, which cornered the other, and each step undid the last. In 20 s of the 50-walker
  Office crowd a pair stepped back and forth between two rows, side by side 0.6 m apart, for
  good.)

An agent whose search still fails waits where it stands, which the planner keeps safe for the
committed steps; no fallback ever moves an agent along an unchecked path.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable, Mapping, Sequence

import numpy as np

Agent = Hashable


def failed_first(order: Sequence[Agent], failed: Iterable[Agent]) -> list[Agent]:
    """``order`` with the ``failed`` agents moved to the front (relative order kept)."""
    bad = set(failed)
    return [a for a in order if a in bad] + [a for a in order if a not in bad]


class PriorityKeeper:
    """Planning order across replans: boosted (stalled) agents, then walkers, then arrivals.

    ``rank``: a fixed seeded permutation, so the base order does not change between calls.
    ``stall_steps``: steps without getting closer to the goal before the boost grows.
    """

    def __init__(self, seed: int = 0, stall_steps: int = 6) -> None:
        self.seed = int(seed)
        self.stall_steps = int(stall_steps)
        self.stall_factor = 4
        self._rank: dict[Agent, float] = {}
        self._best: dict[Agent, float] = {}
        self._since: dict[Agent, int] = {}
        self.boost: dict[Agent, int] = {}
        self._boosted_at: dict[Agent, int] = {}  # the ``observe`` call that last raised the boost
        self._calls = 0

    def _rank_of(self, agent: Agent) -> float:
        if agent not in self._rank:
            rng = np.random.default_rng([self.seed, len(self._rank)])
            self._rank[agent] = float(rng.random())
        return self._rank[agent]

    def reset(self, agent: Agent) -> None:
        """Forget the agent's progress (new goal or arrival)."""
        self._best.pop(agent, None)
        self._since.pop(agent, None)
        self.boost.pop(agent, None)
        self._boosted_at.pop(agent, None)

    def observe(self, distances: Mapping[Agent, float], failed: Iterable[Agent], steps: int = 1,
                repaired: Iterable[Agent] = ()) -> None:
        """Record remaining distances (metres, inf allowed) after ``steps`` executed steps.
        ``failed``: agents the last planning call left waiting (boosted each time);
        ``repaired``: agents whose search failed and a repair pass planned (boosted once)."""
        bad = set(failed) | (set(repaired) - set(self.boost))
        self._calls += 1
        for a, d in distances.items():
            best = self._best.get(a)
            if best is None or d < best - 1e-9:
                self._best[a] = d
                self._since[a] = 0
            else:
                self._since[a] = self._since.get(a, 0) + steps
            if a in bad or self._since[a] >= self.stall_steps * self.stall_factor:
                self.boost[a] = self.boost.get(a, 0) + 1
                self._boosted_at[a] = self._calls
                self._since[a] = 0

    def stalled_steps(self, agent: Agent) -> int:
        """Steps since the agent last got closer to its goal (0 before any observation; back to
        0 whenever its boost grows)."""
        return self._since.get(agent, 0)

    def order(self, walking: Iterable[Agent], arrived: Iterable[Agent]) -> list[Agent]:
        """Who plans first: higher boost, then the boost raised last, then lower rank; agents on
        their goal last."""
        walking = list(walking)
        arrived = list(arrived)
        key = lambda a: (-self.boost.get(a, 0), -self._boosted_at.get(a, 0), self._rank_of(a))  # noqa: E731
        for a in walking + arrived:  # assign ranks in a fixed order
            self._rank_of(a)
        return sorted(walking, key=key) + sorted(arrived, key=lambda a: self._rank_of(a))

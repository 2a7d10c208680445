"""The characters of a new story and the spatial API's view of a planner roster.

:func:`initial_roster` names the characters (:data:`NAMES`, then ``Extra<i>``) and places
them idle on free floor points at least :data:`START_SEPARATION` apart, deterministically for
a seed. :class:`RosterWorld` is the one conversion from a roster
(:class:`~storyteller.agents.messages.CharacterStatus`) to the world view event programs run against:
``storyteller plan`` uses it as it is, a simulation session fills in where busy characters
are heading and which seats are taken (:attr:`RosterWorld.targets`, :attr:`RosterWorld.seats`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from storyteller.agents.messages import CharacterStatus
from storyteller.sim.scene.model import Scene
from storyteller.tools.character_states import CharacterState, WorldView
from storyteller.tools.position_sampling import FloorMap

NAMES = ("Ava", "Ben", "Cleo", "Dan", "Eve", "Finn", "Gia", "Hugo", "Iris", "Jon", "Kai", "Lena")
START_SEPARATION = 1.0
"""Metres between two start positions at least."""


class StartPositionError(ValueError):
    """The scene's free floor cannot hold the requested characters."""


def character_names(count: int) -> list[str]:
    if count <= len(NAMES):
        return list(NAMES[:count])
    return [*NAMES, *(f"Extra{i}" for i in range(count - len(NAMES)))]


def start_positions(scene: Scene, count: int, seed: int) -> list[tuple[float, float]]:
    """``count`` free floor points, >= START_SEPARATION apart, deterministic for ``seed``."""
    rng = np.random.default_rng(seed)
    floor = FloorMap(scene)
    lo, hi = np.array(scene.bounds_min), np.array(scene.bounds_max)
    chosen: list[np.ndarray] = []
    for _ in range(200):
        pts = rng.uniform(lo, hi, size=(256, 2))
        for p in pts[floor.free(pts)]:
            if all(np.linalg.norm(p - q) >= START_SEPARATION for q in chosen):
                chosen.append(p)
                if len(chosen) == count:
                    return [(round(float(x), 3), round(float(y), 3)) for x, y in chosen]
    raise StartPositionError(f"cannot place {count} characters on the free floor of scene '{scene.name}'")


def initial_roster(scene: Scene, count: int, seed: int) -> tuple[CharacterStatus, ...]:
    """``count`` idle characters at :func:`start_positions`, facing +y."""
    return tuple(
        CharacterStatus(name=n, position=p, facing=(0.0, 1.0))
        for n, p in zip(character_names(count), start_positions(scene, count, seed), strict=True)
    )


class RosterWorld:
    """World view for event programs: the roster, plus where busy characters are heading and
    which seats are taken or about to be (both empty without a simulation)."""

    def __init__(self) -> None:
        self.targets: dict[str, tuple[float, float]] = {}
        self.seats: dict[str, str] = {}

    def world_view(self, roster: Sequence[CharacterStatus]) -> WorldView:
        chars = tuple(
            CharacterState(
                name=c.name,
                position=c.position,
                facing=c.facing,
                action=c.action,
                busy=c.busy,
                seat=c.seat,
                target_position=self.targets.get(c.name),
            )
            for c in roster
        )
        in_use = {c.seat: c.name for c in roster if c.seat}
        in_use.update(self.seats)
        return WorldView(characters=chars, objects_in_use=in_use)

    def seats_in_use(self, roster: Sequence[CharacterStatus]) -> list[str]:
        return sorted({*(c.seat for c in roster if c.seat), *self.seats})

"""What a recipe of :mod:`.generate` proposes: a :class:`Draft` (one question about one scene,
before names, distractors and a sentence shape are chosen) and its :class:`Occupant` s.

Plain frozen data: the queries a draft carries are :mod:`.derivation` queries, which may name
the k-th occupant as ``$k`` (filled in when the case is written, :mod:`.case_writer`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

Query = dict[str, Any]
"""A :mod:`.derivation` query (JSON data)."""


@dataclass(frozen=True)
class Occupant:
    """A level-0 character already in the scene (named when the case is written)."""

    action: str
    position: str
    activity: str
    ongoing: bool = True


@dataclass(frozen=True)
class Draft:
    """One question about one scene, before names, distractors and a shape are chosen."""

    group: str
    scene: str
    recipe: str
    key: str
    slots: dict[str, list[str]]
    """Slot -> candidate words (one is drawn per case)."""
    action: str | None
    field: str = "relationships"
    relations: tuple[str, ...] = ("sit on",)
    objects: Query | None = None
    count: str = "any"
    wait_for: Query | None = None
    occupants: tuple[Occupant, ...] = ()
    avoid: frozenset[str] = frozenset()
    """Objects no distractor may use or stand at."""
    noun: str | None = None
    """The label whose nouns fill ``{noun}`` in the activity phrases."""

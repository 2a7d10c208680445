"""Runs of words shared by two texts: the overlap rule between our case pool and the authors'
cases (no run of :data:`WINDOW` words on both sides)."""

from __future__ import annotations

import re

WINDOW = 6  # the longest run of words shared with an authors' case must stay below this


def words(text: str) -> list[str]:
    return re.findall(r"[a-z0-9_']+", text.lower())


def windows(text: str) -> set[tuple[str, ...]]:
    """Every run of :data:`WINDOW` consecutive words of ``text``."""
    found = words(text)
    return {tuple(found[i : i + WINDOW]) for i in range(len(found) - WINDOW + 1)}

"""The world's one error type, in a module of its own so every part of the step can raise it."""

from __future__ import annotations


class WorldError(ValueError):
    """Bad world input (setup or step arguments); one sentence naming what is wrong."""

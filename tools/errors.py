"""Typed errors of event programs: every message is written to be fed back to an LLM.

``EventProgramError`` is the base. The sandbox raises its own subclasses (syntax, forbidden
construct, budget exceeded, runtime error); the spatial API raises ``ToolError`` subclasses
(unknown object, unknown character, unsatisfiable area, bad argument). ``feedback`` is the
one-paragraph text to show the model; ``kind`` is a stable short tag for traces and metrics.
"""

from __future__ import annotations

import difflib
import itertools
from collections.abc import Iterable
from contextvars import ContextVar

PROGRAM_LINE: ContextVar[int | None] = ContextVar("program_line", default=None)
"""The program line of the tool call in progress (the sandbox sets it around every call), so a
tool that records a request can name that line when the request fails later."""


class EventProgramError(Exception):
    """Base class: an event program failed. ``str(err) == err.feedback``."""

    kind: str = "event_program_error"
    steps: int | None = None
    """Interpreter steps the sandbox had counted when the program failed (None: the failure
    came before the program ran, e.g. a syntax error, or outside the sandbox)."""

    def __init__(self, feedback: str, *, line: int | None = None):
        feedback = _clip(feedback)
        self.feedback = feedback if line is None else f"line {line}: {feedback}"
        self.line = line
        super().__init__(self.feedback)


class ToolError(EventProgramError):
    """A spatial-API call was given something it cannot use."""

    kind = "tool_error"


class UnknownObjectError(ToolError):
    kind = "unknown_object"


class UnknownCharacterError(ToolError):
    kind = "unknown_character"


class UnknownActionError(ToolError):
    kind = "unknown_action"


class UnsatisfiableAreaError(ToolError):
    kind = "unsatisfiable_area"


class ToolArgumentError(ToolError):
    kind = "bad_argument"


class ObjectInUseError(ToolError):
    """A character was given an object another one is using alone (``tools.object_use``)."""

    kind = "object_in_use"


class BlockedPositionError(ToolArgumentError):
    """An explicit [x, y] no character can stand on: inside or against furniture, at the edge
    of the scene, or too close to another character. The spatial API raises it, and so does
    the Direct Inference ablation for an answered coordinate (``agents.ablations.direct``)."""

    kind = "blocked_position"


MAX_FEEDBACK = 500
"""Characters of one error message (a program can pass megabytes to a tool's argument)."""


def _clip(text: str) -> str:
    text = str(text)
    if len(text) <= MAX_FEEDBACK:
        return text
    return text[: MAX_FEEDBACK - 20] + f"... ({len(text)} characters)"


SUGGESTION_CANDIDATES = 200
"""Candidates a "did you mean" search compares at most (the first ones it is given)."""
SUGGESTION_CHARS = 40
"""Longest word or candidate a "did you mean" search compares (longer ones are skipped)."""


def did_you_mean(
    word: str, candidates: Iterable[str], *, n: int = 3, limit: int = SUGGESTION_CANDIDATES
) -> str:
    """A suffix like " did you mean 'chair_1'?" (empty when nothing is close).

    Bounded whatever the input: only the first ``limit`` candidates are read, and a word or
    candidate longer than ``SUGGESTION_CHARS`` is not compared (difflib is quadratic in
    length), so one search costs at most ``limit * SUGGESTION_CHARS**2`` character steps.
    """
    if len(word) > SUGGESTION_CHARS:
        return ""
    pool = [c for c in itertools.islice(candidates, limit) if len(c) <= SUGGESTION_CHARS]
    close = difflib.get_close_matches(word, pool, n=n, cutoff=0.6)
    if not close:
        return ""
    return " did you mean " + " or ".join(f"'{c}'" for c in close) + "?"

"""Every way an event program can fail inside the sandbox, in one place.

These are ``storyteller.tools.errors.EventProgramError`` subclasses, so a caller catches sandbox and
spatial-API failures alike with one ``except EventProgramError``. The base class and the
spatial API's ``ToolError`` family stay in ``storyteller.tools.errors``: the spatial API raises them
without knowing about the sandbox, and the sandbox lets programs catch them. Each
``feedback`` is one sentence fit to show the LLM, prefixed with the program line.
"""

from __future__ import annotations

from typing import TypeAlias

from storyteller.tools.errors import EventProgramError
from storyteller.tools.value_text import show

Line: TypeAlias = int | None
"""A program line (1-based); None when the failure has no line (e.g. the text is too long)."""


class ProgramSyntaxError(EventProgramError):
    """The program text is not valid Python (or not text)."""

    kind = "syntax_error"


class ForbiddenConstructError(EventProgramError):
    """The program uses something event programs may not use (imports, classes, `_` names...)."""

    kind = "forbidden_construct"


class BudgetExceededError(EventProgramError):
    """The program ran too long or built something too large."""

    kind = "budget_exceeded"


class ProgramRuntimeError(EventProgramError):
    """The program failed while running (bad operands, index out of range, a tool misused...)."""

    kind = "runtime_error"


class UnknownNameError(ProgramRuntimeError):
    """The program uses a name that is defined nowhere."""

    kind = "unknown_name"


class MissingEntryError(EventProgramError):
    """The program does not define the entry function (``parse_event``)."""

    kind = "missing_entry"


def add_line(err: EventProgramError, line: Line) -> None:
    """Name the program line in an error raised without one (e.g. by a tool)."""
    if err.line is None and line is not None:
        err.line = line
        err.feedback = f"line {line}: {err.feedback}"
        err.args = (err.feedback,)


def describe(err: BaseException) -> str:
    """``"Type: message"`` of an unexpected Python exception, its values shown bounded.

    A ``KeyError``'s text is ``repr(key)`` rendered on demand; it goes through the bounded
    renderer instead (other CPython messages the sandbox could reach are intercepted before
    the call that would build them, e.g. ``list.index``).
    """
    if isinstance(err, KeyError) and len(err.args) == 1:
        return f"KeyError: {show(err.args[0])}"
    return f"{type(err).__name__}: {err}"

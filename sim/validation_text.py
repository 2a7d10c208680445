"""A pydantic ``ValidationError`` said as one sentence for a user: the file, the field, what was wrong.

Every layer reads files through pydantic models (scenes and motion configs in ``sim``, LLM
configs, traces, run folders and checkpoints in ``orchestrator``, cases and scenarios in
``benchmark``); each turns a model's first error into its own typed exception through this
module, so the messages read alike::

    home.json: field 'objects.2.size': required field is missing
    run.json: unknown key                       (the document itself is at fault)

:func:`user_error` is the sentence; :func:`problem_field` and :func:`problem_message` are its
two parts, for errors that keep them apart (``SceneFileError``, ``ConfigError``...).

The result is plain text and may quote a file's own keys (an unknown key is named as the file
spells it), so it is data: whoever shows it escapes it (the CLI's ``error:`` line goes through
``storyteller.orchestrator.safe_text.one_line``, the viewer's panel through ``safe_text.markdown``). Lives
in ``sim`` (no I/O, no environment) so every layer above may import it.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import ValidationError
from pydantic_core import ErrorDetails

_MESSAGES = {
    "extra_forbidden": "unknown key",
    "missing": "required field is missing",
}
"""pydantic's wording replaced by a user's (``Extra inputs are not permitted``, ``Field required``)."""


def problem_field(detail: ErrorDetails, prefix: str = "") -> str:
    """The dotted path of the field at fault (``objects.2.size``), after ``prefix`` (the path of
    the validated part inside its file); empty when the whole document is at fault."""
    return ".".join(p for p in (prefix, ".".join(str(part) for part in detail["loc"])) if p)


def problem_message(detail: ErrorDetails) -> str:
    """What was wrong, in a user's words: ``unknown key``, ``required field is missing``, or
    pydantic's message without its ``Value error, `` prefix."""
    return _MESSAGES.get(detail["type"], detail["msg"]).removeprefix("Value error, ")


def user_error(path: Path | str, error: ValidationError, *, prefix: str = "") -> str:
    """``<path>: field '<field>': <message>`` for the first error of ``error`` (``<path>:
    <message>`` when the document itself is at fault). ``path`` names the file (and, where it
    helps, the line); ``prefix`` is the path of the validated part inside the file."""
    detail = error.errors()[0]
    field = problem_field(detail, prefix)
    message = problem_message(detail)
    return f"{path}: field '{field}': {message}" if field else f"{path}: {message}"

"""One way to turn a failed answer into feedback text for the next attempt.

Narrator, event parser, describer and the ablation planners all call
:func:`feedback_from_error`, so every retry prompt reads alike: what was wrong, then what to
do ("Fix this and answer again ..."). Modelled on pydantic-ai's ``RetryPromptPart.from_error``.
The sentences are prompt files under ``prompts/feedback/``, rendered strictly.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

from pydantic import ValidationError

from storyteller.agents.llm_port import ChatMessage, LLMPort, LLMRequest
from storyteller.agents.prompt_templates import PromptLibrary, package_prompts
from storyteller.tools.errors import EventProgramError

T = TypeVar("T")

MAX_FEEDBACK_CHARS = 600
ANSWER_AGAIN = "feedback/answer_again.md"
"""The instruction after a rejected answer; an event parser's is ``feedback/code_again.md``."""
FEEDBACK_FILES = (
    "feedback/invalid_json.md",
    "feedback/schema_mismatch.md",
    "feedback/answer_rejected.md",
    "feedback/program_failed.md",
    "feedback/other_error.md",
    ANSWER_AGAIN,
)


class AnswerRejectedError(Exception):
    """An LLM answer that parsed but broke a rule (busy character, missing object...).

    ``problems`` are short sentences, each naming the offending value.
    """

    kind = "answer_rejected"

    def __init__(self, problems: list[str]) -> None:
        self.problems = list(problems)
        super().__init__("; ".join(self.problems))


class NoCodeError(Exception):
    """A reply without a usable ``parse_event()`` function."""

    kind = "no_code"


REJECTIONS: tuple[type[Exception], ...] = (
    json.JSONDecodeError,
    ValidationError,
    AnswerRejectedError,
    NoCodeError,
    EventProgramError,
)
"""Errors that mean "the answer was bad" (fed back to the model), as opposed to our own bugs."""


def error_kind(error: BaseException) -> str:
    """A short stable tag for traces and metrics."""
    if isinstance(error, json.JSONDecodeError):
        return "invalid_json"
    if isinstance(error, ValidationError):
        return "schema_mismatch"
    return str(getattr(error, "kind", type(error).__name__))


def _validation_lines(lib: PromptLibrary, error: ValidationError) -> list[str]:
    lines = []
    for item in error.errors()[:5]:
        loc = ".".join(str(p) for p in item["loc"]) or lib.render_text("feedback/schema_root.md")
        lines.append(lib.render_text("feedback/schema_field.md", location=loc, message=item["msg"]))
    return lines


def feedback_from_error(
    error: BaseException, *, instruction: str = ANSWER_AGAIN, prompts: PromptLibrary | None = None
) -> str:
    """Feedback text for the model after ``error``, then the ``instruction`` prompt file's text;
    the part about the error is bounded to MAX_FEEDBACK_CHARS. ``prompts``: where the files are
    read (default: the ``prompts`` package)."""
    lib = prompts or package_prompts()
    if isinstance(error, json.JSONDecodeError):
        body = lib.render_text("feedback/invalid_json.md", message=error.msg, position=error.pos)
    elif isinstance(error, ValidationError):
        body = lib.render_text("feedback/schema_mismatch.md", problems="; ".join(_validation_lines(lib, error)))
    elif isinstance(error, AnswerRejectedError):
        body = lib.render_text("feedback/answer_rejected.md", problems="; ".join(error.problems))
    elif isinstance(error, NoCodeError):
        body = str(error)
    elif isinstance(error, EventProgramError):
        body = lib.render_text("feedback/program_failed.md", feedback=error.feedback)
    else:
        body = lib.render_text("feedback/other_error.md", error_type=type(error).__name__, error=error)
    if len(body) > MAX_FEEDBACK_CHARS:
        body = body[: MAX_FEEDBACK_CHARS - 3] + "..."
    return f"{body} {lib.render_text(instruction)}".strip()


@dataclass(frozen=True)
class Turn:
    """One rejected attempt: the model's reply and the feedback it got."""

    reply: str
    feedback: str


RETRY_TEMPERATURE = 0.7
"""Sampling temperature of retries: at temperature 0 a model given feedback often repeats
its rejected answer word for word. Retries keep the request's seed, so runs stay reproducible."""


def retry_temperature(turns: tuple[Turn, ...]) -> float | None:
    """None (the node's configured temperature) for a first try, RETRY_TEMPERATURE after."""
    return RETRY_TEMPERATURE if turns else None


def with_turns(messages: tuple[ChatMessage, ...], turns: tuple[Turn, ...]) -> tuple[ChatMessage, ...]:
    """The base conversation followed by each rejected reply and its feedback.

    The base messages come first unchanged, so a local model's prefix cache is reused.
    """
    out = list(messages)
    for turn in turns:
        out.append(ChatMessage(role="assistant", content=turn.reply))
        out.append(ChatMessage(role="user", content=turn.feedback))
    return tuple(out)


class RetriesExhaustedError(Exception):
    """Every attempt was rejected. ``feedback`` is the last feedback text."""

    kind = "retries_exhausted"

    def __init__(self, node: str, attempts: int, feedback: str) -> None:
        self.node = node
        self.attempts = attempts
        self.feedback = feedback
        super().__init__(f"{node}: no valid answer after {attempts} attempt(s); last problem: {feedback}")


@dataclass(frozen=True)
class Accepted(Generic[T]):
    value: T
    attempts: int
    reply: str


async def ask_until_valid(
    port: LLMPort,
    build_request: Callable[[tuple[Turn, ...]], LLMRequest],
    parse: Callable[[str], T],
    *,
    max_attempts: int,
    node: str,
    instruction: str = ANSWER_AGAIN,
    prompts: PromptLibrary | None = None,
) -> Accepted[T]:
    """Call the model until ``parse`` accepts a reply, at most ``max_attempts`` times.

    ``parse`` raises on a bad reply; the error becomes feedback for the next attempt through
    :func:`feedback_from_error` (``instruction``: the prompt file said after it). LLM port errors (``LLMError``) are not caught.
    """
    if max_attempts < 1:
        raise ValueError("max_attempts must be >= 1")
    turns: tuple[Turn, ...] = ()
    feedback = ""
    for attempt in range(1, max_attempts + 1):
        response = await port.complete(build_request(turns))
        try:
            value = parse(response.text)
        except REJECTIONS as exc:
            feedback = feedback_from_error(exc, instruction=instruction, prompts=prompts)
            turns = (*turns, Turn(reply=response.text, feedback=feedback))
            continue
        return Accepted(value=value, attempts=attempt, reply=response.text)
    raise RetriesExhaustedError(node, max_attempts, feedback)

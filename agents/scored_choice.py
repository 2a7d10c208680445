"""A decision as a choice among candidates, through the LLM port: one request, one typed answer.

:func:`choice_request` builds an :class:`~storyteller.agents.llm_port.LLMRequest` with ``choices`` (the
candidates) and a JSON schema whose ``choice`` is an enum of exactly those candidates. The
embedded model answers it by scored continuations (the log-likelihood of each candidate as the
whole reply, from one evaluation of the prompt: ``storyteller.orchestrator.llm.llama_decoding``); any other
provider by generation constrained to the schema. :func:`choose` sends it and returns a
:class:`ScoredChoice`: the candidate, and the ranking of all of them (by score when the
provider gave scores). A reply naming anything but a candidate raises :class:`ChoiceError`
(no retry with feedback: the schema makes such a reply impossible, so it means a broken
provider, and the caller decides without the model).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from storyteller.agents.llm_port import ChatMessage, LLMPort, LLMRequest, NodeName


class ChoiceError(Exception):
    """The reply to a choice request names no candidate (or is not the schema's JSON)."""


class ChoiceReply(BaseModel):
    """The reply's JSON: the chosen candidate and, from a scoring provider, every candidate's
    log-likelihood."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    choice: str
    scores: dict[str, float] | None = Field(default=None, description="Log-likelihood per candidate.")


class ScoredChoice(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    choice: str
    ranked: tuple[str, ...]
    """Every candidate, best first (by score; the chosen one first and the rest in the given
    order when the provider gave no scores)."""
    scored: bool
    trace_seq: int | None = None


def choice_schema(candidates: Sequence[str]) -> dict[str, Any]:
    """The reply schema of a choice among ``candidates``: ``{"choice": <one of them>}``."""
    return {
        "type": "object",
        "properties": {"choice": {"type": "string", "enum": list(dict.fromkeys(candidates))}},
        "required": ["choice"],
        "additionalProperties": False,
    }


def choice_request(
    node: NodeName, messages: Sequence[ChatMessage], candidates: Sequence[str], *,
    seed: int | None = None, sim_frame: int | None = None,
) -> LLMRequest:
    unique = tuple(dict.fromkeys(candidates))
    if not unique:
        raise ValueError("a choice needs at least one candidate")
    return LLMRequest(
        node=node, messages=tuple(messages), json_schema=choice_schema(unique), choices=unique,
        max_tokens=16 + 8 * max(len(c) for c in unique), temperature=0.0, seed=seed, sim_frame=sim_frame,
    )


def read_choice(text: str, candidates: Sequence[str]) -> ScoredChoice:
    """The :class:`ScoredChoice` in a reply's ``text``; raises :class:`ChoiceError`."""
    try:
        reply = ChoiceReply.model_validate(json.loads(text))
    except (ValueError, ValidationError) as exc:
        raise ChoiceError(f"the reply to a choice is not its JSON ({exc})") from None
    if reply.choice not in candidates:
        raise ChoiceError(f"the reply chose {reply.choice!r}, which is not a candidate")
    order = list(dict.fromkeys(candidates))
    if reply.scores is not None and set(order) <= set(reply.scores):
        scores = reply.scores
        ranked = tuple(sorted(order, key=lambda c: (-scores[c], order.index(c))))
        return ScoredChoice(choice=reply.choice, ranked=ranked, scored=True)
    return ScoredChoice(choice=reply.choice, ranked=(reply.choice, *(c for c in order if c != reply.choice)), scored=False)


async def choose(port: LLMPort, request: LLMRequest) -> ScoredChoice:
    """Send a :func:`choice_request` through ``port`` and read its answer."""
    if request.choices is None:
        raise ValueError("not a choice request (no choices)")
    response = await port.complete(request)
    return read_choice(response.text, request.choices).model_copy(update={"trace_seq": response.trace_seq})

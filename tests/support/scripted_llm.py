"""The one scripted fake of the LLM port (``storyteller.agents.llm_port.LLMPort``) the unit tests share.

:class:`ScriptedLLM` answers from a script and keeps every request it was sent:

- a list of replies: answered in order, whatever the node;
- a dict node -> list of replies (in order) or a function of the request;
- a function of the request (e.g. an oracle that answers by request content).

A script that runs out raises ``IndexError`` (a test asked for more calls than it planned),
an unscripted node raises ``KeyError``: neither is ever turned into a reply.

With ``trace=`` a trace sink (``storyteller.orchestrator.llm.trace_writer.TraceWriter``), every call is written
as one successful ``attempt`` record and its response carries that record's ``trace_seq``, so
the planning graph records what it made of each reply (``parsed`` records with the error type
that rejected it), as with a real client.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from storyteller.agents.llm_port import LLMRequest, LLMResponse

Reply = Callable[[LLMRequest], str]
Script = Sequence[str] | Mapping[str, Sequence[str] | Reply] | Reply


class ScriptedLLM:
    """An LLM port that answers from a script; ``requests`` holds what it was asked, in order."""

    def __init__(self, script: Script, *, model: str = "scripted", trace: Any = None) -> None:
        if callable(script):
            self._reply: Reply | None = script
            self._queue: list[str] = []
            self._nodes: dict[str, list[str] | Reply] = {}
        elif isinstance(script, Mapping):
            self._reply, self._queue = None, []
            self._nodes = {k: (v if callable(v) else list(v)) for k, v in script.items()}
        else:
            self._reply, self._queue, self._nodes = None, list(script), {}
        self.by_node = isinstance(script, Mapping)
        self.model = model
        self.requests: list[LLMRequest] = []
        self.trace = trace  # None: records nothing
        self._writes_attempts = trace is not None
        self.closed = False

    def close(self) -> None:
        self.closed = True

    def answer(self, request: LLMRequest) -> str:
        """The scripted reply to ``request`` (consumes it from a list)."""
        if self._reply is not None:
            return self._reply(request)
        if not self.by_node:
            return self._queue.pop(0)
        source = self._nodes[request.node]
        return source(request) if callable(source) else source.pop(0)

    async def complete(self, request: LLMRequest) -> LLMResponse:
        self.requests.append(request)
        text = self.answer(request)
        if not self._writes_attempts:
            return LLMResponse(text=text, model=self.model)
        from storyteller.orchestrator.llm.traces import AttemptRecord

        seq = self.trace.next_seq()
        self.trace.write(AttemptRecord(
            run_id=self.trace.run_id, seq=seq, time_unix=time.time(), call=seq, node=request.node, attempt=1,
            model=self.model, params={}, request=request, request_hash=request.content_hash(), response_text=text,
            latency_s=0.0, final=True,
        ))
        return LLMResponse(text=text, model=self.model, trace_seq=seq)

    def count(self, node: str) -> int:
        """Requests sent to ``node`` so far."""
        return sum(1 for r in self.requests if r.node == node)


def choosing(replies: Sequence[str], pick: Callable[[tuple[str, ...]], str] = lambda c: c[0]) -> Reply:
    """A node's script that answers a choice request (``storyteller.agents.scored_choice``: a request with
    ``choices``) with ``pick`` of its candidates (the first by default) and every other request
    with the next of ``replies``."""
    queue = list(replies)

    def reply(request: LLMRequest) -> str:
        if request.choices is not None:
            return json.dumps({"choice": pick(request.choices)})
        return queue.pop(0)

    return reply

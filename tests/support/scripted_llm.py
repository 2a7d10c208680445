"""The one scripted fake of the LLM port (``agents.llm_port.LLMPort``) the unit tests share.

:class:`ScriptedLLM` answers from a script and keeps every request it was sent:

- a list of replies: answered in order, whatever the node;
- a dict node -> list of replies (in order) or a function of the request;
- a function of the request (e.g. an oracle that answers by request content).

A script that runs out raises ``IndexError`` (a test asked for more calls than it planned),
an unscripted node raises ``KeyError``: neither is ever turned into a reply.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

from agents.llm_port import LLMRequest, LLMResponse

Reply = Callable[[LLMRequest], str]
Script = Sequence[str] | Mapping[str, Sequence[str] | Reply] | Reply


class ScriptedLLM:
    """An LLM port that answers from a script; ``requests`` holds what it was asked, in order."""

    def __init__(self, script: Script, *, model: str = "scripted") -> None:
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
        self.trace = None  # records nothing
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
        return LLMResponse(text=self.answer(request), model=self.model)

    def count(self, node: str) -> int:
        """Requests sent to ``node`` so far."""
        return sum(1 for r in self.requests if r.node == node)

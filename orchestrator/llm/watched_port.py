"""An LLM port that tells a watcher when each call starts and ends (for a live view).

:class:`WatchedPort` wraps any :class:`storyteller.agents.llm_port.LLMPort`: before a call goes to the
wrapped port the watcher hears ``call_started(node)`` (which returns an id for the call), and
after it, exactly once, ``call_finished(id, usage)``: the answer's token usage, or ``None``
when the call failed (it raised an exception: an ``LLMError``, a bug), or ``call_cancelled(id)``
when it was cancelled (abandoned: the story ended or was stopped while it ran). Requests and answers pass through
unchanged, so a watched run records, replays and plans exactly as an unwatched one; the
port's ``trace`` and ``close`` are the wrapped port's.

The usage is the answer's (the attempt that was returned); tokens of attempts a client
retried internally are in the trace and ``metrics.json`` only.
"""

from __future__ import annotations

from typing import Protocol

from storyteller.agents.llm_port import LLMPort, LLMRequest, LLMResponse, NodeName, TokenUsage, TraceRecorder


class CallWatcher(Protocol):
    """Who hears about the calls of a :class:`WatchedPort` (e.g. ``orchestrator.session.run_status``)."""

    def call_started(self, node: NodeName) -> int:
        """A call of ``node`` starts; returns an id for :meth:`call_finished`."""
        ...

    def call_finished(self, call: int, usage: TokenUsage | None) -> None:
        """Call ``call`` ended: with an answer of ``usage``, or failed (``None``)."""
        ...

    def call_cancelled(self, call: int) -> None:
        """Call ``call`` was cancelled before it ended (nobody waits for its answer)."""
        ...


class WatchedPort:
    """:class:`agents.llm_port.LLMPort` that reports every call of ``port`` to ``watcher``."""

    def __init__(self, port: LLMPort, watcher: CallWatcher) -> None:
        self.port = port
        self.watcher = watcher

    @property
    def trace(self) -> TraceRecorder | None:
        return self.port.trace

    async def complete(self, request: LLMRequest) -> LLMResponse:
        call = self.watcher.call_started(request.node)
        try:
            response = await self.port.complete(request)
        except Exception:
            self.watcher.call_finished(call, None)
            raise
        except BaseException:  # cancelled (or the process is going down)
            self.watcher.call_cancelled(call)
            raise
        self.watcher.call_finished(call, response.usage)
        return response

    def close(self) -> None:
        self.port.close()

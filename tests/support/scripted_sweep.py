"""A scripted LLM port for benchmark sweeps that writes real traces, as the live client does.

:class:`TracedScript` answers each request with ``answer(request)`` and records the call to the
run's trace file as one successful ``attempt`` (fixed token counts from the text lengths and a
fixed 0.25 s latency, so results are reproducible); the planning graph then records through
``trace`` what it made of each reply (``parsed`` records), so ``bench score`` can replay the
trace. :func:`scripted` makes the sweep's port factory.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path

from storyteller.agents.llm_port import LLMRequest, LLMResponse, TokenUsage
from storyteller.benchmark.sweep.execute import PortFactory
from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.llm.traces import AttemptRecord

Answer = Callable[[LLMRequest], str]


class TracedScript:
    """An LLM port that answers with ``answer`` and records each call to ``trace``; ``calls``
    collects the node of every request (shared by the ports of a sweep)."""

    def __init__(self, trace: Path, calls: list[str], answer: Answer) -> None:
        self.trace = TraceWriter(trace, fsync="never")
        self.calls = calls
        self.answer = answer

    async def complete(self, request: LLMRequest) -> LLMResponse:
        self.calls.append(request.node)
        text = self.answer(request)
        seq = self.trace.next_seq()
        usage = TokenUsage(prompt_tokens=sum(len(m.content) for m in request.messages) // 4,
                           completion_tokens=len(text) // 4)
        self.trace.write(AttemptRecord(
            run_id=self.trace.run_id, seq=seq, time_unix=time.time(), call=seq, node=request.node, attempt=1,
            model="openai/scripted", params={}, request=request, request_hash=request.content_hash(),
            response_text=text, usage=usage, latency_s=0.25, final=True,
        ))
        await asyncio.sleep(0)
        return LLMResponse(text=text, model="openai/scripted", usage=usage, latency_s=0.25, attempts=1, trace_seq=seq)

    def close(self) -> None:
        self.trace.close()


def scripted(calls: list[str], answer: Answer) -> PortFactory:
    """A port factory: every run (and description) of the sweep answered by ``answer``."""
    return lambda model, trace: TracedScript(trace, calls, answer)

"""A trace record to write in trace tests: one final narrator attempt."""

from __future__ import annotations

import time

from storyteller.agents.llm_port import ChatMessage, LLMRequest, TokenUsage
from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.llm.traces import AttemptRecord


def attempt(writer: TraceWriter, text: str = '{"a": 1}', frame: int = 10) -> AttemptRecord:
    req = LLMRequest(node="narrator", messages=(ChatMessage(role="user", content="hi ✓"),), sim_frame=frame)
    seq = writer.next_seq()
    rec = AttemptRecord(
        run_id=writer.run_id, seq=seq, time_unix=time.time(), call=seq, node="narrator", attempt=1,
        model="local/qwen2.5-coder-0.5b", params={"temperature": 0.0, "max_tokens": 64}, request=req,
        request_hash=req.content_hash(), response_text=text, finish_reason="stop", parsed_output={"a": 1},
        usage=TokenUsage(prompt_tokens=3, completion_tokens=4), latency_s=0.25, final=True,
    )
    writer.write(rec)
    return rec

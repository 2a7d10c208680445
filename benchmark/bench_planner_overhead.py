"""What a planning step costs the event loop besides its LLM calls, early and late in a long story.

Two costs that ran on the event loop at every step of a story session:

- the planner's bookkeeping (``storyteller.orchestrator.session.step_planner.GraphStepPlanner.plan``): is
  the step already in the story log (a resumed run), and after the graph ran, its outcome. The
  planning graph is replaced by a stand-in that only records a realistic outcome (an event of
  two characters with its ~600-character event program) in the story log, so what is timed is
  the planner itself; the story log is an in-memory SQLite database, so no fsync is timed either;
- the narrator's history the session builds for the request (``history_window`` in
  ``storyteller.orchestrator.session.story_history``: the latest events, the ones before summarised) from the events so far.

For each story length it prints the wall milliseconds of one step at step 10 and at step
``--steps`` (median over ``--repeat`` steps), their ratio (1.0: flat), and, as the baseline
measured in the same run, what reading and parsing the whole story log once costs at the same
length (``StoryLog`` read afresh, as ``plan`` did twice per step before the log kept an index).

Second, the trace: the wall milliseconds a ``TraceWriter.write`` of a narrator-sized attempt
record keeps its caller (the event loop) busy with ``fsync="always"``, against a write followed
by an inline fsync (how every record was written before the writer fsynced in its own thread).
Not a test: timings depend on the machine and its load; compare the columns of one run.

    nice -n 19 python -m storyteller.benchmark.bench_planner_overhead [--steps 500] [--repeat 9]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from storyteller.agents.llm_port import ChatMessage, LLMRequest
from storyteller.agents.messages import Event, ParsedEvent, PlannedCharacter
from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.llm.traces import AttemptRecord
from storyteller.orchestrator.planning.checkpoints import StoryLog
from storyteller.orchestrator.planning.state import PlanningDeps
from storyteller.orchestrator.session.roster import RosterWorld
from storyteller.orchestrator.session.session_types import PlanningRequest, StoryEvent
from storyteller.orchestrator.session.step_planner import GraphStepPlanner
from storyteller.orchestrator.session.story_history import history_window

NAMES = ("Ava", "Ben", "Cleo", "Dan")
PROGRAM = (
    "def parse_event():\n"
    '    a = get_character("Ava")\n    b = get_character("Ben")\n'
    '    spot = get_area_close_to("couch_1")\n'
    "    a.set_position(spot)\n    a.set_target_action(\"sit_on_couch\")\n"
    '    b.set_position(get_area_in_front_of(a))\n    b.set_target_action("talk")\n'
) * 3


def outcome(index: int) -> ParsedEvent:
    who = (NAMES[index % 4], NAMES[(index + 1) % 4])
    return ParsedEvent(
        index=index,
        event=Event(characters=who, activity=f"chat by the couch, round {index}"),
        plans=tuple(
            PlannedCharacter(character=n, action="talk", area="in front of couch_1", position=(1.0 + k, 2.0),
                             facing=(0.0, 1.0))
            for k, n in enumerate(who)
        ),
        program=PROGRAM,
    )


class RecordingGraph:
    """Stand-in for the compiled planning graph: a step records its outcome and ends."""

    def __init__(self, story: StoryLog) -> None:
        self.story = story
        self.step = 0

    async def aget_state(self, config: Any) -> Any:
        return SimpleNamespace(next=(), values={"step": self.step})

    async def astream(self, start: Any, *, config: Any, context: Any, durability: str, stream_mode: str) -> Any:
        index = start["step"] if start is not None and "step" in start else self.step
        self.story.record(index, outcome(index), trace_seqs=(2 * index, 2 * index + 1))
        self.step = index + 1
        if False:  # an async generator that yields nothing
            yield None


def planner_at(story_len: int, repeat: int) -> tuple[float, float, float]:
    """(planner ms per step, history ms per step, whole-log read ms) at ``story_len`` steps."""
    story = StoryLog(":memory:", "bench")
    for i in range(story_len):
        story.record(i, outcome(i), trace_seqs=(2 * i, 2 * i + 1))
    graph = RecordingGraph(story)
    graph.step = story_len
    deps = PlanningDeps(port=None, scene=None, world=RosterWorld(), story=story, action_labels=())  # type: ignore[arg-type]  # the bookkeeping measured never touches port or scene
    planner = GraphStepPlanner(graph, deps, "bench")
    events = {
        f"event-{i:04d}": StoryEvent(index=i, event_id=f"event-{i:04d}", characters=o.event.characters,
                                     activity=o.event.activity, requested_frame=i, applied_frame=i, state="completed")
        for i, o in story.outcomes() if isinstance(o, ParsedEvent)
    }
    plan_ms, history_ms = [], []
    for k in range(repeat):
        index = story_len + k
        request = PlanningRequest(index=index, frame=index, roster=(), history=())
        t0 = time.perf_counter()
        asyncio.run(planner.plan(request))
        plan_ms.append((time.perf_counter() - t0) * 1000)
        t0 = time.perf_counter()
        history_window(events, ())
        history_ms.append((time.perf_counter() - t0) * 1000)
    read_ms = []
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "runs.sqlite"
        copy = StoryLog(db, "bench")
        for i, o in story.outcomes():
            copy.record(i, o)
        copy.close()
        for _ in range(3):
            t0 = time.perf_counter()
            again = StoryLog(db, "bench")
            again.outcomes()
            read_ms.append((time.perf_counter() - t0) * 1000)
            again.close()
    story.close()
    return statistics.median(plan_ms), statistics.median(history_ms), statistics.median(read_ms)


def attempt(writer: TraceWriter, size: int) -> AttemptRecord:
    req = LLMRequest(node="narrator", messages=(ChatMessage(role="user", content="x" * size),))
    seq = writer.next_seq()
    return AttemptRecord(run_id=writer.run_id, seq=seq, time_unix=0.0, call=seq, node="narrator", attempt=1,
                         model="m", params={}, request=req, request_hash=req.content_hash(), response_text="{}",
                         latency_s=0.0, final=True)


def trace_write_ms(repeat: int, size: int = 6000) -> tuple[float, float]:
    """(median ms a write keeps its caller now, median ms of a write plus an inline fsync)."""
    with tempfile.TemporaryDirectory() as tmp:
        writer = TraceWriter(Path(tmp) / "t.jsonl", fsync="always")
        now, inline = [], []
        for _ in range(repeat):
            rec = attempt(writer, size)
            t0 = time.perf_counter()
            writer.write(rec)
            now.append((time.perf_counter() - t0) * 1000)
            writer.sync()  # let the writer's fsync finish: each sample starts from the same state
            rec = attempt(writer, size)
            t0 = time.perf_counter()
            writer.write(rec)
            writer.sync()  # what an inline fsync costs the caller
            inline.append((time.perf_counter() - t0) * 1000)
        writer.close()
    return statistics.median(now), statistics.median(inline)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=500, help="the long story's length (steps)")
    parser.add_argument("--repeat", type=int, default=9, help="steps timed per length (median)")
    args = parser.parse_args()
    rows = {n: planner_at(n, args.repeat) for n in (10, args.steps)}
    print(f"{'step':>6} {'planner ms':>11} {'history ms':>11} {'whole-log read ms':>18}")
    for n, (plan, hist, read) in rows.items():
        print(f"{n:>6} {plan:>11.3f} {hist:>11.3f} {read:>18.2f}")
    (p10, h10, r10), (pn, hn, rn) = rows[10], rows[args.steps]
    print(f"step {args.steps} / step 10: planner x{pn / p10:.2f}, history x{hn / h10:.2f}; "
          f"whole-log read (baseline) x{rn / r10:.1f}")
    now, inline = trace_write_ms(args.repeat)
    print(f"trace write, fsync=always, caller's ms: {now:.3f} now, {inline:.2f} with an inline fsync "
          f"(x{inline / now:.0f}); disk: {os.statvfs(tempfile.gettempdir()).f_bsize} B blocks")


if __name__ == "__main__":
    main()

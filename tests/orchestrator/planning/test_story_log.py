"""The story log's in-memory index: a planning step looks its outcome up without reading the
log, the index survives a reopen (resume), and records from a worker thread are seen at once."""

from __future__ import annotations

import asyncio
import sqlite3
import threading
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from storyteller.agents.messages import Event, ParsedEvent, PlannedCharacter, PlanningFailure
from storyteller.orchestrator.planning.checkpoints import StoryLog
from storyteller.orchestrator.planning.state import PlanningDeps
from storyteller.orchestrator.session.roster import RosterWorld
from storyteller.orchestrator.session.session_types import PlanningRequest
from storyteller.orchestrator.session.step_planner import GraphStepPlanner


def event(index: int) -> ParsedEvent:
    return ParsedEvent(
        index=index,
        event=Event(characters=("Ava",), activity=f"read {index}"),
        plans=(PlannedCharacter(character="Ava", action="read", position=(1.0, 2.0), facing=(0.0, 1.0)),),
        program="def parse_event():\n    pass\n",
    )


def statements(story: StoryLog) -> list[str]:
    """Every SQL statement the log runs from now on (sqlite3's trace callback)."""
    seen: list[str] = []
    conn: sqlite3.Connection = story._conn  # the test watches the connection
    conn.set_trace_callback(seen.append)
    return seen


class RecordingGraph:
    """Stand-in for the planning graph: a step records its outcome and ends."""

    def __init__(self, story: StoryLog) -> None:
        self.story = story
        self.runs = 0

    async def aget_state(self, config: Any) -> Any:
        return SimpleNamespace(next=(), values={})

    async def astream(self, start: Any, **_: Any) -> Any:
        self.runs += 1
        self.story.record(start["step"], event(start["step"]), trace_seqs=(7,))
        if False:
            yield None


def planner_for(story: StoryLog) -> tuple[GraphStepPlanner, RecordingGraph]:
    graph = RecordingGraph(story)
    deps = PlanningDeps(port=None, scene=None, world=RosterWorld(), story=story, action_labels=())  # type: ignore[arg-type]  # record_outcome never touches port or scene
    return GraphStepPlanner(graph, deps, "t"), graph


def test_a_step_reads_nothing_back_from_the_log(tmp_path: Path) -> None:
    story = StoryLog(tmp_path / "runs.sqlite", "t")
    for i in range(40):
        story.record(i, event(i), trace_seqs=(i,))
    planner, graph = planner_for(story)
    seen = statements(story)
    recorded = asyncio.run(planner.plan(PlanningRequest(index=12, frame=0, roster=(), history=())))
    fresh = asyncio.run(planner.plan(PlanningRequest(index=40, frame=0, roster=(), history=())))
    assert recorded == event(12) and graph.runs == 1  # a finished step is not planned again
    assert fresh == event(40) and planner.trace_seqs(40) == (7,) and planner.trace_seqs(3) == (3,)
    assert not [s for s in seen if s.lstrip().upper().startswith("SELECT")], seen  # only the one record's writes
    story.close()


def test_a_reopened_log_knows_every_step(tmp_path: Path) -> None:
    db = tmp_path / "runs.sqlite"
    story = StoryLog(db, "t")
    failure = PlanningFailure(index=1, node="event_parser", attempts=4, feedback="no area", event=Event())
    story.record(0, event(0), trace_seqs=(1, 2))
    story.record(1, failure, trace_seqs=(3,))
    story.record(2, None)
    story.record(0, event(0), trace_seqs=(1, 2))  # a re-run node: harmless
    StoryLog(db, "other").record(5, event(5))  # another thread in the same file
    story.close()
    again = StoryLog(db, "t")
    assert again.outcomes() == [(0, event(0)), (1, failure), (2, None)]
    assert again.recorded(2) and again.outcome(2) is None and not again.recorded(5)
    assert again.trace_seqs(0) == (1, 2) and again.trace_seqs(2) == () and again.trace_seqs(9) == ()
    again.close()


def test_records_from_worker_threads_do_not_interleave(tmp_path: Path) -> None:
    story = StoryLog(tmp_path / "runs.sqlite", "t")

    def record_every_third(k: int) -> None:
        for i in range(k, 60, 3):
            story.record(i, event(i), (i,))

    threads = [threading.Thread(target=record_every_third, args=(k,)) for k in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert [i for i, _ in story.outcomes()] == list(range(60))
    story.close()
    assert [i for i, _ in StoryLog(tmp_path / "runs.sqlite", "t").outcomes()] == list(range(60))

"""Durable storage of planning runs: the langgraph checkpointer and the story log.

Both live in one SQLite file (default ``$STORYTELLER_CACHE_DIR/runs.sqlite``, else
``~/.cache/storyteller/runs.sqlite``):

- langgraph's ``AsyncSqliteSaver`` tables hold one checkpoint per finished node (the graph is
  run with ``durability="sync"``, so a node's result is on disk before the next node starts;
  a killed process resumes at the node that was cut, and no finished LLM call is repeated);
- the ``story_events`` table holds every planned event of a thread, keyed by (thread, index)
  and written with ``INSERT OR REPLACE``, so re-running the node that wrote it is harmless.
  This keeps the growing story out of the checkpointed graph state;
- the ``story_trace_refs`` table holds, per (thread, index), the trace seqs of the LLM
  attempts that produced the step's outcome (written in the same transaction), so the
  simulation can record the frame it applied the outcome at against exactly those records,
  also after a restart.
"""

from __future__ import annotations

import json
import os
import sqlite3
from collections.abc import AsyncIterator, Sequence
from contextlib import asynccontextmanager
from pathlib import Path

from langgraph.checkpoint.serde.jsonplus import JsonPlusSerializer
from langgraph.checkpoint.sqlite.aio import AsyncSqliteSaver

from agents.messages import ParsedEvent, PlanningFailure

_SCHEMA = """
CREATE TABLE IF NOT EXISTS story_events (
    thread_id TEXT NOT NULL,
    idx INTEGER NOT NULL,
    kind TEXT NOT NULL,
    body TEXT NOT NULL,
    PRIMARY KEY (thread_id, idx)
);
CREATE TABLE IF NOT EXISTS story_trace_refs (
    thread_id TEXT NOT NULL,
    idx INTEGER NOT NULL,
    seqs TEXT NOT NULL,
    PRIMARY KEY (thread_id, idx)
)
"""


def default_runs_db() -> Path:
    root = os.environ.get("STORYTELLER_CACHE_DIR")
    base = Path(root) if root else Path.home() / ".cache" / "storyteller"
    return base / "runs.sqlite"


class StoryLog:
    """Append-only (idempotent per index) log of a thread's planning outcomes."""

    def __init__(self, path: Path | str, thread_id: str) -> None:
        self.path = str(path)
        self.thread_id = thread_id
        if self.path != ":memory:":
            Path(self.path).parent.mkdir(parents=True, exist_ok=True)
        self._conn = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
        self._conn.executescript(_SCHEMA)

    def close(self) -> None:
        self._conn.close()

    def record(
        self, index: int, outcome: ParsedEvent | PlanningFailure | None, trace_seqs: Sequence[int] = ()
    ) -> None:
        """Store step ``index``'s outcome (``None``: the narrator chose to wait) and the trace
        seqs of the attempts that produced it, atomically."""
        if outcome is None:
            kind, body = "wait", "{}"
        elif isinstance(outcome, ParsedEvent):
            kind, body = "event", outcome.model_dump_json()
        else:
            kind, body = "failure", outcome.model_dump_json()
        self._conn.execute("BEGIN")
        try:
            self._conn.execute(
                "INSERT OR REPLACE INTO story_events (thread_id, idx, kind, body) VALUES (?, ?, ?, ?)",
                (self.thread_id, index, kind, body),
            )
            self._conn.execute(
                "INSERT OR REPLACE INTO story_trace_refs (thread_id, idx, seqs) VALUES (?, ?, ?)",
                (self.thread_id, index, json.dumps([int(s) for s in trace_seqs])),
            )
        except BaseException:
            self._conn.execute("ROLLBACK")
            raise
        self._conn.execute("COMMIT")

    def trace_seqs(self, index: int) -> tuple[int, ...]:
        """Trace seqs of the attempts behind step ``index`` (empty if unknown)."""
        row = self._conn.execute(
            "SELECT seqs FROM story_trace_refs WHERE thread_id = ? AND idx = ?", (self.thread_id, index)
        ).fetchone()
        return tuple(int(s) for s in json.loads(row[0])) if row else ()

    def outcomes(self) -> list[tuple[int, ParsedEvent | PlanningFailure | None]]:
        rows = self._conn.execute(
            "SELECT idx, kind, body FROM story_events WHERE thread_id = ? ORDER BY idx", (self.thread_id,)
        ).fetchall()
        out: list[tuple[int, ParsedEvent | PlanningFailure | None]] = []
        for idx, kind, body in rows:
            if kind == "event":
                out.append((idx, ParsedEvent.model_validate_json(body)))
            elif kind == "failure":
                out.append((idx, PlanningFailure.model_validate_json(body)))
            else:
                out.append((idx, None))
        return out

    def events(self) -> list[ParsedEvent]:
        return [o for _, o in self.outcomes() if isinstance(o, ParsedEvent)]


CHECKPOINT_TYPE_MODULES = ("agents.messages", "orchestrator.planning.state", "tools.character_states")


def checkpoint_types() -> tuple[tuple[str, str], ...]:
    """(module, class) of every pydantic model that graph state may hold: the only types a
    checkpoint may rebuild besides langgraph's own safe ones (strict msgpack allowlist)."""
    import importlib

    from pydantic import BaseModel

    out: list[tuple[str, str]] = []
    for name in CHECKPOINT_TYPE_MODULES:
        module = importlib.import_module(name)
        for obj in vars(module).values():
            if isinstance(obj, type) and issubclass(obj, BaseModel) and obj.__module__ == name:
                out.append((name, obj.__name__))
    return tuple(sorted(out))


def checkpoint_serializer() -> JsonPlusSerializer:
    return JsonPlusSerializer(allowed_msgpack_modules=checkpoint_types())


@asynccontextmanager
async def open_checkpointer(path: Path | str) -> AsyncIterator[AsyncSqliteSaver]:
    """An async SQLite checkpointer on ``path`` (created with its folder if missing) that
    rebuilds only our own state types (no warning per type, nothing else unpickled)."""
    import aiosqlite

    if str(path) != ":memory:":
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    async with aiosqlite.connect(str(path)) as conn:
        yield AsyncSqliteSaver(conn, serde=checkpoint_serializer())

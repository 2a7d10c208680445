"""Durable storage of planning runs: the langgraph checkpointer and the story log.

Both live in one SQLite file (default ``$STORYTELLER_CACHE_DIR/runs.sqlite``, else
``~/.cache/storyteller/runs.sqlite``):

- langgraph's ``AsyncSqliteSaver`` tables hold one checkpoint per finished node (the graph is
  run with ``durability="sync"``, so a node's result is on disk before the next node starts;
  a killed process resumes at the node that was cut, and no finished LLM call is repeated);
- the ``story_events`` table holds every planned event of a thread, keyed by (thread, index)
  and written with ``INSERT OR REPLACE``, so re-running the node that wrote it is harmless.
  This keeps the growing story out of the checkpointed graph state.
"""

from __future__ import annotations

import os
import sqlite3
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

from langgraph.checkpoint.sqlite.aio import AsyncSqliteSaver

from agents.messages import ParsedEvent, PlanningFailure

_SCHEMA = """
CREATE TABLE IF NOT EXISTS story_events (
    thread_id TEXT NOT NULL,
    idx INTEGER NOT NULL,
    kind TEXT NOT NULL,
    body TEXT NOT NULL,
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
        self._conn.execute(_SCHEMA)

    def close(self) -> None:
        self._conn.close()

    def record(self, index: int, outcome: ParsedEvent | PlanningFailure | None) -> None:
        """Store step ``index``'s outcome (``None``: the narrator chose to wait)."""
        if outcome is None:
            kind, body = "wait", "{}"
        elif isinstance(outcome, ParsedEvent):
            kind, body = "event", outcome.model_dump_json()
        else:
            kind, body = "failure", outcome.model_dump_json()
        self._conn.execute(
            "INSERT OR REPLACE INTO story_events (thread_id, idx, kind, body) VALUES (?, ?, ?, ?)",
            (self.thread_id, index, kind, body),
        )

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


@asynccontextmanager
async def open_checkpointer(path: Path | str) -> AsyncIterator[AsyncSqliteSaver]:
    """An async SQLite checkpointer on ``path`` (created with its folder if missing)."""
    if str(path) != ":memory:":
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    async with AsyncSqliteSaver.from_conn_string(str(path)) as saver:
        yield saver

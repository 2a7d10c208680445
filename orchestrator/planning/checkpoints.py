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

:class:`StoryLog` keeps an in-memory index of its thread's rows, read once when it opens and
updated by every :meth:`StoryLog.record` after its transaction commits, so looking up one
step (:meth:`StoryLog.outcome`, :meth:`StoryLog.trace_seqs`) costs the same at step 10 as at
step 5000 and never touches the disk: a planner asks at every step, on the event loop. The
index is only in step with the file while this object is the thread's one writer (one
``StoryLog`` per thread and file at a time, as ``storyteller run`` and ``plan`` open it).
"""

from __future__ import annotations

import json
import sqlite3
import threading
from collections.abc import AsyncIterator, Sequence
from contextlib import asynccontextmanager
from pathlib import Path

from langgraph.checkpoint.serde.jsonplus import JsonPlusSerializer
from langgraph.checkpoint.sqlite.aio import AsyncSqliteSaver

from storyteller.agents.messages import ParsedEvent, PlanningFailure
from storyteller.orchestrator.cache_paths import cache_root

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
    """``runs.sqlite`` in the cache folder (:func:`storyteller.orchestrator.cache_paths.cache_root`)."""
    return cache_root() / "runs.sqlite"


Outcome = ParsedEvent | PlanningFailure | None
"""A step's outcome: the planned event, the failure that ended the step, or None (a wait)."""


def _encode(outcome: Outcome) -> tuple[str, str]:
    if outcome is None:
        return "wait", "{}"
    if isinstance(outcome, ParsedEvent):
        return "event", outcome.model_dump_json()
    return "failure", outcome.model_dump_json()


def _decode(kind: str, body: str) -> Outcome:
    if kind == "event":
        return ParsedEvent.model_validate_json(body)
    if kind == "failure":
        return PlanningFailure.model_validate_json(body)
    return None


class StoryLog:
    """Append-only (idempotent per index) log of a thread's planning outcomes, with an
    in-memory index of them (see the module doc). Thread-safe: :meth:`record` may run in a
    worker thread while the event loop looks steps up."""

    def __init__(self, path: Path | str, thread_id: str) -> None:
        self.path = str(path)
        self.thread_id = thread_id
        if self.path != ":memory:":
            Path(self.path).parent.mkdir(parents=True, exist_ok=True)
        self._conn = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
        self._conn.executescript(_SCHEMA)
        self._lock = threading.Lock()  # one transaction at a time on the shared connection
        self._outcomes: dict[int, Outcome] = {
            idx: _decode(kind, body)
            for idx, kind, body in self._conn.execute(
                "SELECT idx, kind, body FROM story_events WHERE thread_id = ?", (self.thread_id,)
            )
        }
        self._seqs: dict[int, tuple[int, ...]] = {
            idx: tuple(int(s) for s in json.loads(seqs))
            for idx, seqs in self._conn.execute(
                "SELECT idx, seqs FROM story_trace_refs WHERE thread_id = ?", (self.thread_id,)
            )
        }

    def close(self) -> None:
        with self._lock:
            self._conn.close()

    def record(self, index: int, outcome: Outcome, trace_seqs: Sequence[int] = ()) -> None:
        """Store step ``index``'s outcome (``None``: the narrator chose to wait) and the trace
        seqs of the attempts that produced it, atomically; the index sees it once it committed."""
        kind, body = _encode(outcome)
        seqs = tuple(int(s) for s in trace_seqs)
        with self._lock:
            self._conn.execute("BEGIN")
            try:
                self._conn.execute(
                    "INSERT OR REPLACE INTO story_events (thread_id, idx, kind, body) VALUES (?, ?, ?, ?)",
                    (self.thread_id, index, kind, body),
                )
                self._conn.execute(
                    "INSERT OR REPLACE INTO story_trace_refs (thread_id, idx, seqs) VALUES (?, ?, ?)",
                    (self.thread_id, index, json.dumps(list(seqs))),
                )
            except BaseException:
                self._conn.execute("ROLLBACK")
                raise
            self._conn.execute("COMMIT")
            self._seqs[index] = seqs
            self._outcomes[index] = outcome

    def recorded(self, index: int) -> bool:
        """Whether step ``index`` has an outcome."""
        return index in self._outcomes

    def outcome(self, index: int) -> Outcome:
        """Step ``index``'s outcome; KeyError when it has none yet (see :meth:`recorded`)."""
        return self._outcomes[index]

    def trace_seqs(self, index: int) -> tuple[int, ...]:
        """Trace seqs of the attempts behind step ``index`` (empty if unknown)."""
        return self._seqs.get(index, ())

    def outcomes(self) -> list[tuple[int, Outcome]]:
        """Every step's outcome, in step order."""
        return sorted(self._outcomes.items(), key=lambda item: item[0])

    def events(self) -> list[ParsedEvent]:
        return [o for _, o in self.outcomes() if isinstance(o, ParsedEvent)]


CHECKPOINT_TYPE_MODULES = ("storyteller.agents.messages", "storyteller.orchestrator.planning.state", "storyteller.tools.character_states")


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

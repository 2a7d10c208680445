"""``live.json``: the run now, for a viewer in another process (its run panel, planner and characters).

A viewer reads the motion from the chunk files, which grow by a record per 10 simulated
seconds; what a director needs sooner comes from this small file, which the run replaces a few
times a second (:class:`LivePublisher`, a task on the run's event loop: the snapshot is taken
between two frames, the file is written in a worker thread, renamed over the old one without
following a link: ``storyteller.sim.no_follow_writes.write_file``):

- the simulated frame, the speed it is set to, whether it is paused (held at a frame boundary)
  and why it takes no pause or speed when it does not (``storyteller.orchestrator.session.viewer_controls``);
- per planner role (describer, narrator, event parser, the unified planner): the calls in flight
  and for how long the oldest has been thinking, calls so far, and the last reply with its
  latency (:class:`ReplyTap`, an LLM port that passes everything through unchanged);
- per character: its state, current event, what the event is, its action and place
  (``storyteller.orchestrator.session.run_status``).

Text in it (replies, activities, places) is a model's or a user's: data, escaped where shown,
and cut to :data:`MAX_TEXT_CHARS` / :data:`MAX_REPLY_CHARS`. :func:`read_live_state` reads it
bounded and validated; nothing a run decides depends on it, so it is left out of the trace.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import anyio
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from storyteller.agents.llm_port import LLMPort, LLMRequest, LLMResponse, TraceRecorder
from storyteller.orchestrator.session.run_status import RunStatus
from storyteller.orchestrator.session.viewer_controls import DirectorControls
from storyteller.sim.bounded_files import BoundedFileError, read_bounded_bytes
from storyteller.sim.no_follow_writes import write_file
from storyteller.sim.run_folder_names import LIVE_STATE

LIVE_FILE = LIVE_STATE
MAX_LIVE_BYTES = 1 << 20
"""Bytes of the largest ``live.json`` read."""
MAX_TEXT_CHARS = 300
"""Characters kept of an activity or a place."""
MAX_REPLY_CHARS = 1500
"""Characters kept of a role's last reply."""
PUBLISH_EVERY_S = 0.25
"""Wall seconds between two writes of the file."""


def _cut(text: str, limit: int) -> str:
    return text if len(text) <= limit else text[: limit - 1] + "\u2026"


class _Live(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


class RoleNow(_Live):
    """One planner role: ``thinking_s`` the oldest call in flight has run (None: none in flight)."""

    role: str = Field(max_length=64)
    thinking_s: float | None = Field(default=None, ge=0)
    in_flight: int = Field(default=0, ge=0)
    calls: int = Field(default=0, ge=0)
    failed: int = Field(default=0, ge=0)
    last_reply: str = Field(default="", max_length=MAX_REPLY_CHARS)
    last_reply_s: float | None = Field(default=None, ge=0, description="Wall seconds the last reply took.")


class CharacterNow(_Live):
    """One character at :attr:`LiveState.frame` (``run_status.CharacterRow``)."""

    name: str = Field(max_length=200)
    state: str = Field(max_length=32)
    event_id: str = Field(default="", max_length=64)
    activity: str = Field(default="", max_length=MAX_TEXT_CHARS)
    action: str = Field(default="", max_length=MAX_TEXT_CHARS)
    place: str = Field(default="", max_length=MAX_TEXT_CHARS)


class LiveState(_Live):
    """The whole file."""

    thread: str = Field(max_length=200)
    frame: int = Field(ge=0)
    frames: int = Field(ge=0)
    fps: int = Field(gt=0)
    pace: str = Field(max_length=16)
    speed: float = Field(gt=0, description="Simulated seconds per wall second the run is set to.")
    paused: bool = Field(default=False, description="Held at a frame boundary now.")
    pausing: bool = Field(default=False, description="The last control says pause (held at the next boundary).")
    controls: str | None = Field(default=None, max_length=400, description="Why pause and speed are refused.")
    controls_applied: int = Field(default=0, ge=0)
    running: bool = True
    updated_unix: float = Field(ge=0)
    roles: tuple[RoleNow, ...] = Field(default=(), max_length=16)
    characters: tuple[CharacterNow, ...] = Field(default=(), max_length=256)


@dataclass
class _Reply:
    text: str
    latency_s: float


class ReplyTap:
    """An :class:`agents.llm_port.LLMPort` that keeps each role's last reply (text and latency)
    and passes requests and answers through unchanged (so a run plans, records and replays as
    without it)."""

    def __init__(self, port: LLMPort) -> None:
        self.port = port
        self.last: dict[str, _Reply] = {}

    @property
    def trace(self) -> TraceRecorder | None:
        return self.port.trace

    async def complete(self, request: LLMRequest) -> LLMResponse:
        response = await self.port.complete(request)
        self.last[request.node] = _Reply(_cut(response.text, MAX_REPLY_CHARS), max(response.latency_s, 0.0))
        return response

    def close(self) -> None:
        self.port.close()


class LivePublisher:
    """Writes ``<out>/live.json`` from the run's status, replies and controls (see the module doc)."""

    def __init__(self, out: Path, thread: str, status: RunStatus, replies: ReplyTap, controls: DirectorControls,
                 *, speed: float, refusal: str | None, wall: Callable[[], float] = time.time) -> None:
        self.path = out / LIVE_FILE
        self.thread = thread
        self.status = status
        self.replies = replies
        self.controls = controls
        self.speed = speed
        self.refusal = refusal
        self.wall = wall

    def state(self, *, running: bool = True) -> LiveState:
        """The run now (on the event loop, between two frames)."""
        snap = self.status.snapshot()
        roles = []
        for r in snap.roles:
            reply = self.replies.last.get(r.role)
            roles.append(RoleNow(
                role=r.role[:64], thinking_s=r.longest_s if r.in_flight else None, in_flight=r.in_flight,
                calls=r.calls, failed=r.failed, last_reply=reply.text if reply is not None else "",
                last_reply_s=reply.latency_s if reply is not None else None,
            ))  # fmt: skip
        characters = tuple(
            CharacterNow(name=c.name[:200], state=c.state, event_id=c.event_id[:64],
                         activity=_cut(c.activity, MAX_TEXT_CHARS), action=_cut(c.action, MAX_TEXT_CHARS),
                         place=_cut(c.place, MAX_TEXT_CHARS))
            for c in snap.characters[:256]
        )  # fmt: skip
        accepted = self.refusal is None
        return LiveState(
            thread=self.thread[:200], frame=snap.frame, frames=snap.frames, fps=snap.fps, pace=snap.pace[:16],
            speed=self.controls.speed(self.speed) if accepted else self.speed,
            paused=self.controls.paused_at is not None, pausing=accepted and self.controls.paused,
            controls=self.refusal, controls_applied=self.controls.applied, running=running,
            updated_unix=max(self.wall(), 0.0), roles=tuple(roles[:16]), characters=characters,
        )  # fmt: skip

    def write(self, state: LiveState) -> None:
        write_file(self.path, json.dumps(state.model_dump(mode="json"), ensure_ascii=True).encode("ascii"))

    async def run(self, every_s: float = PUBLISH_EVERY_S) -> None:
        """Write the state every ``every_s`` until cancelled (a failed write is tried again later)."""
        while True:
            state = self.state()
            with contextlib.suppress(OSError):  # a full disk: the run goes on (the trace reports its writes)
                await anyio.to_thread.run_sync(self.write, state)
            await anyio.sleep(every_s)


def read_live_bytes(folder: Path) -> bytes | None:
    """The bytes of ``folder``'s ``live.json`` (None when there is none yet), read within
    :data:`MAX_LIVE_BYTES`; ``ValueError`` with one line naming the file when it is too big or
    not a regular file."""
    path = folder / LIVE_FILE
    try:
        return read_bounded_bytes(path, MAX_LIVE_BYTES, str(path))
    except BoundedFileError as exc:
        if exc.missing:
            return None
        raise ValueError(str(exc)) from None


def read_live_state(folder: Path) -> LiveState | None:
    """``folder``'s ``live.json`` (None when there is none yet); ``ValueError`` with one line
    naming the file when it is not one (too big, not a regular file, not the model)."""
    path = folder / LIVE_FILE
    raw = read_live_bytes(folder)
    if raw is None:
        return None
    try:
        return LiveState.model_validate_json(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(p) for p in err["loc"]) or "(file)"
        raise ValueError(f"{path}: {where}: {err['msg']}") from None

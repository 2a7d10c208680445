"""The instructions waiting to take effect in a story session, scheduled and live.

The narrator always sees the latest instruction (a new one replaces the old). A new instruction
takes effect at the start of a frame, before the world steps: scheduled ones
(``SessionSettings.instructions``: a timed script, or a replay's recorded ones) at their frame,
live ones (:meth:`InstructionQueue.instruct`, :meth:`InstructionQueue.instruct_nowait`, e.g.
from stdin) at the first frame the simulation starts after they arrive (a resumed session: after
the last frame its trace shows, ``SessionSettings.recorded_until``). Every request made
after that frame carries it, with ``instruction_since`` = its own step index, so events planned
under an earlier instruction never count as parts of this one done
(``storyteller.agents.instruction_parts``). Each one is reported to ``on_instruction`` (the run job records
it in the trace with its frame); a replay passes the recorded ones as scheduled and ignores
live ones, so they take effect at the same frames again.

The session takes the ones due at each frame (:meth:`InstructionQueue.due`) and tells the queue
the frame each live one took effect at (:meth:`InstructionQueue.took_effect`), which wakes its
waiting :meth:`~InstructionQueue.instruct`. Live instructions may be added from any thread.

Bounded: a session takes at most :data:`MAX_LIVE_INSTRUCTIONS` live instructions (as many as a
script may hold); later ones are refused with a warning, and a reader that is refused stops (a
viewer's inbox of a million lines took a resume past 40 s and wrote each line into the trace).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

import anyio
import structlog

from storyteller.orchestrator.session.instruction_script import MAX_SCRIPT_INSTRUCTIONS
from storyteller.orchestrator.session.session_types import InstructionSource, TimedInstruction

MAX_LIVE_INSTRUCTIONS = MAX_SCRIPT_INSTRUCTIONS
"""Live instructions (stdin, a viewer's box) one session takes at most."""

_log = structlog.get_logger("storyteller.session")


class InstructionQueue:
    """Scheduled instructions by frame (stable: file order on ties) and live ones in arrival
    order; ``live`` False (a replay): live ones are ignored."""

    def __init__(self, scheduled: Sequence[TimedInstruction], *, live: bool) -> None:
        self._live_allowed = live
        self._scheduled = sorted(scheduled, key=lambda i: i.frame)  # stable: file order on ties
        self._live: deque[tuple[str, InstructionSource, anyio.Event | None]] = deque()  # thread-safe appends
        self._taken: dict[int, int] = {}  # id(event) of a waiting instruct() -> frame it took effect at
        self._ended = False
        self._live_taken = 0  # live instructions taken so far (a count: nothing else reads it across threads)

    async def instruct(self, text: str, source: InstructionSource = "api") -> int | None:
        """Make ``text`` the instruction from the next frame the simulation starts; returns
        that frame once it took effect (None: ignored, in a replay, or the story had ended).
        Called before the session runs, it waits for the run's first frame. Raises ValueError
        for an empty text."""
        event = anyio.Event()
        if not self._enqueue(text, source, event):
            return None
        await event.wait()
        return self._taken.pop(id(event), None)

    def instruct_nowait(self, text: str, source: InstructionSource = "stdin") -> bool:
        """:meth:`instruct` without waiting; safe to call from any thread (e.g. a stdin reader).
        False when the instruction is ignored (a replay, or the story has ended)."""
        return self._enqueue(text, source, None)

    def _enqueue(self, text: str, source: InstructionSource, event: anyio.Event | None) -> bool:
        text = " ".join(text.split())
        if not text:
            raise ValueError("an instruction must not be empty")
        if not self._live_allowed or self._ended:
            _log.warning("instruction_ignored", text=text, reason="replay" if not self._ended else "story ended")
            return False
        if self._live_taken >= MAX_LIVE_INSTRUCTIONS:
            if self._live_taken == MAX_LIVE_INSTRUCTIONS:  # said once
                _log.warning("instruction_ignored", text=text, reason=f"more than {MAX_LIVE_INSTRUCTIONS} live instructions")
                self._live_taken += 1
            return False
        self._live_taken += 1
        self._live.append((text, source, event))
        return True

    def due(self, frame: int, *, live: bool = True) -> list[tuple[TimedInstruction, anyio.Event | None]]:
        """The instructions that take effect at ``frame``, in order (scheduled ones first), each
        with the event its :meth:`instruct` waits on (None: nobody waits). ``live`` False: the
        live ones wait for a later frame."""
        out: list[tuple[TimedInstruction, anyio.Event | None]] = []
        while self._scheduled and self._scheduled[0].frame <= frame:
            out.append((self._scheduled.pop(0), None))
        while live and self._live:
            text, source, event = self._live.popleft()
            out.append((TimedInstruction(frame=frame, text=text, source=source), event))
        return out

    def took_effect(self, event: anyio.Event | None, frame: int) -> None:
        """The instruction ``event`` waits on took effect at ``frame``: its :meth:`instruct` returns."""
        if event is not None:
            self._taken[id(event)] = frame
            event.set()

    def skip_before(self, frame: int) -> None:
        """Resumed at ``frame``: the scheduled instructions before it took effect already."""
        self._scheduled = [i for i in self._scheduled if i.frame >= frame]

    def close(self) -> None:
        """The story ended: later instructions are ignored, and every waiting one returns None."""
        self._ended = True
        while self._live:
            _, _, event = self._live.popleft()
            if event is not None:
                event.set()

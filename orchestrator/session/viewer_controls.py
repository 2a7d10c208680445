"""``viewer_controls.jsonl``: a director's pause, resume and speed, from a viewer to a realtime run.

The viewer's run panel (``storyteller view RUN_DIR`` or ``run --view``, any number of them and
of browsers) appends one JSON line per press (:func:`send_control`):
``{"id": "<32 hex>", "thread": "<run.json's thread id>", "kind": "pause" | "resume" | "speed",
"speed": 2.0 | null, "sent_unix": 1.7e9}``, in one ``write`` without following a link, fsynced
before the page says it was sent (the same channel as the instruction box:
``storyteller.orchestrator.session.viewer_instructions``). The run reads the file from its last offset in a
thread of its own (:func:`start_control_reader`, lines bounded and parsed as instructions are:
:class:`~storyteller.orchestrator.session.viewer_instructions.ThreadLines`), each line once (by id, for
this run's thread only), and the simulation applies what they say at a frame boundary
(:class:`DirectorControls` is the session's ``session_types.Pacer``): paused, it waits between two
frames until a ``resume``; a new speed sets the wall time of the next frames.

Only a ``realtime`` run takes them (:func:`controls_refusal` says why another does not): in
``lockstep``, ``fast`` and ``offline`` pace simulated time does not follow the wall clock.

Determinism (why the trace records nothing new): a pause or a speed changes when frames start on
the wall clock, never what a frame computes. What wall time can decide in a realtime run is
already recorded with its frame: the frame a planning result is applied at (``applied``), the
frame an instruction takes effect at (``instruction``), the frame and phase a step is requested
at (``requested``, with overlapping steps). A step that finishes while the run is paused is
applied at the first frame after it resumes, and that frame is in the trace, so ``storyteller
replay`` gives the same events and motion, byte for byte (``tests/orchestrator/viewer/test_viewer_controls.py``).

Restarts: the state is the file's, folded in order (the last ``pause`` / ``resume``, the last
speed), so a resumed run (which reads the file from its start) takes the state the director
left: paused when the last press was Pause. Nothing else in the run depends on it.
"""

from __future__ import annotations

import math
import threading
import time
import uuid
from pathlib import Path
from typing import Literal

import anyio
import structlog
from pydantic import Field, model_validator

from storyteller.orchestrator.session.pace import MAX_SPEED, MIN_SPEED
from storyteller.orchestrator.session.viewer_instructions import POLL_S, ThreadLines, ViewerLine, append_line
from storyteller.sim.run_folder_names import VIEWER_CONTROLS

_log = structlog.get_logger("storyteller.session")

CONTROLS_FILE = VIEWER_CONTROLS
HOLD_POLL_S = 0.02
"""Wall seconds between two looks at the pause flag while the simulation is held."""
ControlKind = Literal["pause", "resume", "speed"]


class ViewerControl(ViewerLine):
    """One line of the file: a press in a viewer's run panel for the run of ``thread``."""

    kind: ControlKind
    speed: float | None = Field(default=None, ge=MIN_SPEED, le=MAX_SPEED,
                                description="kind 'speed': simulated seconds per wall second.")
    sent_unix: float = Field(ge=0, description="When the viewer wrote it (wall clock; shown only).")

    @model_validator(mode="after")
    def _speed_with_its_kind(self) -> ViewerControl:
        if (self.kind == "speed") != (self.speed is not None):
            raise ValueError("a speed is given with kind 'speed' and only then")
        return self


def speed_problem(speed: float) -> str | None:
    """Why ``speed`` cannot be set (None: it can)."""
    if not math.isfinite(speed) or not MIN_SPEED <= speed <= MAX_SPEED:
        return f"a speed between {MIN_SPEED:g} and {MAX_SPEED:g} is taken, not {speed!r}"
    return None


def send_control(folder: Path, thread: str, kind: ControlKind, speed: float | None = None, *,
                 sent_unix: float) -> ViewerControl:
    """Append a ``kind`` press for the run of ``thread`` to ``folder``'s file, on disk when this
    returns. ``ValueError`` for a speed out of bounds; ``OSError`` naming the file when it cannot
    be written (a link or anything but a regular file there, a full disk)."""
    if speed is not None and (problem := speed_problem(speed)) is not None:
        raise ValueError(problem)
    line = ViewerControl(id=uuid.uuid4().hex, thread=thread, kind=kind, speed=speed, sent_unix=sent_unix)
    append_line(folder / CONTROLS_FILE, line)
    return line


def controls_refusal(pace: str) -> str | None:
    """Why a run of ``pace`` takes no pause or speed (None: it takes them)."""
    if pace == "realtime":
        return None
    why = {
        "lockstep": "the simulation waits for the planner at every step",
        "fast": "the simulation runs as fast as it can",
        "offline": "simulated time follows the LLM calls' latency",
    }.get(pace, "its simulated time does not follow the wall clock")
    return f"pause and speed apply to a realtime run; this run's pace is {pace} ({why})"


class ControlInbox(ThreadLines[ViewerControl]):
    """The run's side: the new lines for ``thread`` since the last :meth:`poll`."""

    what = "viewer_control"

    def __init__(self, path: Path, thread: str) -> None:
        super().__init__(path, thread, ViewerControl)


class DirectorControls:
    """Pause and speed of one realtime run, as its control lines say (thread-safe: the reader
    thread calls :meth:`take`, the simulation :meth:`hold` and :meth:`speed` between frames).

    ``speed``: the run's own (``--speed``) until a line sets another. :attr:`paused_at`: the
    frame the simulation is held before (None: running); :attr:`paused_s`: wall seconds held
    so far, in all."""

    def __init__(self, speed: float) -> None:
        self._lock = threading.Lock()
        self._paused = False
        self._speed = speed
        self.applied = 0
        self.paused_at: int | None = None
        self.paused_s = 0.0

    @property
    def paused(self) -> bool:
        """Whether the last line says pause (the simulation holds at its next frame boundary)."""
        return self._paused

    def take(self, lines: list[ViewerControl]) -> None:
        """Fold new lines into the state, in file order."""
        with self._lock:
            for line in lines:
                if line.kind == "speed" and line.speed is not None:
                    self._speed = line.speed
                else:
                    self._paused = line.kind == "pause"
                self.applied += 1
                _log.info("viewer_control", kind=line.kind, speed=line.speed)

    def speed(self, current: float) -> float:
        """The speed the next frames run at (``current``: the session's now; unused)."""
        return self._speed

    async def hold(self, frame: int) -> float:
        """At the boundary before ``frame``: wait while paused; the wall seconds waited."""
        if not self._paused:
            return 0.0
        t0 = time.monotonic()
        self.paused_at = frame
        try:
            while self._paused:
                await anyio.sleep(HOLD_POLL_S)
        finally:
            self.paused_at = None
            held = time.monotonic() - t0
            self.paused_s += held
        return held


def start_control_reader(controls: DirectorControls, path: Path, thread: str, *,
                         stop: threading.Event) -> threading.Thread:
    """Start the daemon thread that feeds every new line of ``path`` for ``thread`` to
    ``controls`` (every :data:`~storyteller.orchestrator.session.viewer_instructions.POLL_S`); it ends when
    ``stop`` is set. The file's lines from before are read at once (a resumed run starts in the
    state they leave)."""
    inbox = ControlInbox(path, thread)
    controls.take(inbox.poll())

    def read() -> None:
        while not stop.wait(POLL_S):
            lines = inbox.poll()
            if lines:
                controls.take(lines)

    reader = threading.Thread(target=read, name="storyteller-viewer-controls", daemon=True)
    reader.start()
    return reader

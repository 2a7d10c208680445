"""Where each frame's wall time went, in the simulation task of a session (this process).

The simulation task (``storyteller.orchestrator.session.runtime``) times the parts of every frame it runs
and appends them here; the interval between two frames is their sum. Parts (wall seconds):

- ``settle``: instructions, news from the planner, outcomes applied (trace and story-stream
  records handed to the writer), waiting for news in ``lockstep`` / ``offline`` pace;
- ``step``: the world step (``storyteller.sim.world.step.step``) and the event bookkeeping after it;
- ``ask``: building and starting planning requests;
- ``checkpoint``: taking the session's checkpoint and handing it to ``on_checkpoint`` (the run
  job's writer thread writes it);
- ``sleep``: the time the task asked to sleep (``realtime``: until the frame is due);
- ``late``: how much longer than asked the sleep lasted: other tasks on the event loop
  (a planning step, the LLM client, a trace write), other threads holding the GIL, the
  garbage collector, the machine.

Storage is float32 per part and frame (24 bytes a frame: an hour at 30 fps is 2.6 MB). Only
for measurement (``metrics.json``, ``benchmark/bench_frame_interval.py``): nothing reads it back
to decide anything, so timing never changes a story.
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass, field

PARTS = ("settle", "step", "ask", "checkpoint", "sleep", "late")
"""The parts of a frame, in the order the simulation task runs them."""


def _column() -> array[float]:
    return array("f")


@dataclass
class FrameProfile:
    """Per-frame wall seconds of each part (see the module doc), one entry per frame run."""

    settle: array[float] = field(default_factory=_column)
    step: array[float] = field(default_factory=_column)
    ask: array[float] = field(default_factory=_column)
    checkpoint: array[float] = field(default_factory=_column)
    sleep: array[float] = field(default_factory=_column)
    late: array[float] = field(default_factory=_column)

    def add(self, settle: float, step: float, ask: float, checkpoint: float, sleep: float, late: float) -> None:
        """The parts of one more frame, in :data:`PARTS` order."""
        self.settle.append(settle)
        self.step.append(step)
        self.ask.append(ask)
        self.checkpoint.append(checkpoint)
        self.sleep.append(sleep)
        self.late.append(late)

    def __len__(self) -> int:
        return len(self.step)

    def part(self, name: str) -> array[float]:
        """The column of one of :data:`PARTS`."""
        if name not in PARTS:
            raise KeyError(f"unknown frame part {name!r}; expected one of {', '.join(PARTS)}")
        col: array[float] = getattr(self, name)
        return col

"""The viewer process of ``run --view`` (``storyteller.orchestrator.viewer.child``) yields the CPU to the run.

On a shared machine the run's frames come first: the child runs ``NICE`` steps below its parent
(``benchmark/results/2026-12-03-viewer-frame-interval.md``: with the viewer and a browser on the
same two cores, late frames were the machine's, not the run's own work).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from storyteller.orchestrator.viewer.child import NICE, spawn_viewer


def test_the_viewer_process_runs_at_a_lower_cpu_priority_than_the_run(tmp_path: Path) -> None:
    (tmp_path / "run").mkdir()
    viewer = spawn_viewer(tmp_path / "run", port=0, host="127.0.0.1")
    try:
        assert viewer.alive and viewer.url.startswith("http://127.0.0.1:")
        mine = os.getpriority(os.PRIO_PROCESS, 0)
        assert os.getpriority(os.PRIO_PROCESS, viewer.proc.pid) == min(mine + NICE, 19)
    finally:
        viewer.stop()
    assert not viewer.alive
    assert viewer.proc.stdout is not None
    deadline = time.monotonic() + 10
    while not viewer.proc.stdout.closed and time.monotonic() < deadline:  # the reader's end of the pipe
        time.sleep(0.05)
    assert viewer.proc.stdout.closed

"""Ending a child process this process started: SIGTERM, a grace period, then SIGKILL.

:func:`stop_child` is the one place that does it (the viewer child of ``run --view``, the
benchmark's headless Chromium and busy core); it returns only once the child is reaped, so no
zombie is left behind whatever the child does with SIGTERM.
"""

from __future__ import annotations

import subprocess
from typing import Any

__all__ = ["stop_child"]


def stop_child(proc: subprocess.Popen[Any], *, grace_s: float) -> None:
    """Send ``proc`` SIGTERM, wait up to ``grace_s`` wall seconds for it to end, then SIGKILL
    it; reaped when this returns."""
    proc.terminate()
    try:
        proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()

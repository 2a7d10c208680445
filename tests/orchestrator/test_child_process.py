"""``storyteller.orchestrator.child_process.stop_child``: a child that ends on SIGTERM ends by it; one that
ignores SIGTERM is killed after the grace period; either way it is reaped."""

from __future__ import annotations

import signal
import subprocess
import sys

from storyteller.orchestrator.child_process import stop_child

IGNORES_TERM = (
    "import signal, sys, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
    "print('ready', flush=True); time.sleep(60)"
)


def test_a_child_that_takes_sigterm_ends_by_it() -> None:
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    stop_child(proc, grace_s=30)
    assert proc.returncode == -signal.SIGTERM


def test_a_child_that_ignores_sigterm_is_killed_and_reaped() -> None:
    proc = subprocess.Popen([sys.executable, "-c", IGNORES_TERM], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    assert proc.stdout.readline() == "ready\n"  # its handler is in place
    stop_child(proc, grace_s=0.2)
    assert proc.returncode == -signal.SIGKILL
    proc.stdout.close()

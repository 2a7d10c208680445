"""The viewer in a process of its own, for ``storyteller run --view``.

Why not a thread of the run: the viewer's work is Python (reading the growing chunk files,
posing every figure 30 times a second, serving the page), and in the run's process it takes the
interpreter lock the simulation needs every 33 ms. Measured with ``python -m
storyteller.benchmark.bench_frame_interval --viewer`` (20 characters, realtime), the viewer in the run's
process made many more frames late than in a process of its own
(``benchmark/results/2026-12-03-viewer-frame-interval.md``).

:func:`spawn_viewer` starts ``storyteller view FOLDER --play --port P --host H`` with this
process as its parent (the child stops by itself within a second when its parent is gone, even
after a kill -9), reads the address it prints and returns a :class:`ViewerProcess`; a child
that ends before (an address it cannot listen on) is a :class:`ViewerStartError` with its
error line. The child is in this process's group, so Ctrl-C on the terminal reaches both. It
runs at a lower CPU priority (:data:`NICE`) than the run.
"""

from __future__ import annotations

import os
import queue
import subprocess
import sys
import threading
from pathlib import Path
from typing import IO

from storyteller.orchestrator.child_process import stop_child
from storyteller.orchestrator.terminal import say
from storyteller.orchestrator.viewer.access import is_loopback

START_TIMEOUT_S = 120.0
"""Wall seconds the viewer may take to print its address (its imports on a busy machine)."""
NICE = 10
"""How much lower the viewer's CPU priority is than the run's: on a busy machine the run's frames
come first (os.nice; the viewer only shows them)."""
ENTRY = f"import os; os.nice({NICE}); from storyteller.orchestrator.cli.app import app; app()"


class ViewerStartError(Exception):
    """The viewer process ended before it printed its address (the message is its error)."""


class ViewerProcess:
    """A running ``storyteller view`` child: :attr:`address` is what it printed, :attr:`url` the
    page; :meth:`stop` ends it (SIGTERM, then SIGKILL after 10 s)."""

    def __init__(self, proc: subprocess.Popen[str], address: str, url: str) -> None:
        self.proc = proc
        self.address = address
        self.url = url

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self) -> None:
        if self.proc.poll() is None:
            stop_child(self.proc, grace_s=10)


def spawn_viewer(
    folder: Path, *, port: int, host: str, smplx_model: Path | None = None, play: bool = True,
    forward: IO[str] | None = None,
) -> ViewerProcess:
    """Start the viewer of ``folder`` and wait for its address. What it prints afterwards goes
    to ``forward`` (default: stderr), except viser's own "Server stopped"."""
    args = [sys.executable, "-c", ENTRY, "view", str(folder), "--port", str(port), "--host", host,
            "--play" if play else "--paused", "--parent", str(os.getpid())]
    if smplx_model is not None:
        args += ["--smplx-model", str(smplx_model)]
    proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, errors="replace", bufsize=1)
    assert proc.stdout is not None
    lines: queue.Queue[str | None] = queue.Queue()

    def read(stream: IO[str]) -> None:
        with stream:  # closed at the child's end (its last line read)
            for line in stream:
                lines.put(line.rstrip("\n"))
        lines.put(None)

    threading.Thread(target=read, args=(proc.stdout,), name="viewer-output", daemon=True).start()
    said: list[str] = []
    wanted = 1 if is_loopback(host) else 2  # beyond this machine a second line says who can reach it
    address: list[str] = []
    while len(address) < wanted:
        try:
            line = lines.get(timeout=START_TIMEOUT_S)
        except queue.Empty:
            proc.kill()
            proc.wait()
            raise ViewerStartError(f"the viewer printed no address within {START_TIMEOUT_S:.0f} s") from None
        if line is None:
            proc.wait()
            errors = [s for s in said if s.startswith("error:")]
            raise ViewerStartError((errors[-1] if errors else f"the viewer ended ({proc.returncode})").removeprefix("error: "))
        if address or line.startswith("viewing "):
            address.append(line)
        else:
            said.append(line)
    first = address[0]
    url = first[first.rindex(" at http") + 4 :].split(" ", 1)[0]
    sink = forward if forward is not None else sys.stderr

    def relay() -> None:
        while (line := lines.get()) is not None:
            if not line.startswith("(viser)"):
                say(line, file=sink)

    threading.Thread(target=relay, name="viewer-relay", daemon=True).start()
    return ViewerProcess(proc, "\n".join(address), url)

"""How an attack is run and judged: a CLI subprocess under the address-space guard and a time
limit (:func:`run_command`), the files around it before and after (:func:`tree_state`,
:func:`digest`) and the verdict on the issue's targets (:func:`judge`, :class:`Outcome`).

The time judged is the command's wall-clock time less the time its main thread waited for a CPU
while it could run (Linux ``/proc/PID/schedstat``, the run-queue delay): on a busy machine
other processes' work is not counted against it, while everything the command does itself
(its CPU time, and any time it sleeps or blocks: on a FIFO, a lock, a child, a timeout) still
is, so a hang or a long sleep fails exactly as before. The clean command that sets the limit is
timed the same way. Where ``schedstat`` cannot be read the delay counts as 0 (the wall clock).
The CPU time of the command and the children it waited for is measured and shown beside it.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import resource
import signal
import stat
import subprocess
import tempfile
import time
import unicodedata
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from storyteller.benchmark.hostile.harness import AS_LIMIT, CLI, RSS_LIMIT, Spec


@dataclass
class Outcome:
    kind: str
    name: str
    code: int | None
    seconds: float
    rss: int
    problems: list[str]
    queued: float = 0.0
    """Seconds of ``seconds`` the command's main thread waited for a CPU (not judged)."""
    cpu: float = 0.0
    """CPU seconds of the command and the children it waited for."""

    @property
    def verdict(self) -> str:
        return "ok" if not self.problems else "FAIL: " + "; ".join(self.problems)


def tree_state(root: Path, skip: tuple[Path, ...]) -> dict[str, tuple[int, int, int]]:
    """Every entry under ``root`` but ``skip``: (mode, size, mtime) from lstat, links not followed."""
    state: dict[str, tuple[int, int, int]] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        here = Path(dirpath)
        dirnames[:] = [d for d in dirnames if here / d not in skip]
        for name in (*dirnames, *filenames):
            path = here / name
            if path in skip:
                continue
            st = os.lstat(path)  # a folder's own times change as its outputs are written: its mode only
            state[str(path)] = (st.st_mode, 0, 0) if stat.S_ISDIR(st.st_mode) else (st.st_mode, st.st_size, st.st_mtime_ns)
    return state


def digest(root: Path) -> dict[str, str]:
    out: dict[str, str] = {}
    if not root.is_dir() or root.is_symlink():
        return out
    for path in sorted(root.rglob("*")):
        if path.is_symlink() or not path.is_file():
            out[str(path)] = "special"
        elif path.stat().st_size < (64 << 20):
            out[str(path)] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def bad_characters(text: str) -> list[str]:
    return sorted({f"U+{ord(c):04X}" for c in text
                   if unicodedata.category(c) in ("Cc", "Cf", "Zl", "Zp") and c not in "\n\t"})


def limit_child() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (AS_LIMIT, AS_LIMIT))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))


BACKSTOP = 10.0
"""A command is killed after this many times its limit of wall-clock time, whatever it waited."""


class Run(NamedTuple):
    """What :func:`run_command` measured."""

    code: int | None
    """Exit code, or None after a kill at the time limit."""
    seconds: float
    """Wall-clock seconds."""
    queued: float
    """Seconds the command's main thread waited for a CPU while runnable (not judged)."""
    cpu: float
    """CPU seconds (user + system) of the command and the children it waited for."""
    rss: int
    """Max resident set size, bytes."""
    stdout: str
    stderr: str

    @property
    def judged(self) -> float:
        """The time judged: wall-clock less the wait for a CPU."""
        return self.seconds - self.queued


def run_queue_delay(pid: int) -> float | None:
    """Seconds thread ``pid`` has waited on a run queue so far (``/proc/PID/schedstat``'s second
    field, nanoseconds), or None where it cannot be read."""
    try:
        with open(f"/proc/{pid}/schedstat", "rb") as f:
            return int(f.read().split()[1]) / 1e9
    except (OSError, ValueError, IndexError):
        return None


def run_command(argv: list[str], timeout: float, env: dict[str, str], cwd: Path,
                stdin: bytes | None = None) -> Run:
    """Run the CLI with ``argv``, killed once its judged time (wall-clock less the wait for a CPU)
    passes ``timeout`` (or its wall-clock time passes ``BACKSTOP`` times that). ``stdin`` (an
    attack's :attr:`Spec.stdin`) is what the command reads on stdin, from a file (so a command
    that does not read it never blocks the harness); None: nothing (``/dev/null``)."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err, tempfile.TemporaryFile() as given:
        if stdin is not None:
            given.write(stdin)
            given.seek(0)
        start = time.monotonic()
        proc = subprocess.Popen([*CLI, *argv], stdout=out, stderr=err,
                                stdin=subprocess.DEVNULL if stdin is None else given, env=env, cwd=cwd,
                                preexec_fn=limit_child, start_new_session=True)
        code: int | None = None
        queued = 0.0  # as last read; the wait after the last read (< one poll) is counted as work
        while True:
            queued = run_queue_delay(proc.pid) or queued
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                code = os.waitstatus_to_exitcode(status)
                break
            elapsed = time.monotonic() - start
            if elapsed - queued > timeout or elapsed > BACKSTOP * timeout:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                _, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.05)
        seconds = time.monotonic() - start
        proc.returncode = -1  # reaped here
        out.seek(0)
        err.seek(0)
        return Run(code, seconds, min(queued, seconds), usage.ru_utime + usage.ru_stime, usage.ru_maxrss * 1024,
                   out.read().decode("utf-8", "replace"), err.read().decode("utf-8", "replace"))


def judge(spec: Spec, run: Run, limit: float) -> list[str]:
    problems = []
    code, rss, stdout, stderr = run.code, run.rss, run.stdout, run.stderr
    if code is None:
        problems.append(f"killed after {limit:.0f} s")
    elif run.judged > limit:
        problems.append(f"{run.judged:.1f} s > {limit:.1f} s (wall {run.seconds:.1f} s, {run.queued:.1f} s waiting for a CPU)")
    if rss > RSS_LIMIT:
        problems.append(f"RSS {rss >> 20} MiB")
    lines = [line for line in stderr.splitlines() if line.strip()]
    if "Traceback" in stdout + stderr:
        problems.append("traceback")
    one_line = code == 2 and len(lines) == 1 and lines[0].startswith("error:")
    refused_program = code == 1 and len(lines) == 1 and lines[0].startswith("error (")
    accepted = spec.expect in ("either", "program") and code == 0
    if code is not None and not (one_line or accepted or (spec.expect == "program" and refused_program)):
        shown = (lines[-1] if lines else "")[:120]
        problems.append(f"exit {code} with {len(lines)} stderr lines ({shown!r})")
    bad = bad_characters(stdout + stderr)
    if bad:
        problems.append("raw " + ",".join(bad[:4]))
    return problems

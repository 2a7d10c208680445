"""How an attack is run and judged: a CLI subprocess under the address-space guard and a
wall-clock limit (:func:`run_command`), the files around it before and after (:func:`tree_state`,
:func:`digest`) and the verdict on the issue's targets (:func:`judge`, :class:`Outcome`).
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

from benchmark.hostile.harness import AS_LIMIT, CLI, RSS_LIMIT, Spec


@dataclass
class Outcome:
    kind: str
    name: str
    code: int | None
    seconds: float
    rss: int
    problems: list[str]

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


def run_command(argv: list[str], timeout: float, env: dict[str, str], cwd: Path,
                stdin: bytes | None = None) -> tuple[int | None, float, int, str, str]:
    """Run the CLI with ``argv``: (exit code or None after a kill at ``timeout``, seconds, max
    RSS in bytes, stdout, stderr)."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        start = time.monotonic()
        proc = subprocess.Popen([*CLI, *argv], stdout=out, stderr=err, stdin=subprocess.DEVNULL, env=env, cwd=cwd,
                                preexec_fn=limit_child, start_new_session=True)
        code: int | None = None
        rss = 0
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                code = os.waitstatus_to_exitcode(status)
                rss = usage.ru_maxrss * 1024
                break
            if time.monotonic() - start > timeout:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                _, status, usage = os.wait4(proc.pid, 0)
                rss = usage.ru_maxrss * 1024
                break
            time.sleep(0.05)
        seconds = time.monotonic() - start
        proc.returncode = -1  # reaped here
        out.seek(0)
        err.seek(0)
        return code, seconds, rss, out.read().decode("utf-8", "replace"), err.read().decode("utf-8", "replace")


def judge(spec: Spec, code: int | None, seconds: float, rss: int, stdout: str, stderr: str, limit: float) -> list[str]:
    problems = []
    if code is None:
        problems.append(f"killed after {limit:.0f} s")
    elif seconds > limit:
        problems.append(f"{seconds:.1f} s > {limit:.1f} s")
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

"""A short CPU slice for the thread that paces a realtime run (Linux 6.12 and later).

A realtime frame is due every 33 ms, and the simulation task sleeps until then; on a busy
machine that sleep ends late when the woken thread waits for a CPU behind other programs'
slices (a browser rendering the viewer's page in software, other jobs). Linux's EEVDF
scheduler lets a thread ask for a shorter slice (``sched_attr.sched_runtime`` of
``sched_setattr(2)`` for ``SCHED_OTHER``, 0.1 to 100 ms, no privilege needed): a woken thread
with a short slice has an earlier deadline and is run sooner. Its share of the CPU (its nice
value, its weight) is unchanged; it only gets that share in shorter turns.

:func:`short_slice` asks for :data:`SLICE_NS` for the calling thread (the event loop's, which
the simulation task runs on; threads and processes it starts meanwhile, such as the planner's
workers, keep the default) and gives the thread back its slice before on exit. Where it
cannot (not Linux, an architecture whose system-call numbers it does not know, a kernel that
keeps no custom slice, a policy other than ``SCHED_OTHER``, a refusal) it changes nothing and
:attr:`SliceRequest.problem` says why: nothing of a story depends on it, only how late its
frames start. Measured with ``python -m storyteller.benchmark.bench_frame_interval --viewer``
(``benchmark/results/2026-12-07-viewer-frame-interval.md``).
"""

from __future__ import annotations

import contextlib
import ctypes
import platform
import sys
from collections.abc import Iterator
from dataclasses import dataclass

SLICE_NS = 100_000
"""The slice asked for, nanoseconds (0.1 ms: the kernel's lower bound; its default here is 1.4 ms)."""
SYSCALLS = {"x86_64": (314, 315), "aarch64": (274, 275)}
"""``(sched_setattr, sched_getattr)`` system-call numbers by machine."""
SCHED_OTHER = 0
RESET_ON_FORK = 0x01
"""``SCHED_FLAG_RESET_ON_FORK``: threads and processes started meanwhile get the default slice."""


class SchedAttr(ctypes.Structure):
    """``struct sched_attr`` (``SCHED_ATTR_SIZE_VER1``, 56 bytes), see sched_setattr(2)."""

    _fields_ = [  # ctypes reads the layout from this class attribute
        ("size", ctypes.c_uint32), ("sched_policy", ctypes.c_uint32), ("sched_flags", ctypes.c_uint64),
        ("sched_nice", ctypes.c_int32), ("sched_priority", ctypes.c_uint32), ("sched_runtime", ctypes.c_uint64),
        ("sched_deadline", ctypes.c_uint64), ("sched_period", ctypes.c_uint64),
        ("sched_util_min", ctypes.c_uint32), ("sched_util_max", ctypes.c_uint32),
    ]  # fmt: skip


@dataclass(frozen=True)
class SliceRequest:
    """What became of a request: the slice the thread had before and has now (nanoseconds, as
    the kernel reports them; 0 where it reports none), or why nothing was changed."""

    before_ns: int = 0
    now_ns: int = 0
    problem: str | None = None


def thread_slice_ns() -> int | None:
    """The calling thread's slice as the kernel reports it (nanoseconds), None where it cannot be read."""
    attr = _get()
    return None if isinstance(attr, str) else int(attr.sched_runtime)


def _syscall() -> tuple[ctypes.CDLL, int, int] | str:
    if not sys.platform.startswith("linux"):
        return f"not Linux ({sys.platform})"
    numbers = SYSCALLS.get(platform.machine())
    if numbers is None:
        return f"sched_setattr's number on {platform.machine()} is not known here"
    return ctypes.CDLL(None, use_errno=True), *numbers


def _get() -> SchedAttr | str:
    call = _syscall()
    if isinstance(call, str):
        return call
    libc, _, get = call
    attr = SchedAttr()
    if libc.syscall(get, 0, ctypes.byref(attr), ctypes.sizeof(SchedAttr), 0) != 0:
        return f"sched_getattr failed (errno {ctypes.get_errno()})"
    return attr


def _set(attr: SchedAttr, runtime_ns: int, flags: int) -> str | None:
    call = _syscall()
    if isinstance(call, str):
        return call
    libc, put, _ = call
    wanted = SchedAttr(size=ctypes.sizeof(SchedAttr), sched_policy=attr.sched_policy, sched_flags=flags,
                       sched_nice=attr.sched_nice, sched_runtime=runtime_ns)
    if libc.syscall(put, 0, ctypes.byref(wanted), 0) != 0:
        return f"sched_setattr refused (errno {ctypes.get_errno()})"
    return None


@contextlib.contextmanager
def short_slice(enabled: bool = True, slice_ns: int = SLICE_NS) -> Iterator[SliceRequest]:
    """Run the block with the calling thread's slice at ``slice_ns`` (when ``enabled`` and the
    kernel keeps it); the slice before is given back on exit."""
    if not enabled:
        yield SliceRequest(problem="not asked")
        return
    before = _get()
    if isinstance(before, str):
        yield SliceRequest(problem=before)
        return
    if before.sched_policy != SCHED_OTHER:
        yield SliceRequest(before_ns=before.sched_runtime, problem=f"scheduling policy {before.sched_policy}, not SCHED_OTHER")
        return
    refused = _set(before, slice_ns, RESET_ON_FORK)
    now = thread_slice_ns() or 0
    if refused is None and now != slice_ns:  # an older kernel accepts the field and ignores it
        refused = f"this kernel keeps no custom slice (it reports {now} ns)"
    try:
        yield SliceRequest(before_ns=before.sched_runtime, now_ns=now, problem=refused)
    finally:
        if now != before.sched_runtime:
            _set(before, before.sched_runtime, before.sched_flags & RESET_ON_FORK)

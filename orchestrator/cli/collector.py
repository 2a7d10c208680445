"""The cyclic garbage collector in a command's process: paused while the command imports its
modules, and told at exit that what is left need not be searched for cycles.

Why: a ``run`` or ``replay`` imports about 300,000 objects that live until the process ends
(langgraph, langchain-core, numba, matplotlib, pydantic models and their validators), and every
full collection walks all of them, about 0.13 s per 100,000 on this kind of machine. Measured on
a replay of a 60 s story: 0.8 s of collections during the run (most of them while importing)
and 0.8 s more at interpreter shutdown, of a 5 s CPU time.

What this changes, and what it does not:

- :func:`imports_paused` collects once (cheap before the command's imports: about 10 ms for the
  23,000 objects of the command line), disables the collector while its block imports modules,
  then freezes (:func:`gc.freeze`) every object alive at that point: later collections skip
  them. So no garbage is frozen; garbage cycles made after the freeze are collected as before;
  objects alive at the freeze (the modules, and whatever a test process held then) are never
  searched again, and one of them left in a cycle later stays until the process ends.
- :func:`skip_final_collection` freezes everything at the end of the command, so interpreter
  shutdown frees objects by reference count only and leaves cyclic garbage to the operating
  system. Files are closed by the code that opened them (the trace writer, the exports), never
  by the collector, so no written byte depends on it.

Nothing here changes what a command computes or writes; only when memory is searched.
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator


@contextlib.contextmanager
def imports_paused() -> Iterator[None]:
    """Collect, then no collection while the block runs (meant for imports); then freeze what is
    alive and restore the collector's previous state."""
    enabled = gc.isenabled()
    gc.collect()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


def skip_final_collection() -> None:
    """Freeze every object now alive: the collections of interpreter shutdown skip them. Call it
    once the command is done (its files written and closed)."""
    gc.freeze()


__all__ = ["imports_paused", "skip_final_collection"]

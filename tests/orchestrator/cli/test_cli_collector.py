"""The collector policy of a command process (``storyteller.orchestrator.cli.collector``): garbage made before
the imports is collected, not frozen; the collector is off inside the block and back as it was
after it; what is alive after the block is frozen."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Iterator

import pytest

from storyteller.orchestrator.cli.collector import imports_paused, skip_final_collection


class _Node:
    def __init__(self) -> None:
        self.me = self  # a reference cycle: only the cyclic collector frees it


@pytest.fixture(autouse=True)
def _thawed() -> Iterator[None]:
    enabled = gc.isenabled()
    yield
    gc.unfreeze()  # the test process goes on collecting as before
    if enabled:
        gc.enable()
    else:
        gc.disable()


def test_garbage_before_the_imports_is_collected_and_what_lives_is_frozen() -> None:
    gc.unfreeze()
    gc.enable()
    garbage = _Node()
    gone = weakref.ref(garbage)
    del garbage
    with imports_paused():
        assert not gc.isenabled()
        alive = _Node()
    assert gc.isenabled()
    assert gone() is None
    assert gc.get_freeze_count() > 0
    assert not any(o is alive for o in gc.get_objects())  # frozen objects are not tracked for collection
    del alive


@pytest.mark.slow
def test_a_paused_collector_stays_paused() -> None:
    gc.disable()
    with imports_paused():
        pass
    assert not gc.isenabled()


def test_skip_final_collection_freezes_everything() -> None:
    gc.unfreeze()
    kept = _Node()
    skip_final_collection()
    assert gc.get_freeze_count() > 0 and not any(o is kept for o in gc.get_objects())

"""The authors' reference data and the shared mocap clips as the tests see them.

Both are looked up once, at import, by ``storyteller.orchestrator.reference_data`` (``STORYTELLER_REFERENCE``
/ ``STORYTELLER_MOCAP``, else ``../shared/...``). The paths below always exist as values (the
folder, or where it was expected), so a test module may build paths from them at import time;
every test that reads them carries ``requires_reference`` / ``requires_mocap`` (or calls
``reference_or_skip()`` in a fixture) and is skipped with the one-line reason when the data is
absent, never errors.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from storyteller.orchestrator.reference_data import locate_mocap, locate_reference

_REFERENCE = locate_reference()
_MOCAP = locate_mocap()

REFERENCE: Path = _REFERENCE.path
SCENES = REFERENCE / "configs" / "scenes"
OFFICE = SCENES / "Office"
TEST_CASES = REFERENCE / "benchmark" / "test_cases"
MOCAP: Path = _MOCAP.path

requires_reference = pytest.mark.skipif(not _REFERENCE.found, reason=_REFERENCE.reason)
requires_mocap = pytest.mark.skipif(not _MOCAP.found, reason=_MOCAP.reason)


def reference_or_skip() -> Path:
    """The reference folder; skips the calling test (or fixture) with the reason when it is absent."""
    if not _REFERENCE.found:
        pytest.skip(_REFERENCE.reason)
    return REFERENCE

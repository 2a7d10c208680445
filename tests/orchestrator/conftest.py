"""Fixtures shared by the orchestrator's tests (the guards of tests/conftest.py apply here too)."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short finished ``storyteller run`` folder (``tests.support.finished_run``), made once for
    the session (a run is deterministic): tests read it, and one that changes a run works on a copy."""
    from tests.support.finished_run import make_finished_run

    return make_finished_run(tmp_path_factory.mktemp("finished"))

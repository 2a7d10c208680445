"""Fixtures shared by the viewer's tests."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from storyteller.orchestrator.viewer.server import ViewerApp


@pytest.fixture
def viewer(tmp_path: Path) -> Iterator[ViewerApp]:
    """A viewer of ``tmp_path / "run"`` on a free port, stopped after the test."""
    app = ViewerApp(tmp_path / "run", port=0)
    yield app
    app.stop()


@pytest.fixture
def shots(tmp_path: Path) -> Path:
    """Where a browser test saves its screenshots: ``$STORYTELLER_TEST_OUTPUT/viewer`` (CI keeps
    them), else the test's temporary folder."""
    folder = Path(os.environ.get("STORYTELLER_TEST_OUTPUT", tmp_path)) / "viewer"
    folder.mkdir(parents=True, exist_ok=True)
    return folder

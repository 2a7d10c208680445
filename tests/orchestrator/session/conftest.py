"""Fixtures shared by the session's tests of damaged and hostile run folders."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest


@pytest.fixture
def run_dir(finished_run: Path, tmp_path: Path) -> Path:
    """A copy of the module's finished run, for the test to damage."""
    return Path(shutil.copytree(finished_run, tmp_path / "run"))

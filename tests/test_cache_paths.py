"""The application's cache folders come from the environment at the edge (orchestrator), not from sim."""

from __future__ import annotations

from pathlib import Path

import pytest

from orchestrator.cache_paths import CACHE_ENV, cache_root, motion_cache_dir


def test_the_cache_folder_honours_the_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    assert cache_root() == tmp_path
    assert motion_cache_dir() == tmp_path / "motion"
    monkeypatch.delenv(CACHE_ENV)
    assert motion_cache_dir() == Path.home() / ".cache" / "storyteller" / "motion"
    assert not (tmp_path / "motion").exists()  # named, not created

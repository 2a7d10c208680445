"""The application's cache folders come from the environment at the edge (orchestrator), not from sim."""

from __future__ import annotations

from pathlib import Path

import pytest

from storyteller.orchestrator.cache_paths import CACHE_ENV, cache_root, description_cache_dir, motion_cache_dir


def test_the_cache_folder_honours_the_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    assert cache_root() == tmp_path
    assert motion_cache_dir() == tmp_path / "motion"
    monkeypatch.delenv(CACHE_ENV)
    assert motion_cache_dir() == Path.home() / ".cache" / "storyteller" / "motion"
    assert not (tmp_path / "motion").exists()  # named, not created


def test_every_cache_location_is_under_the_one_cache_root(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from storyteller.orchestrator.llm.model_weights import cache_dir
    from storyteller.orchestrator.planning.checkpoints import default_runs_db

    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    assert (motion_cache_dir(), cache_dir(), default_runs_db()) == (
        tmp_path / "motion", tmp_path / "models", tmp_path / "runs.sqlite",
    )
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv(CACHE_ENV, "~/cache")  # a home-relative setting means the same folder for all
    assert default_runs_db() == tmp_path / "home" / "cache" / "runs.sqlite"
    assert cache_dir() == tmp_path / "home" / "cache" / "models"
    assert description_cache_dir() == tmp_path / "home" / "cache" / "descriptions"

"""The one lookup of the authors' data and the mocap clips (orchestrator/reference_data.py), and
the skip the tests get from it when the data is absent."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from storyteller.orchestrator.reference_data import (
    DEFAULT_MOCAP,
    DEFAULT_REFERENCE,
    MOCAP_ENV,
    REFERENCE_ENV,
    REFERENCE_URL,
    ReferenceDataNotFound,
    locate_mocap,
    locate_reference,
)

ROOT = Path(__file__).resolve().parents[2]


def _beside(tmp_path: Path, default: Path) -> tuple[Path, Path]:
    """A checkout folder with the default data folder next to it (``<tmp>/shared/...``)."""
    checkout = tmp_path / "checkout"
    checkout.mkdir(parents=True)
    data = (checkout / default).resolve()
    data.mkdir(parents=True)
    return checkout, data


def test_the_variable_wins_over_the_default_folder(tmp_path: Path) -> None:
    checkout, _ = _beside(tmp_path, DEFAULT_REFERENCE)
    clone = tmp_path / "Event-Driven-Storytelling"
    clone.mkdir()
    found = locate_reference(env={REFERENCE_ENV: str(clone)}, bases=[checkout])
    assert found.found and found.path == clone.resolve() and found.reason == ""
    assert found.require() == clone.resolve()


def test_a_relative_variable_is_read_from_the_current_directory(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "data").mkdir()
    monkeypatch.chdir(tmp_path)
    assert locate_reference(env={REFERENCE_ENV: "data"}, bases=[]).path == (tmp_path / "data").resolve()


def test_unset_variable_finds_the_default_folder_beside_the_checkout(tmp_path: Path) -> None:
    checkout, data = _beside(tmp_path, DEFAULT_REFERENCE)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    found = locate_reference(env={}, bases=[elsewhere, checkout])  # first base lacks it, second has it
    assert found.found and found.path == data
    assert data == tmp_path / "shared" / "reference" / "event-driven-storytelling"
    assert locate_reference(env={REFERENCE_ENV: ""}, bases=[checkout]).path == data  # empty = unset


def test_the_first_base_that_has_the_folder_wins(tmp_path: Path) -> None:
    first, data_first = _beside(tmp_path / "a", DEFAULT_REFERENCE)
    second, _ = _beside(tmp_path / "b", DEFAULT_REFERENCE)
    assert locate_reference(env={}, bases=[first, second]).path == data_first


def test_absent_data_gives_a_one_line_reason_and_a_typed_error(tmp_path: Path) -> None:
    found = locate_reference(env={}, bases=[tmp_path])
    assert not found.found
    assert found.path == (tmp_path / DEFAULT_REFERENCE).resolve()  # where it was expected
    assert "\n" not in found.reason
    assert REFERENCE_ENV in found.reason and REFERENCE_URL in found.reason and "does not exist" in found.reason
    with pytest.raises(ReferenceDataNotFound, match=REFERENCE_ENV) as info:
        found.require()
    assert isinstance(info.value, FileNotFoundError)


def test_a_variable_naming_a_missing_folder_is_absent_with_no_fall_back(tmp_path: Path) -> None:
    checkout, _ = _beside(tmp_path, DEFAULT_REFERENCE)  # the default exists, but the setting is explicit
    found = locate_reference(env={REFERENCE_ENV: str(tmp_path / "nope")}, bases=[checkout])
    assert not found.found and found.path == tmp_path / "nope"
    assert f"{REFERENCE_ENV}={tmp_path / 'nope'} is not a folder" in found.reason
    file = tmp_path / "a_file"
    file.write_text("")
    assert not locate_reference(env={REFERENCE_ENV: str(file)}, bases=[checkout]).found


def test_mocap_has_its_own_variable_and_default(tmp_path: Path) -> None:
    checkout, data = _beside(tmp_path, DEFAULT_MOCAP)
    assert data == tmp_path / "shared" / "mocap"
    assert locate_mocap(env={}, bases=[checkout]).path == data
    assert locate_mocap(env={REFERENCE_ENV: str(tmp_path)}, bases=[checkout]).path == data  # not the reference's
    missing = locate_mocap(env={MOCAP_ENV: str(tmp_path / "nope")}, bases=[checkout])
    assert not missing.found and MOCAP_ENV in missing.reason


@pytest.mark.slow
def test_tests_needing_the_data_skip_with_the_reason_when_the_variable_is_wrong(tmp_path: Path) -> None:
    test = tmp_path / "test_needs_data.py"
    test.write_text(
        "from tests.support.reference import OFFICE, reference_or_skip, requires_reference\n\n"
        "@requires_reference\ndef test_marked():\n    assert OFFICE.is_dir()\n\n"
        "def test_called():\n    assert (reference_or_skip() / 'configs').is_dir()\n"
    )
    run = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider", "-c", str(ROOT / "pyproject.toml"), str(test)],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
        env={**os.environ, REFERENCE_ENV: str(tmp_path / "missing")},
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "2 skipped" in run.stdout
    assert run.stdout.count(f"{REFERENCE_ENV}={tmp_path / 'missing'} is not a folder") == 2

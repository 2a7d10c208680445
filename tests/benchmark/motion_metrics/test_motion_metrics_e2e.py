"""``python -m storyteller.benchmark.motion_metrics`` end to end on a tiny scripted run folder (no LLM)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from storyteller.benchmark.motion_metrics.__main__ import main
from tests.support.finished_run import make_finished_run


@pytest.mark.slow
def test_the_command_measures_a_scripted_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = make_finished_run(tmp_path, seconds=6, max_events=2)
    out = tmp_path / "report"
    assert main([str(run), "--out", str(out), "--crowd", "0", "--no-real", "--partners", "2"]) == 0
    printed = capsys.readouterr().out
    assert "Feet, furniture and bodies" in printed and "Interactions" in printed
    partners = printed.split("Partners (2 pairs", 1)[1].splitlines()
    assert partners[2].split()[:3] == ["chat", "1", "1"] and partners[3].split()[:3] == ["handshake", "1", "1"]
    figures = json.loads((out / "metrics.json").read_text(encoding="utf-8"))
    row = figures[run.name]
    assert row["characters"] == 2 and row["frames"] == 2 * 180
    assert 0.0 <= row["skating_ratio"] <= 1.0
    assert row["overlap_checked_frames"] == 180
    assert "## Interactions" in (out / "report.md").read_text(encoding="utf-8")
    strips = sorted(p.name for p in (out / "strips").glob("*.png"))
    assert "strip_walk.png" in strips


def test_a_folder_that_is_not_a_run_is_one_error_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "empty").mkdir()
    assert main([str(tmp_path / "empty"), "--out", str(tmp_path / "o"), "--crowd", "0", "--no-real", "--partners", "0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1

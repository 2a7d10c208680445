"""``python -m storyteller.benchmark.motion_metrics --scripted-story RUN_DIR``: the scripted home story is
built by the benchmark itself (a local scripted server, no LLM) and measured in one command."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from storyteller.benchmark.motion_metrics.__main__ import main
from storyteller.benchmark.motion_metrics.scripted_story import ScriptedPlanner, StoryBuildError, build_story


def _request(free: str) -> dict[str, object]:
    return {"messages": [{"role": "system", "content": "plan"}, {"role": "user", "content": f"Free characters: {free}"}]}


def test_the_planner_cycles_each_free_characters_tasks() -> None:
    planner = ScriptedPlanner()
    first = planner(_request("Max, Zoe"))
    assert 'get_character("Max")' in first and 'set_target_action("use_toaster")' in first
    assert 'set_target_action("watch_tv")' in planner(_request("Max"))
    assert 'get_area_to_sit_on("armchair_1")' not in planner(_request("Zoe"))  # Zoe starts at her first task
    for _ in range(3):
        planner(_request("Max"))
    assert 'set_target_action("use_toaster")' in planner(_request("Max"))  # five tasks, then again
    with pytest.raises(ValueError):
        planner({"messages": [{"role": "user", "content": "no roster here"}]})


@pytest.mark.slow
def test_the_command_builds_the_story_and_measures_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run, out = tmp_path / "scripted_home", tmp_path / "report"
    argv = ["--scripted-story", str(run), "--story-seconds", "10", "--story-names", "Zoe,Max", "--out", str(out),
            "--crowd", "0", "--no-real", "--no-strips"]  # fmt: skip
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "scripted_home" in printed and "Interactions" in printed
    assert (run / "story.json").is_file() and (run / "trace.jsonl").is_file()
    row = json.loads((out / "metrics.json").read_text(encoding="utf-8"))["scripted_home"]
    assert row["characters"] == 2 and row["frames"] == 2 * 300
    assert "## Interactions" in (out / "report.md").read_text(encoding="utf-8")
    # the folder now holds a run: building into it again is a user error, one line
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "already exists" in err


def test_bad_story_arguments_are_refused_before_anything_runs(tmp_path: Path) -> None:
    with pytest.raises(StoryBuildError, match="distinct names"):
        build_story(tmp_path / "a", names=["Bob"])
    with pytest.raises(StoryBuildError, match="positive"):
        build_story(tmp_path / "b", seconds=float("nan"))
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()

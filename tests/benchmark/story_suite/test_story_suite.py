"""The story suite's scenarios load, and its evaluator judges hand-written story logs right.

Every story log here is written by hand in the shape ``storyteller run`` writes
(``storyteller.orchestrator.cli.run.story_json``), so each test says which expectation must pass or fail
and why; none needs a model.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

from storyteller.benchmark.story_suite.__main__ import main
from storyteller.benchmark.story_suite.evaluate import ScenarioScore, StoryLogError, score_run, score_story
from storyteller.benchmark.story_suite.runner import RunOptions, record_scores, run_args, run_scenario
from storyteller.benchmark.story_suite.scenario import (
    SCENARIO_DIR,
    Scenario,
    ScenarioError,
    load_scenario,
    load_scenarios,
)
from storyteller.sim.scene.bundled import resolve_scene

HOME = resolve_scene("home")
COFFEE = load_scenario(SCENARIO_DIR / "home_coffee_then_couch.toml")
INSTRUCTION = COFFEE.instruction

AT_COFFEE_MAKER = [1.3, 1.0]  # 0.4 m in front of coffee_maker_1, clear of cabinet_1
ON_COUCH = [4.0, 5.5]
INSIDE_CABINET = [1.3, 0.3]  # close to coffee_maker_1, but inside cabinet_1's footprint


def plan(character: str, action: str, position: list[float], seat: str | None = None) -> dict[str, Any]:
    return {"character": character, "action": action, "area": "", "position": position,
            "facing": [0.0, 1.0], "seat": seat}  # fmt: skip


def story(*steps: tuple[int, list[dict[str, Any]]], failed: dict[int, str] | None = None,
          instruction: str = INSTRUCTION) -> dict[str, Any]:  # fmt: skip
    """A story log of events applied at the given frames, one step each, in order."""
    failed = failed or {}
    step_entries, events = [], []
    for i, (frame, plans) in enumerate(steps):
        chars = [p["character"] for p in plans]
        step_entries.append({"index": i, "applied_frame": frame, "kind": "event", "characters": chars,
                             "activity": "something", "plans": plans})  # fmt: skip
        events.append({"event_id": f"e{i}", "index": i, "characters": chars, "activity": "something",
                       "requested_frame": frame, "applied_frame": frame,
                       "state": "failed" if i in failed else "ongoing", "finished_frame": None,
                       "failure": failed.get(i)})  # fmt: skip
    return {"scene": "home", "characters": ["Ava", "Ben"], "instruction": instruction, "fps": 30,
            "frames": 1200, "steps": step_entries, "events": events}  # fmt: skip


def verdicts(log: dict[str, Any]) -> dict[str, bool]:
    return {v.id: v.met for v in score_story(COFFEE, HOME, log).verdicts}


def test_a_story_that_follows_the_instruction_meets_every_expectation() -> None:
    log = story(
        (0, [plan("Ava", "use_coffee_maker", AT_COFFEE_MAKER), plan("Ben", "read_book", [3.7, 6.2])]),
        (300, [plan("Ava", "drink", ON_COUCH, seat="couch_1")]),
    )
    score = score_story(COFFEE, HOME, log)
    assert (score.met, score.total, score.share) == (4, 4, 1.0)
    assert all(v.reason for v in score.verdicts)


def test_wrong_action_label_fails_only_that_expectation_and_the_order_that_needs_it() -> None:
    log = story(
        (0, [plan("Ava", "use_laptop", AT_COFFEE_MAKER), plan("Ben", "read_book", [3.7, 6.2])]),
        (300, [plan("Ava", "drink", ON_COUCH, seat="couch_1")]),
    )
    assert verdicts(log) == {"brew": False, "drink": True, "brew<drink": False, "Ben-busy": True}
    reason = score_story(COFFEE, HOME, log).verdicts[0].reason
    assert "'use_laptop' is not 'use_coffee_maker'" in reason


def test_wrong_seat_fails_even_when_the_point_is_on_the_couch() -> None:
    log = story(
        (0, [plan("Ava", "use_coffee_maker", AT_COFFEE_MAKER)]),
        (300, [plan("Ava", "drink", ON_COUCH, seat="armchair_1")]),
        (300, [plan("Ava", "drink", ON_COUCH, seat=None)]),
    )
    assert verdicts(log)["drink"] is False


def test_a_position_inside_furniture_fails_as_a_collision() -> None:
    log = story((0, [plan("Ava", "use_coffee_maker", INSIDE_CABINET)]))
    score = score_story(COFFEE, HOME, log)
    assert score.verdicts[0].met is False
    assert "collides with cabinet_1" in score.verdicts[0].reason


def test_a_position_too_far_from_the_object_fails_with_the_distance() -> None:
    log = story((0, [plan("Ava", "use_coffee_maker", [4.0, 3.0])]))
    reason = score_story(COFFEE, HOME, log).verdicts[0].reason
    assert "not 'close to coffee_maker_1' (off by" in reason


def test_parts_in_the_wrong_order_or_at_the_same_frame_fail_the_order() -> None:
    reversed_ = story(
        (0, [plan("Ava", "drink", ON_COUCH, seat="couch_1")]),
        (300, [plan("Ava", "use_coffee_maker", AT_COFFEE_MAKER)]),
    )
    assert verdicts(reversed_)["brew<drink"] is False
    same_frame = story((0, [plan("Ava", "use_coffee_maker", AT_COFFEE_MAKER)]),
                       (0, [plan("Ava", "drink", ON_COUCH, seat="couch_1")]))  # fmt: skip
    assert verdicts(same_frame)["brew<drink"] is False
    again = story((0, [plan("Ava", "drink", ON_COUCH, seat="couch_1")]),
                  (100, [plan("Ava", "use_coffee_maker", AT_COFFEE_MAKER)]),
                  (400, [plan("Ava", "drink", ON_COUCH, seat="couch_1")]))  # fmt: skip
    assert verdicts(again)["brew<drink"] is True


def test_a_character_left_out_or_only_idle_fails_not_idle() -> None:
    left_out = story((0, [plan("Ava", "use_coffee_maker", AT_COFFEE_MAKER)]))
    assert verdicts(left_out)["Ben-busy"] is False
    idle = story((0, [plan("Ava", "use_coffee_maker", AT_COFFEE_MAKER), plan("Ben", "idle", [6.0, 4.0])]))
    score = score_story(COFFEE, HOME, idle)
    assert score.verdicts[-1].met is False
    assert "idles the whole run" in score.verdicts[-1].reason


def test_an_event_that_failed_in_the_simulation_does_not_count() -> None:
    log = story((0, [plan("Ava", "use_coffee_maker", AT_COFFEE_MAKER)]), failed={0: "no path to the target"})
    score = score_story(COFFEE, HOME, log)
    assert score.verdicts[0].met is False
    assert "failed in the simulation: no path to the target" in score.verdicts[0].reason


def test_waits_and_planning_failures_contribute_no_plans() -> None:
    log = story()
    log["steps"] = [{"index": 0, "applied_frame": 0, "kind": "wait"},
                    {"index": 1, "applied_frame": 90, "kind": "failed", "node": "parser", "feedback": "x"}]  # fmt: skip
    score = score_story(COFFEE, HOME, log)
    assert score.met == 0
    assert score.verdicts[0].reason == "Ava is in no event"


def test_a_log_of_another_story_or_a_broken_log_is_refused(tmp_path: Path) -> None:
    with pytest.raises(StoryLogError, match="not of scenario home_coffee_then_couch"):
        score_story(COFFEE, HOME, story(instruction="Ava dances."))
    broken = story((0, [plan("Ava", "drink", ON_COUCH)]))
    del broken["steps"][0]["plans"][0]["position"]
    with pytest.raises(StoryLogError, match="not a story log"):
        score_story(COFFEE, HOME, broken)
    with pytest.raises(StoryLogError, match="cannot read the story log"):
        score_run(COFFEE, tmp_path)


def test_the_bundled_suite_covers_the_brief() -> None:
    scenarios = load_scenarios()
    assert len(scenarios) >= 24
    assert {s.scene for s in scenarios} == {"home", "office", "restaurant"}
    assert {s.characters for s in scenarios} >= {2, 3, 4, 5, 6}
    assert sum(any(e.kind == "order" for e in s.expect) for s in scenarios) >= 8  # "then" sequences
    assert len({s.instruction for s in scenarios}) == len(scenarios)


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    return path


HEAD = 'scene = "home"\ncharacters = 2\ninstruction = "x"\nduration = 10\nmax_events = 2\n'


@pytest.mark.parametrize(("body", "message"), [
    ('[[expect]]\nkind = "does"\nid = "a"\ncharacter = "Cleo"\naction = "drink"\n', "'Cleo' is not one of Ava, Ben"),
    ('[[expect]]\nkind = "does"\nid = "a"\ncharacter = "Ava"\naction = "fly"\n', "fly not an action label of home"),
    ('[[expect]]\nkind = "does"\nid = "a"\ncharacter = "Ava"\nwhere = "close to sofa_9"\n', "unknown object 'sofa_9'"),
    ('[[expect]]\nkind = "does"\nid = "a"\ncharacter = "Ava"\naction = "drink ||"\n', "expect[0].action"),
    ('[[expect]]\nkind = "does"\nid = "a"\ncharacter = "Ava"\n', "needs an action, a where, or both"),
    ('[[expect]]\nkind = "order"\nfirst = "a"\nthen = "b"\n', "no 'does' expectation with id 'a'"),
    ('[[expect]]\nkind = "not_idle"\ncharacter = "Ava"\nextra = 1\n', "extra"),
])  # fmt: skip
def test_a_bad_scenario_file_names_the_file_and_the_field(tmp_path: Path, body: str, message: str) -> None:
    with pytest.raises(ScenarioError, match=r"bad\.toml") as info:
        load_scenario(_write(tmp_path, HEAD + body))
    assert message in str(info.value)


def test_score_command_writes_the_table_results_and_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "home_coffee_then_couch"
    run.mkdir()
    log = story((0, [plan("Ava", "use_coffee_maker", AT_COFFEE_MAKER)]))
    (run / "story.json").write_text(json.dumps(log), encoding="utf-8")
    assert main(["score", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^home_coffee_then_couch +1/4 +0\.25$", out, re.M)
    assert re.search(r"^total +1/4 +0\.25$", out, re.M)
    results = json.loads((tmp_path / "results.json").read_text())
    assert (results["met"], results["total"]) == (1, 4)
    assert [v["met"] for v in results["scenarios"][0]["verdicts"]] == [True, False, False, False]
    assert "NOT met `drink`" in (tmp_path / "report.md").read_text()


def test_score_command_refuses_a_folder_without_runs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["score", str(tmp_path)]) == 2
    assert "no scenario run folder" in capsys.readouterr().err


def test_runner_passes_the_scenario_to_storyteller_run_and_scores_a_missing_trace_as_failed(tmp_path: Path) -> None:
    args = run_args(COFFEE, RunOptions(out=tmp_path, replay=tmp_path / "traces"))
    assert args[-4:] == ["--out", str(tmp_path / COFFEE.name), "--replay", str(tmp_path / "traces" / f"{COFFEE.name}.jsonl")]
    assert args[args.index("--pace"):args.index("--pace") + 2] == ["--pace", "lockstep"]
    assert args[args.index("-i"):args.index("-i") + 2] == ["-i", INSTRUCTION]
    score, _ = run_scenario(COFFEE, RunOptions(out=tmp_path, replay=tmp_path / "traces"))
    assert score.met == 0 and all("no trace" in v.reason for v in score.verdicts)


def test_scenario_names_come_from_the_file(tmp_path: Path) -> None:
    path = tmp_path / "mine.toml"
    path.write_text(HEAD + '[[expect]]\nkind = "not_idle"\ncharacter = "Ben"\n', encoding="utf-8")
    scenario = load_scenario(path)
    assert isinstance(scenario, Scenario)
    assert scenario.name == "mine" and scenario.names == ("Ava", "Ben")


def test_recorded_scores_merge_per_scenario(tmp_path: Path) -> None:
    one = score_story(COFFEE, HOME, story((0, [plan("Ava", "use_coffee_maker", AT_COFFEE_MAKER)])))
    record_scores(tmp_path, [one], "local/m")
    other = ScenarioScore("other", (), steps=0, events=0)
    record_scores(tmp_path, [other], "local/m")
    stored = json.loads((tmp_path / "scores.json").read_text())
    assert list(stored["scenarios"]) == ["home_coffee_then_couch", "other"]
    assert stored["scenarios"]["home_coffee_then_couch"]["met"] == 1


def test_another_seat_is_named_with_its_distance() -> None:
    log = story((0, [plan("Ava", "drink", [2.4, 6.7], seat="armchair_1")]))
    reason = score_story(COFFEE, HOME, log).verdicts[1].reason
    assert reason == "Ava: step 0: drink at seat armchair_1: not 'sit on couch_1' (off by 0.83 m)"

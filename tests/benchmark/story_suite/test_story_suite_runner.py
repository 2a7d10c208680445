"""The story suite's runner drives ``storyteller run`` for real: a recorded run is scored from
its story log, and replaying its trace (the model server stopped) scores the same.

The model is a scripted OpenAI-compatible server on 127.0.0.1 (``tests/fake_openai_server.py``)
that the ``storyteller run`` subprocess reaches through ``STORYTELLER_CONFIG``; the narrator
sends Ava to the coffee maker and the event parser writes the matching program.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from storyteller.benchmark.story_suite.runner import RunOptions, record_scores, run_scenario
from storyteller.benchmark.story_suite.scenario import Does, NotIdle, Scenario
from storyteller.benchmark.support.fake_openai_server import FakeOpenAI

NODES = ("describer", "narrator", "event_parser", "planner")
NARRATION = json.dumps({"reasoning": "r", "event": {"characters": ["Ava"], "activity": "make coffee with coffee_maker_1"}})
COFFEE = (
    '```python\ndef parse_event():\n    a = get_character("Ava")\n'
    '    a.set_position(get_area_to_interact_with("coffee_maker_1"))\n'
    '    a.set_orientation("coffee_maker_1")\n    a.set_target_action("use_coffee_maker")\n```'
)
SCENARIO = Scenario(
    name="fake_coffee", scene="home", characters=2, instruction="Ava makes coffee.", duration=3, max_events=1,
    expect=(Does(id="brew", character="Ava", action="use_coffee_maker", where="close to coffee_maker_1"),
            NotIdle(kind="not_idle", character="Ben")),
)  # fmt: skip


@pytest.fixture
def fake(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[FakeOpenAI]:
    monkeypatch.setenv("FAKE_PROVIDER_KEY", "sk-test-123")
    monkeypatch.setenv("STORYTELLER_CACHE_DIR", str(tmp_path / "cache"))
    for var in ("STORYTELLER_MODEL", *(f"STORYTELLER_{n.upper()}_MODEL" for n in NODES)):
        monkeypatch.delenv(var, raising=False)
    with FakeOpenAI(default='{"error": "no script"}') as server:
        lines = ["[llm]", f'api_base = "{server.base}"', 'api_key_env = "FAKE_PROVIDER_KEY"', "timeout_s = 10.0",
                 "[llm.retry]", "max_attempts = 1"]  # fmt: skip
        for node in NODES:
            lines += [f"[nodes.{node}]", f'model = "openai/fake-{node}"']
        (tmp_path / "fake.toml").write_text("\n".join(lines) + "\n", encoding="utf-8")
        monkeypatch.setenv("STORYTELLER_CONFIG", str(tmp_path / "fake.toml"))
        server.script.update({"fake-narrator": [NARRATION], "fake-event_parser": [COFFEE]})
        yield server


@pytest.mark.slow
def test_a_recorded_run_is_scored_and_its_replay_scores_the_same(fake: FakeOpenAI, tmp_path: Path) -> None:
    traces = tmp_path / "traces"
    live, _ = run_scenario(SCENARIO, RunOptions(out=tmp_path / "live", record=traces))
    assert (traces / "fake_coffee.jsonl").is_file()
    assert [(v.id, v.met) for v in live.verdicts] == [("brew", True), ("Ben-busy", False)], live.verdicts
    assert live.verdicts[0].reason.startswith("Ava step 0: use_coffee_maker at [")
    assert any(r["model"] == "fake-event_parser" for r in fake.requests)
    record_scores(traces, [live], "fake")
    fake.stop()
    replayed, _ = run_scenario(SCENARIO, RunOptions(out=tmp_path / "again", replay=traces))
    assert replayed.to_json() == json.loads((traces / "scores.json").read_text())["scenarios"]["fake_coffee"]
    story = (tmp_path / "again" / "fake_coffee" / "story.json").read_bytes()
    assert story == (tmp_path / "live" / "fake_coffee" / "story.json").read_bytes()


@pytest.mark.slow
def test_a_run_that_fails_scores_every_expectation_unmet_with_the_error(fake: FakeOpenAI, tmp_path: Path) -> None:
    (tmp_path / "traces").mkdir()
    (tmp_path / "traces" / "fake_coffee.jsonl").write_text("not a trace\n", encoding="utf-8")
    score, _ = run_scenario(SCENARIO, RunOptions(out=tmp_path / "out", replay=tmp_path / "traces"))
    assert score.met == 0
    assert all(v.reason.startswith("run failed: error: ") for v in score.verdicts), score.verdicts


@pytest.mark.slow
def test_run_log_replaces_a_link_planted_in_the_run_folder(fake: FakeOpenAI, tmp_path: Path) -> None:
    (tmp_path / "traces").mkdir()
    (tmp_path / "traces" / "fake_coffee.jsonl").write_text("not a trace\n", encoding="utf-8")
    outside = tmp_path / "outside.txt"
    outside.write_text("keep me", encoding="utf-8")
    (tmp_path / "out" / "fake_coffee").mkdir(parents=True)
    (tmp_path / "out" / "fake_coffee" / "run.log").symlink_to(outside)
    run_scenario(SCENARIO, RunOptions(out=tmp_path / "out", replay=tmp_path / "traces"))
    log = tmp_path / "out" / "fake_coffee" / "run.log"
    assert outside.read_text(encoding="utf-8") == "keep me"
    assert not log.is_symlink() and "error: " in log.read_text(encoding="utf-8")

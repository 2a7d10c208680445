"""The story suite's recorded runs replay to their recorded scores, through the command.

``traces/story_suite/<scenario>.jsonl`` is one full ``storyteller run --pace lockstep`` of the
scenario with the embedded model, recorded by ``python -m storyteller.benchmark.story_suite run --record
traces/story_suite``; ``traces/story_suite/scores.json`` holds the score that live run got.
Replaying the trace serves every LLM call and applied frame from it (no model loaded), so the
story log, hence every verdict and its reason (which quotes the sampled positions), must come
out the same. A scenario file edited after its recording fails here until it is re-recorded.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from storyteller.benchmark.story_suite.__main__ import main
from storyteller.benchmark.story_suite.scenario import SCENARIO_DIR, load_scenario

TRACES = Path(__file__).resolve().parents[3] / "traces" / "story_suite"
RECORDED = json.loads((TRACES / "scores.json").read_text(encoding="utf-8"))["scenarios"]
REPLAYED_IN_CI = tuple(n for n in ("home_coffee_then_couch", "office_water_then_chat", "restaurant_bar_drink") if n in RECORDED)
"""One recorded scenario per scene (the README's story among them): a replay is a full run of
the simulation and its exports, tens of seconds on a loaded machine, so CI replays these and the
bookkeeping test below covers every recorded one."""


def test_every_trace_has_its_recorded_score_for_the_current_scenario_file() -> None:
    traces = {p.stem for p in TRACES.glob("*.jsonl")}
    assert traces == set(RECORDED)
    assert set(REPLAYED_IN_CI) <= traces
    for name, recorded in RECORDED.items():
        scenario = load_scenario(SCENARIO_DIR / f"{name}.toml")
        assert [v["id"] for v in recorded["verdicts"]] == [e.id for e in scenario.expect], name
        assert recorded["met"] == sum(v["met"] for v in recorded["verdicts"])


def test_trace_files_stay_small() -> None:
    sizes = {p.name: p.stat().st_size for p in TRACES.glob("*.jsonl")}
    assert max(sizes.values()) < 400_000, sizes


@pytest.mark.parametrize("name", REPLAYED_IN_CI)
@pytest.mark.slow
def test_replaying_a_recorded_run_gives_the_recorded_score(name: str, tmp_path: Path) -> None:
    assert main(["run", "--scenarios", name, "--replay", str(TRACES), "--out", str(tmp_path)]) == 0
    (replayed,) = json.loads((tmp_path / "results.json").read_text(encoding="utf-8"))["scenarios"]
    assert replayed == RECORDED[name]

"""``storyteller plan`` from the committed golden traces (recorded with the embedded 0.5B
model), with no model loaded; plus one test that runs the real embedded model.

The golden files (``traces/<name>.jsonl`` + the command's stdout ``traces/<name>.out``) were
recorded with ``storyteller plan <ARGS> --record traces/<name>.jsonl``.
"""

from __future__ import annotations

import json
import shutil
from importlib import resources
from pathlib import Path

import pytest
from typer.testing import CliRunner, Result

from storyteller.orchestrator.cli.app import app

REPO = Path(__file__).resolve().parents[3]
TRACES = REPO / "traces"
GOLDEN = {
    "plan_home_2events": [
        "plan", "home", "-n", "2", "-k", "2", "--seed", "0", "--busy-events", "1",
        "-i", "Ben watches TV sitting on the couch.",
    ],
}


def run_cli(args: list[str], tmp_path: Path) -> Result:
    return CliRunner().invoke(app, [*args, "--runs-db", str(tmp_path / "runs.sqlite")], catch_exceptions=False)


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_replay_reproduces_the_recorded_output_byte_for_byte(
    name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from storyteller.orchestrator.llm import local_model

    loads: list[str] = []

    def no_load(spec: object) -> object:  # another test may have loaded the model already
        loads.append(str(spec))
        raise AssertionError("replay tried to load the embedded model")

    monkeypatch.setattr(local_model, "get_llama", no_load)
    result = run_cli([*GOLDEN[name], "--replay", str(TRACES / f"{name}.jsonl")], tmp_path)
    assert result.exit_code == 0, result.stderr
    assert result.stdout == (TRACES / f"{name}.out").read_text(encoding="utf-8")
    assert loads == []  # no model was loaded


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_replay_json_lists_every_event_with_plans(name: str, tmp_path: Path) -> None:
    result = run_cli([*GOLDEN[name], "--replay", str(TRACES / f"{name}.jsonl"), "--json"], tmp_path)
    assert result.exit_code == 0, result.stderr
    payload = json.loads(result.stdout)
    k = int(GOLDEN[name][GOLDEN[name].index("-k") + 1])
    assert len(payload["events"]) == k
    for event in payload["events"]:
        if event["kind"] == "event":
            assert {p["character"] for p in event["plans"]} == set(event["characters"])
            for p in event["plans"]:
                assert len(p["position"]) == 2 and len(p["facing"]) == 2 and p["action"]


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_golden_trace_holds_the_parsed_output_of_every_attempt(name: str) -> None:
    """Every attempt has a parsed record: accepted output (parser: plans per character) or the
    typed error. ``plan`` runs no simulation: sim_frame is null and nothing is "applied"."""
    from storyteller.orchestrator.llm.traces import read_trace

    contents = read_trace(TRACES / f"{name}.jsonl")
    attempts = list(contents.attempts())
    parsed = contents.parsed_by_seq()
    assert sorted(parsed) == [a.seq for a in attempts]
    for a in attempts:
        (p,) = parsed[a.seq]
        assert p.node == a.node and a.request.sim_frame is None
        if p.ok and a.node == "event_parser":
            for plan in p.parsed_output["plans"]:
                assert {"character", "action", "area", "position", "facing"} <= set(plan)
        elif not p.ok:
            assert p.error_type and p.error_message
    assert not any(r.kind == "applied" for r in contents.records)


def test_one_edited_character_in_a_prompt_fails_the_replay_naming_the_node(tmp_path: Path) -> None:
    prompts = tmp_path / "prompts"
    shutil.copytree(Path(str(resources.files("storyteller.prompts"))), prompts)
    path = prompts / "narrator" / "system.md"
    text = path.read_text(encoding="utf-8")
    path.write_text(text.replace("free characters", "free characterz", 1), encoding="utf-8")
    name = "plan_home_2events"
    result = run_cli([*GOLDEN[name], "--replay", str(TRACES / f"{name}.jsonl"), "--prompts", str(prompts)], tmp_path)
    assert result.exit_code == 1
    err = result.stderr
    assert "replay miss for node narrator" in err
    assert "characterz" in err and "characters" in err  # the diff shows both versions


def test_replay_with_a_different_instruction_fails(tmp_path: Path) -> None:
    name = "plan_home_2events"
    args = [*GOLDEN[name][:-1], "Ben dances.", "--replay", str(TRACES / f"{name}.jsonl")]
    result = run_cli(args, tmp_path)
    assert result.exit_code == 1 and "replay miss for node narrator" in result.stderr


def test_replay_of_another_planners_trace_is_one_line_exit_2(tmp_path: Path) -> None:
    name = "plan_home_2events"  # recorded with the narrator and the event parser
    result = run_cli([*GOLDEN[name], "--planner", "unified", "--replay", str(TRACES / f"{name}.jsonl")], tmp_path)
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "recorded with another planner" in lines[0] and "--planner unified" in lines[0]
    assert result.stdout == ""


def test_bad_arguments_exit_2(tmp_path: Path) -> None:
    result = run_cli(["plan", "no_such_scene", "-i", "x"], tmp_path)
    assert result.exit_code == 2 and "not a bundled scene" in result.stderr
    result = run_cli(["plan", "home", "--record", "a.jsonl", "--replay", "b.jsonl"], tmp_path)
    assert result.exit_code == 2


GENEROUS_CONFIG = "[llm]\ntimeout_s = 1800.0\n\n[llm.retry]\nmax_attempts = 1\n"
"""Per-attempt timeout for the real-model test: generous, so a loaded machine (other jobs on
the 2 cores) slows the test down instead of failing it; one attempt per call."""


@pytest.mark.embedded_model
async def test_embedded_model_narrator_and_parser_end_to_end(tmp_path: Path) -> None:
    """The real path through the planning graph: litellm -> local provider -> llama.cpp, one
    narrator call and one event-parser call. The narrator must name the free character with
    an activity; the parser may fail, but only as a typed PlanningFailure from checking its
    program (not a timeout, not a crash)."""
    from langgraph.checkpoint.memory import InMemorySaver

    from storyteller.agents.event_parser import PARSER_RETRY_INSTRUCTION, scene_action_labels
    from storyteller.agents.messages import ParsedEvent, PlanningFailure, SceneDescription
    from storyteller.agents.prompt_templates import PromptLibrary
    from storyteller.orchestrator.llm.config import load_config
    from storyteller.orchestrator.llm.replay import build_llm_port
    from storyteller.orchestrator.llm.traces import read_trace
    from storyteller.orchestrator.planning.checkpoints import StoryLog
    from storyteller.orchestrator.planning.graph import compile_planning_graph, recursion_limit
    from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState
    from storyteller.orchestrator.session.roster import RosterWorld, initial_roster
    from storyteller.sim.scene.bundled import resolve_scene

    config_path = tmp_path / "generous.toml"
    config_path.write_text(GENEROUS_CONFIG, encoding="utf-8")
    config = load_config(config_path, env={})
    assert config.node("event_parser").timeout_s == 1800.0
    scene = resolve_scene("home")
    trace_path = tmp_path / "trace.jsonl"
    port = build_llm_port(config, record=trace_path)
    story = StoryLog(":memory:", "e2e")
    description = "- kitchen (make coffee): cabinet_1 (with coffee_maker_1 on it), fridge_1"
    deps = PlanningDeps(port=port, scene=scene, world=RosterWorld(), story=story,
                        action_labels=scene_action_labels(scene), tags=("OA",), seed=0, max_retries=0)
    start = PlanningState(
        instruction="Ava makes coffee.", events_target=1, roster=initial_roster(scene, 1, seed=0),
        description=SceneDescription(scene="home", text=description),  # no describer call
    )
    graph = compile_planning_graph(InMemorySaver())
    try:
        await graph.ainvoke(start.model_dump(), context=deps, durability="sync", config={
            "configurable": {"thread_id": "e2e"}, "recursion_limit": recursion_limit(1, 0)})
    finally:
        port.close()
    contents = read_trace(trace_path)
    attempts = list(contents.attempts())
    assert [a.node for a in attempts] == ["narrator", "event_parser"], [(a.node, a.error_type) for a in attempts]
    assert all(a.ok and a.final for a in attempts), [(a.error_type, a.error_message) for a in attempts]
    # the narrator produced a valid event: the free character, doing something
    (narrated,) = contents.parsed_by_seq()[attempts[0].seq]
    assert narrated.ok, narrated.error_message
    event = narrated.parsed_output["event"]
    assert event["characters"] == ["Ava"] and event["activity"].strip()
    ((index, outcome),) = story.outcomes()
    assert index == 0
    if isinstance(outcome, ParsedEvent):
        assert outcome.event.characters == ("Ava",) and outcome.plans[0].character == "Ava"
        assert scene.bounds_min[0] <= outcome.plans[0].position[0] <= scene.bounds_max[0]
    else:  # a weak model may write a program that fails: typed feedback from the check, not an outage
        assert isinstance(outcome, PlanningFailure), outcome
        assert outcome.node == "event_parser"
        assert PromptLibrary().render_text(PARSER_RETRY_INSTRUCTION) in outcome.feedback
        (checked,) = contents.parsed_by_seq()[attempts[1].seq]
        assert not checked.ok and checked.error_type

"""``storyteller plan/run --planner ... --description ...``: the paper's ablations from the CLI.

Each node's model is an ``openai/fake-<node>`` model served by a scripted OpenAI-compatible
server on 127.0.0.1 (``benchmark/support/fake_openai_server.py``; the real litellm client, config, trace
recording and replay are used); a recorded ablation trace is then replayed through the CLI with
the server stopped.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from storyteller.benchmark.support.fake_openai_server import Action, FakeOpenAI
from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.llm.traces import read_trace
from storyteller.orchestrator.session.roster import initial_roster
from storyteller.sim.scene.bundled import resolve_scene
from storyteller.tools.position_sampling import FloorMap

SCENE = resolve_scene("home")
NODES = ("describer", "narrator", "event_parser", "planner")


@pytest.fixture
def fake(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[FakeOpenAI]:
    monkeypatch.setenv("FAKE_PROVIDER_KEY", "sk-test-123")
    monkeypatch.setenv("STORYTELLER_CACHE_DIR", str(tmp_path / "cache"))  # describer cache
    for var in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL", *(f"STORYTELLER_{n.upper()}_MODEL" for n in NODES)):
        monkeypatch.delenv(var, raising=False)
    with FakeOpenAI(default='{"error": "no script"}') as server:
        yield server


def write_config(tmp_path: Path, api_base: str) -> Path:
    """Every node on its own fake model: the per-node config decides who answers."""
    lines = [
        "[llm]", f'api_base = "{api_base}"', 'api_key_env = "FAKE_PROVIDER_KEY"', "timeout_s = 10.0",
        "[llm.retry]", "max_attempts = 1",
    ]
    for node in NODES:
        lines += [f"[nodes.{node}]", f'model = "openai/fake-{node}"']
    path = tmp_path / "fake.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def plan(tmp_path: Path, *args: str) -> Any:
    return CliRunner().invoke(
        app, ["plan", "home", "--seed", "0", *args, "--runs-db", str(tmp_path / "runs.sqlite")], catch_exceptions=False
    )


def free_point_near(name: str, *, away_from: list[tuple[float, float]]) -> tuple[float, float]:
    """A free floor point within ~1 m of ``name``, >= 1 m from ``away_from``."""
    floor = FloorMap(SCENE)
    c = np.array(SCENE.get(name).center[:2])
    for r in (0.5, 0.6, 0.7, 0.8, 0.9, 1.0):
        for a in np.linspace(0, 2 * np.pi, 24, endpoint=False):
            p = c + r * np.array([np.cos(a), np.sin(a)])
            if floor.free(p[None])[0] and all(np.hypot(*(p - np.array(q))) >= 1.0 for q in away_from):
                return round(float(p[0]), 2), round(float(p[1]), 2)
    raise AssertionError(f"no free point near {name}")


ROSTER = initial_roster(SCENE, 2, seed=0)
NARRATION = json.dumps({"reasoning": "r", "event": {"characters": ["Ava"], "activity": "make coffee with coffee_maker_1"}})
COFFEE = (
    '```python\ndef parse_event():\n    a = get_character("Ava")\n'
    '    a.set_position(get_area_to_interact_with("coffee_maker_1"))\n'
    '    a.set_orientation("coffee_maker_1")\n    a.set_target_action("use_coffee_maker")\n```'
)


def direct_reply(x: float, y: float, action: str = "use_coffee_maker", look_at: str = "coffee_maker_1") -> str:
    return json.dumps({"plans": [{"character": "Ava", "action": action, "x": x, "y": y, "look_at": look_at}]})


# ----- w/o Event ------------------------------------------------------------------------------
@pytest.mark.slow
def test_unified_planner_plans_from_one_call_and_replays_byte_for_byte(fake: FakeOpenAI, tmp_path: Path) -> None:
    cfg = write_config(tmp_path, fake.base)
    fake.script["fake-planner"] = [COFFEE]
    trace = tmp_path / "unified.jsonl"
    args = ["-n", "2", "-k", "1", "-i", "Ava makes coffee.", "--planner", "unified", "--description", "object-list"]
    live = plan(tmp_path, *args, "--config", str(cfg), "--record", str(trace))
    assert live.exit_code == 0, live.stderr
    lines = live.stdout.splitlines()
    assert lines[0] == "event 1: Ava: Ava: use_coffee_maker (interact with coffee_maker_1)"
    assert lines[1].startswith("  Ava: use_coffee_maker | interact with coffee_maker_1 | position [")
    # one call, to the planner node's own model, with the object list as the description
    assert [r["model"] for r in fake.requests] == ["fake-planner"]
    system = fake.requests[0]["messages"][0]["content"]
    assert "coffee_maker_1: position [" in system and "Instruction: Ava makes coffee." in fake.requests[0]["messages"][1]["content"]
    assert "--planner unified --description object-list" in live.stderr
    assert [r.node for r in read_trace(trace).attempts()] == ["planner"]

    fake.stop()  # the replay must not need the provider
    again = plan(tmp_path, *args, "--replay", str(trace))
    assert again.exit_code == 0, again.stderr
    assert again.stdout == live.stdout
    as_json = plan(tmp_path, *args, "--replay", str(trace), "--json")
    payload = json.loads(as_json.stdout)
    assert payload["ablation"] == {"planner": "unified", "description": "object-list"}
    (event,) = payload["events"]
    assert event["kind"] == "event" and event["narrator_attempts"] == 0 and event["parser_attempts"] == 1
    # the same trace under the full method: refused before anything runs, one line, by plan and by run
    full = plan(tmp_path, *args[:-4], "--description", "object-list", "--replay", str(trace))
    assert full.exit_code == 2 and full.stderr.count("\n") == 1
    assert "recorded with another planner (nodes planner); --planner event asks event_parser, narrator" in full.stderr
    run = CliRunner().invoke(app, ["run", "home", "-n", "2", "-d", "2", "--replay", str(trace), "--out",
                                   str(tmp_path / "run")], catch_exceptions=False)
    assert run.exit_code == 2 and "recorded with another planner" in run.stderr
    assert not any((tmp_path / "run").iterdir())  # nothing written


def test_unified_planner_busy_character_feedback_and_wait(fake: FakeOpenAI, tmp_path: Path) -> None:
    cfg = write_config(tmp_path, fake.base)
    wait = "```python\ndef parse_event():\n    pass\n```"
    # step 1 plans Ava (busy for one more step); step 2 names Ava again, is told, then waits
    fake.script["fake-planner"] = [COFFEE, COFFEE, wait]
    out = plan(tmp_path, "-n", "2", "-k", "2", "--busy-events", "1", "--planner", "unified", "--description", "object-list",
               "--config", str(cfg), "--json")
    assert out.exit_code == 0, out.stderr
    kinds = [e["kind"] for e in json.loads(out.stdout)["events"]]
    assert kinds == ["event", "wait"]
    second = fake.to("fake-planner")[1]["messages"]
    assert "Free characters: Ben" in second[1]["content"]
    retry = fake.to("fake-planner")[2]["messages"]
    assert retry[-1]["role"] == "user" and "Ava is busy and cannot be planned" in retry[-1]["content"]


@pytest.mark.slow
def test_unified_planner_gives_up_with_a_typed_failure(fake: FakeOpenAI, tmp_path: Path) -> None:
    cfg = write_config(tmp_path, fake.base)
    bad = COFFEE.replace("coffee_maker_1", "espresso_machine_9")
    fake.script["fake-planner"] = [bad]
    out = plan(tmp_path, "-k", "1", "--max-retries", "1", "--planner", "unified", "--description", "scene-graph",
               "--config", str(cfg))
    assert out.exit_code == 0, out.stderr
    assert out.stdout.startswith("event 1: failed in planner after 2 attempts:")
    assert "espresso_machine_9" in out.stdout and len(fake.to("fake-planner")) == 2
    # the raw scene graph is the description
    system = fake.to("fake-planner")[0]["messages"][0]["content"]
    assert '"coffee_maker_1":{"position":' in system and '"relations":[' in system


# ----- Direct Inference -----------------------------------------------------------------------
@pytest.mark.slow
def test_direct_inference_rejects_a_point_inside_furniture_then_accepts_a_free_one(
    fake: FakeOpenAI, tmp_path: Path
) -> None:
    cfg = write_config(tmp_path, fake.base)
    table = SCENE.get("table_1").center
    other = ROSTER[1].position
    assert other is not None  # the initial roster places everyone
    x, y = free_point_near("coffee_maker_1", away_from=[other])
    fake.script["fake-narrator"] = [NARRATION]
    fake.script["fake-event_parser"] = [direct_reply(table[0], table[1]), direct_reply(x, y)]
    trace = tmp_path / "direct.jsonl"
    args = ["-k", "1", "--planner", "direct", "--description", "object-list"]
    live = plan(tmp_path, *args, "--config", str(cfg), "--record", str(trace), "--json")
    assert live.exit_code == 0, live.stderr
    (event,) = json.loads(live.stdout)["events"]
    assert event["kind"] == "event" and event["parser_attempts"] == 2 and event["narrator_attempts"] == 1
    (p,) = event["plans"]
    assert p["position"] == [x, y] and p["action"] == "use_coffee_maker"
    retry = fake.to("fake-event_parser")[1]
    feedback = next(m["content"] for m in reversed(retry["messages"]) if m["content"].startswith("Running your"))
    assert f"Ava at [{table[0]:.2f}, {table[1]:.2f}] is inside table_1" in feedback
    # the fake model has no native schema support: the client states the schema in the prompt
    assert retry["response_format"] == {"type": "json_object"}
    assert '"enum": ["Ava"]' in retry["messages"][-1]["content"] and '"maxItems": 1' in retry["messages"][-1]["content"]
    assert [r.node for r in read_trace(trace).attempts()] == ["narrator", "event_parser", "event_parser"]
    # each attempt's verdict is traced against it: parsed output, or the typed error
    records = read_trace(trace).records
    attempt_seqs = [r.seq for r in records if r.kind == "attempt"]
    parsed = [r for r in records if r.kind == "parsed"]
    assert [r.ref_seq for r in parsed] == attempt_seqs
    assert [r.node for r in parsed] == ["narrator", "event_parser", "event_parser"]
    assert parsed[0].parsed_output["event"]["characters"] == ["Ava"]
    assert parsed[1].error_type == "BlockedPositionError" and "inside table_1" in (parsed[1].error_message or "")
    assert parsed[2].error_type is None and parsed[2].parsed_output["plans"][0]["position"] == [x, y]

    fake.stop()
    again = plan(tmp_path, *args, "--replay", str(trace), "--json")
    assert again.exit_code == 0, again.stderr
    assert again.stdout == live.stdout


def test_direct_inference_out_of_retries_is_a_failed_step(fake: FakeOpenAI, tmp_path: Path) -> None:
    cfg = write_config(tmp_path, fake.base)
    fridge = SCENE.get("fridge_1").center
    fake.script["fake-narrator"] = [NARRATION]
    fake.script["fake-event_parser"] = [direct_reply(fridge[0], fridge[1])]
    out = plan(tmp_path, "-k", "1", "--max-retries", "1", "--planner", "direct", "--description", "object-list",
               "--config", str(cfg))
    assert out.exit_code == 0, out.stderr
    assert out.stdout.startswith("event 1: failed in event_parser after 2 attempts:")
    assert "inside fridge_1" in out.stdout


@pytest.mark.slow
def test_direct_inference_point_on_a_seat_sits_on_it(fake: FakeOpenAI, tmp_path: Path) -> None:
    cfg = write_config(tmp_path, fake.base)
    chair = SCENE.get("chair_1").center
    fake.script["fake-narrator"] = [
        json.dumps({"reasoning": "", "event": {"characters": ["Ava"], "activity": "sit on chair_1 and eat"}})
    ]
    fake.script["fake-event_parser"] = [direct_reply(chair[0], chair[1], action="eat", look_at="table_1")]
    # the describer is asked first (its reply must name every object once: one area here)
    fake.script["fake-describer"] = [json.dumps({"areas": [{"name": "home", "purpose": "", "objects": list(SCENE.object_names)}]})]
    out = plan(tmp_path, "-k", "1", "--planner", "direct", "--description", "describer", "--config", str(cfg), "--json")
    assert out.exit_code == 0, out.stderr
    (event,) = json.loads(out.stdout)["events"]
    assert event["kind"] == "event", event
    (p,) = event["plans"]
    assert p["action"] == "eat" and "chair_1" in p["area"]
    assert fake.to("fake-describer") and "home:" in fake.to("fake-narrator")[-1]["messages"][0]["content"]


# ----- description ablations with the full method --------------------------------------------
@pytest.mark.slow
def test_event_planner_with_the_object_list_skips_the_describer(fake: FakeOpenAI, tmp_path: Path) -> None:
    cfg = write_config(tmp_path, fake.base)
    fake.script["fake-narrator"] = [NARRATION]
    fake.script["fake-event_parser"] = [COFFEE]
    trace = tmp_path / "objects.jsonl"
    args = ["-k", "1", "--description", "object-list"]
    live = plan(tmp_path, *args, "--config", str(cfg), "--record", str(trace))
    assert live.exit_code == 0, live.stderr
    assert live.stdout.startswith("event 1: Ava: make coffee with coffee_maker_1\n  Ava: use_coffee_maker |")
    assert [r["model"] for r in fake.requests] == ["fake-narrator", "fake-event_parser"]
    assert "coffee_maker_1: position [" in fake.to("fake-narrator")[0]["messages"][0]["content"]
    fake.stop()
    again = plan(tmp_path, *args, "--replay", str(trace))
    assert again.exit_code == 0 and again.stdout == live.stdout


# ----- option checking ------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("command", "option", "value", "choices"),
    [
        ("plan", "--planner", "events", "'event', 'unified', 'direct'"),
        ("plan", "--description", "objects", "'describer', 'object-list', 'scene-graph'"),
        ("run", "--planner", "Unified", "'event', 'unified', 'direct'"),
        ("run", "--description", "graph", "'describer', 'object-list', 'scene-graph'"),
        ("run", "--pace", "slow", "'lockstep', 'realtime', 'fast', 'offline'"),
    ],
)
def test_bad_choices_exit_2_with_a_clear_message(
    command: str, option: str, value: str, choices: str, tmp_path: Path
) -> None:
    extra = ["--runs-db", str(tmp_path / "r.sqlite")] if command == "plan" else ["--out", str(tmp_path / "out")]
    result = CliRunner().invoke(app, [command, "home", option, value, *extra])
    assert result.exit_code == 2
    # typer checks the Literal-typed option and prints the error in a box: drop the frame
    # and the line breaks before reading the sentence
    text = " ".join(result.stderr.replace("│", " ").split())
    assert f"Invalid value for '{option}': Value error, '{value}' is not one of {choices}." in text
    assert not (tmp_path / "out").exists()  # nothing was started


# ----- storyteller run ------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("planner", "description", "script", "nodes"),
    [
        ("unified", "object-list", {"fake-planner": [COFFEE]}, ["planner"]),
        ("event", "scene-graph", {"fake-narrator": [NARRATION], "fake-event_parser": [COFFEE]}, ["narrator", "event_parser"]),
    ],
)
@pytest.mark.slow
def test_run_with_an_ablation_records_and_replays_the_same_story(
    planner: str, description: str, script: dict[str, list[Action]], nodes: list[str], fake: FakeOpenAI, tmp_path: Path
) -> None:
    cfg = write_config(tmp_path, fake.base)
    fake.script.update(script)
    args = ["run", "home", "-n", "2", "-d", "2", "--max-events", "1", "--planner", planner, "--description", description]
    live = CliRunner().invoke(app, [*args, "--config", str(cfg), "--out", str(tmp_path / "live")], catch_exceptions=False)
    assert live.exit_code == 0, live.stderr
    assert "event-0000 starts: Ava makes coffee at the coffee maker." in live.stdout
    assert [r["model"] for r in fake.requests] == [f"fake-{n}" for n in nodes]  # no describer call
    story = json.loads((tmp_path / "live" / "story.json").read_text(encoding="utf-8"))
    assert story["steps"][0]["kind"] == "event" and story["steps"][0]["plans"][0]["action"] == "use_coffee_maker"
    fake.stop()
    again = CliRunner().invoke(
        app, [*args, "--replay", str(tmp_path / "live" / "trace.jsonl"), "--out", str(tmp_path / "again")], catch_exceptions=False
    )
    assert again.exit_code == 0, again.stderr
    assert (tmp_path / "again" / "story.json").read_bytes() == (tmp_path / "live" / "story.json").read_bytes()


@pytest.mark.slow
def test_run_raw_feet_replays_the_same_story_with_the_animated_legs(fake: FakeOpenAI, tmp_path: Path) -> None:
    cfg = write_config(tmp_path, fake.base)
    fake.script.update({"fake-planner": [COFFEE]})
    args = ["run", "home", "-n", "2", "-d", "4", "--max-events", "1", "--planner", "unified", "--description", "object-list"]
    live = CliRunner().invoke(app, [*args, "--config", str(cfg), "--out", str(tmp_path / "live")], catch_exceptions=False)
    assert live.exit_code == 0, live.stderr
    fake.stop()
    raw = CliRunner().invoke(app, [*args, "--raw-feet", "--replay", str(tmp_path / "live" / "trace.jsonl"),
                                   "--out", str(tmp_path / "raw")], catch_exceptions=False)
    assert raw.exit_code == 0, raw.stderr
    assert (tmp_path / "raw" / "story.json").read_bytes() == (tmp_path / "live" / "story.json").read_bytes()
    from storyteller.sim.body.foot_ik import LEG_JOINTS

    with np.load(tmp_path / "live" / "Ava.track.npz") as ik, np.load(tmp_path / "raw" / "Ava.track.npz") as plain:
        assert np.array_equal(ik["root_positions"], plain["root_positions"])  # same paths, same pelvis
        legs = list(LEG_JOINTS)  # hips, knees, ankles
        others = [j for j in range(22) if j not in legs]
        assert np.array_equal(ik["local_rotations"][:, others], plain["local_rotations"][:, others])
        assert not np.allclose(ik["local_rotations"][:, legs], plain["local_rotations"][:, legs])

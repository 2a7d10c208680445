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
from typer.testing import CliRunner

from orchestrator.cli import app

REPO = Path(__file__).resolve().parents[1]
TRACES = REPO / "traces"
GOLDEN = {
    "plan_home_2events": [
        "plan", "home", "-n", "2", "-k", "2", "--seed", "0", "--busy-events", "1",
        "-i", "Ben watches TV sitting on the couch.",
    ],
}


def run_cli(args: list[str], tmp_path: Path) -> object:
    return CliRunner().invoke(app, [*args, "--runs-db", str(tmp_path / "runs.sqlite")], catch_exceptions=False)


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_replay_reproduces_the_recorded_output_byte_for_byte(
    name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from orchestrator import local_model

    loads: list[str] = []

    def no_load(spec: object) -> object:  # another test may have loaded the model already
        loads.append(str(spec))
        raise AssertionError("replay tried to load the embedded model")

    monkeypatch.setattr(local_model, "get_llama", no_load)
    result = run_cli([*GOLDEN[name], "--replay", str(TRACES / f"{name}.jsonl")], tmp_path)
    assert result.exit_code == 0, result.stderr  # type: ignore[attr-defined]
    assert result.stdout == (TRACES / f"{name}.out").read_text(encoding="utf-8")  # type: ignore[attr-defined]
    assert loads == []  # no model was loaded


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_replay_json_lists_every_event_with_plans(name: str, tmp_path: Path) -> None:
    result = run_cli([*GOLDEN[name], "--replay", str(TRACES / f"{name}.jsonl"), "--json"], tmp_path)
    assert result.exit_code == 0, result.stderr  # type: ignore[attr-defined]
    payload = json.loads(result.stdout)  # type: ignore[attr-defined]
    k = int(GOLDEN[name][GOLDEN[name].index("-k") + 1])
    assert len(payload["events"]) == k
    for event in payload["events"]:
        if event["kind"] == "event":
            assert {p["character"] for p in event["plans"]} == set(event["characters"])
            for p in event["plans"]:
                assert len(p["position"]) == 2 and len(p["facing"]) == 2 and p["action"]


def test_one_edited_character_in_a_prompt_fails_the_replay_naming_the_node(tmp_path: Path) -> None:
    prompts = tmp_path / "prompts"
    shutil.copytree(Path(str(resources.files("prompts"))), prompts)
    path = prompts / "narrator" / "system.md"
    text = path.read_text(encoding="utf-8")
    path.write_text(text.replace("free characters", "free characterz", 1), encoding="utf-8")
    name = "plan_home_2events"
    result = run_cli([*GOLDEN[name], "--replay", str(TRACES / f"{name}.jsonl"), "--prompts", str(prompts)], tmp_path)
    assert result.exit_code == 1
    err = result.stderr  # type: ignore[attr-defined]
    assert "replay miss for node narrator" in err
    assert "characterz" in err and "characters" in err  # the diff shows both versions


def test_replay_with_a_different_instruction_fails(tmp_path: Path) -> None:
    name = "plan_home_2events"
    args = [*GOLDEN[name][:-1], "Ben dances.", "--replay", str(TRACES / f"{name}.jsonl")]
    result = run_cli(args, tmp_path)
    assert result.exit_code == 1 and "replay miss for node narrator" in result.stderr  # type: ignore[attr-defined]


def test_bad_arguments_exit_2(tmp_path: Path) -> None:
    result = run_cli(["plan", "no_such_scene", "-i", "x"], tmp_path)
    assert result.exit_code == 2 and "not a bundled scene" in result.stderr  # type: ignore[attr-defined]
    result = run_cli(["plan", "home", "--record", "a.jsonl", "--replay", "b.jsonl"], tmp_path)
    assert result.exit_code == 2


@pytest.mark.embedded_model
async def test_embedded_model_narrator_and_parser_end_to_end() -> None:
    """The real path: litellm -> local provider -> llama.cpp, one narrator and one parser call."""
    from agents.event_parser import ParserInput, parse_event, scene_action_labels
    from agents.messages import CharacterStatus
    from agents.narrator import NarratorInput, narrate
    from agents.prompt_templates import PromptLibrary
    from agents.retry_feedback import RetriesExhaustedError
    from orchestrator.cli_plan import RosterWorld, initial_roster
    from orchestrator.config import default_config
    from orchestrator.replay import build_llm_port
    from sim.bundled_scenes import resolve_scene

    scene = resolve_scene("home")
    port = build_llm_port(default_config())
    prompts = PromptLibrary()
    roster: tuple[CharacterStatus, ...] = initial_roster(scene, 1, seed=0)
    description = "- kitchen (make coffee): cabinet_1 (with coffee_maker_1 on it), fridge_1"
    narrated = await narrate(
        port, prompts,
        NarratorInput(scene_description=description, characters=roster, instruction="Ava makes coffee.", tags=("OA",), seed=0),
        max_retries=0,
    )
    event = narrated.value.event
    assert event.characters in ((), ("Ava",))  # grammar: only the free character can be named
    if event.is_wait:
        event = event.model_copy(update={"characters": ("Ava",), "activity": "make coffee with coffee_maker_1"})
    labels = scene_action_labels(scene)
    try:
        parsed = await parse_event(
            port, prompts,
            ParserInput(scene_description=description, event=event, characters=roster, action_labels=labels, tags=("OA",), seed=0),
            scene=scene, world=RosterWorld().world_view(roster), seed=0, max_retries=0,
        )
    except RetriesExhaustedError as exc:  # a weak model may fail; the failure must be typed feedback
        assert exc.feedback
    else:
        assert parsed.value.plans[0].character == "Ava"

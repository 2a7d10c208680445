"""The planning benchmark on the reference test cases: case loading, scoring, the runner with
scripted planners, and the command line (record, then replay byte for byte) through the real
litellm client against a fake OpenAI-compatible server on 127.0.0.1
(``benchmark/support/fake_openai_server.py``)."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from storyteller.agents.llm_port import LLMRequest
from storyteller.agents.messages import Event, ParsedEvent, PlannedCharacter, PlanningFailure
from storyteller.benchmark.plan_scoring import ActionExpressionError, action_matches, score_outcome
from storyteller.benchmark.planning_benchmark import Descriptions, main, run_cases, summary_rows
from storyteller.benchmark.reference_cases import (
    BenchmarkCase,
    BenchmarkCaseError,
    load_case,
    load_cases,
    planning_inputs,
    scene_dir,
)
from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene
from tests.support.reference import REFERENCE, requires_reference
from tests.support.scripted_llm import ScriptedLLM

pytestmark = requires_reference

PROGRAMS = {  # correct answers for a few cases, as an event parser would write them
    0: ("Ryan", "text a friend near table_3", 'a = get_character("Ryan")\n'
        '    a.set_position(get_area_close_to("table_3"))\n    a.set_target_action("use_smartphone")'),
    20: ("Taylor", "read a book sitting on chair_3", 'a = get_character("Taylor")\n'
         '    a.set_position(get_area_to_sit_on("chair_3"))\n    a.set_target_action("read_book")'),
    60: ("Theodore", "wait in front of the fridge", 'a = get_character("Theodore")\n'
         '    a.set_position(get_area_in_front_of("fridge_1"))\n    a.set_target_action("idle")'),
}


def narration(case: int) -> str:
    who, activity, _ = PROGRAMS[case]
    return json.dumps({"reasoning": "the instruction asks for it", "event": {"characters": [who], "activity": activity}})


def program(case: int) -> str:
    return f"```python\ndef parse_event():\n    {PROGRAMS[case][2]}\n```"


def oracle(case_of: dict[str, int], broken: bool = False) -> ScriptedLLM:
    """Answers narrator and parser requests with the known-good reply of the current case (the
    case whose character the user messages name); ``broken``: a parser that cannot write Python."""

    def reply(request: LLMRequest) -> str:
        text = " ".join(m.content for m in request.messages if m.role == "user")
        case = next(c for name, c in case_of.items() if name in text)
        if request.node == "narrator":
            return narration(case)
        return "def parse_event(:\n" if broken else program(case)

    return ScriptedLLM(reply, model="oracle")


def _scene(case_id: int) -> tuple[BenchmarkCase, Scene]:
    case = load_cases(REFERENCE, [case_id])[0]
    return case, load_scene(scene_dir(REFERENCE, case))


def test_all_forty_cases_load_with_their_inputs() -> None:
    cases = load_cases(REFERENCE)
    assert len(cases) == 40 and sorted(c.id for c in cases)[:3] == [0, 1, 2]
    assert {c.group for c in cases} == {"OA", "RC", "SS", "OA+RC", "OA+SS", "RC+SS", "PI"}
    case, scene = _scene(0)
    inputs = planning_inputs(case, scene)
    assert set(inputs.free) == {"Ryan", "Jorge"}  # Norma, Jason, Deanna are busy
    assert {"chair_2", "chair_6"} <= set(inputs.seats_in_use)
    assert [h.state for h in inputs.history] == ["completed", "ongoing", "ongoing", "completed"]
    plain = case.at_level(0)
    assert [c.name for c in plain.current_states] == ["Ryan"] and plain.planning_history == ()
    assert len(load_cases(REFERENCE, tags=["PI"])) == 10


def test_bad_case_files_are_typed_errors(tmp_path: Path) -> None:
    bad = tmp_path / "testcase_1.json"
    bad.write_text('{"id": 1, "tags": ["OA"]')
    with pytest.raises(BenchmarkCaseError, match=r"testcase_1\.json: not valid JSON"):
        load_case(bad)
    bad.write_text('{"id": "one"}')
    with pytest.raises(BenchmarkCaseError, match="field 'id'"):
        load_case(bad)
    with pytest.raises(BenchmarkCaseError, match="no test case with id"):
        load_cases(REFERENCE, [999])


def test_action_expressions() -> None:
    assert action_matches("order_food || order_drink", "order_drink")
    assert not action_matches("order_food || order_drink", "eat")
    assert action_matches("(eat || drink) && drink", "drink")
    assert not action_matches("eat && drink", "eat")
    for bad in ("", "eat ||", "(eat", "eat )", "eat; drink"):
        with pytest.raises(ActionExpressionError):
            action_matches(bad, "eat")


def _event(character: str, action: str, position: tuple[float, float], seat: str | None = None) -> ParsedEvent:
    return ParsedEvent(index=0, event=Event(characters=(character,), activity="x"), plans=(
        PlannedCharacter(character=character, action=action, position=position, facing=(1.0, 0.0), seat=seat),))


def test_scoring_judges_action_relationship_seat_and_failures() -> None:
    case, scene = _scene(0)
    table = scene.by_name["table_3"]
    near = (float(table.center[0] + table.width / 2 + 0.6), float(table.center[1]))
    assert score_outcome(case, scene, _event("Ryan", "use_smartphone", near)).passed
    wrong = score_outcome(case, scene, _event("Ryan", "read_book", near))
    assert wrong.executed and not wrong.passed and "does not match" in wrong.reason
    far = score_outcome(case, scene, _event("Ryan", "use_smartphone", (0.5, 0.5)))
    assert not far.passed and "is not 'close to table_3" in far.reason
    inside = score_outcome(case, scene, _event("Ryan", "use_smartphone", (float(table.center[0]), float(table.center[1]))))
    assert not inside.passed and "collides with table_3" in inside.reason
    other = score_outcome(case, scene, _event("Jorge", "use_smartphone", near))
    assert not other.passed and "no plan for Ryan" in other.reason
    wait = score_outcome(case, scene, None)
    assert wait.executed and not wait.passed
    failed = score_outcome(case, scene, PlanningFailure(index=0, node="event_parser", attempts=4, feedback="boom"))
    assert not failed.executed and not failed.passed

    case20, house = _scene(20)
    chair = house.by_name["chair_3"]
    on_chair = (float(chair.center[0]), float(chair.center[1]))
    assert score_outcome(case20, house, _event("Taylor", "read_book", on_chair, seat="chair_3")).passed
    standing = score_outcome(case20, house, _event("Taylor", "read_book", on_chair, seat=None))
    assert not standing.passed  # a standing point on a seat is not sitting on it
    seated_elsewhere = score_outcome(case, scene, _event("Ryan", "use_smartphone", (
        float(scene.by_name["chair_1"].center[0]), float(scene.by_name["chair_1"].center[1])), seat="chair_1"))
    assert "collides" not in seated_elsewhere.reason  # sitting on a seat is not a collision with it


async def test_runner_with_an_oracle_passes_and_a_broken_parser_does_not_execute() -> None:
    cases = [c.at_level(2) for c in load_cases(REFERENCE, list(PROGRAMS))]
    who = {PROGRAMS[c.id][0]: c.id for c in cases}
    port = oracle(who)
    descriptions = Descriptions("reference", REFERENCE)
    results = await run_cases(cases, port, descriptions, REFERENCE, runs=2)
    assert [(r.case, r.run) for r in results] == [(0, 0), (0, 1), (20, 0), (20, 1), (60, 0), (60, 1)]
    assert all(r.score.passed for r in results), [r.score.reason for r in results]
    assert [r.node for r in port.requests[:2]] == ["narrator", "event_parser"]
    assert "Kitchen" in port.requests[0].messages[0].content + port.requests[0].messages[-1].content  # the authors' text
    rows = {label: (n, s, e) for label, n, s, e in summary_rows(results)}
    assert rows["all"] == (6, 1.0, 1.0) and rows["PI"] == (2, 1.0, 1.0)

    broken = oracle(who, broken=True)
    results = await run_cases(cases[:1], broken, descriptions, REFERENCE, max_retries=2)
    assert not results[0].score.executed and results[0].score.kind == "failure"
    assert [r.node for r in broken.requests] == ["narrator", "event_parser", "event_parser", "event_parser"]


def oracle_reply(who: dict[str, int]) -> Callable[[dict[str, Any]], str]:
    """The oracle's reply to a chat request, chosen by request content: the case whose
    character is named in the user messages; a narration if JSON output was asked for, else
    the event program."""

    def reply(body: dict[str, Any]) -> str:
        text = " ".join(m["content"] for m in body["messages"] if m["role"] == "user")
        case = next(c for name, c in who.items() if name in text)
        return narration(case) if "response_format" in body else program(case)

    return reply


@pytest.fixture
def fake() -> Iterator[FakeOpenAI]:
    with FakeOpenAI(responder=oracle_reply({PROGRAMS[c][0]: c for c in PROGRAMS})) as server:
        yield server


@pytest.mark.slow
def test_cli_records_then_replays_byte_for_byte(fake: FakeOpenAI, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FAKE_KEY", "sk-test")
    config = tmp_path / "bench.toml"
    config.write_text(f'[llm]\nmodel = "openai/fake"\napi_base = "{fake.base}"\napi_key_env = "FAKE_KEY"\n')
    trace = tmp_path / "bench.jsonl"
    common = ["--reference", str(REFERENCE), "--cases", "0", "60", "--description", "reference", "--verbose"]
    assert main([*common, "--config", str(config), "--record", str(trace), "--json", str(tmp_path / "r.json")]) == 0
    recorded = capsys.readouterr().out
    # per case a narration and a program; the PI case's words name no action: one action choice too
    assert len(fake.requests) == 5
    assert "case  0 run 0 [OA]: pass" in recorded and "case 60 run 0 [PI]: pass" in recorded
    assert "all" in recorded and "1.00" in recorded and "paper" in recorded
    report = json.loads((tmp_path / "r.json").read_text())
    assert [r["score"]["passed"] for r in report["runs"]] == [True, True]

    fake.stop()  # the replay must not need the server
    assert main([*common, "--replay", str(trace)]) == 0
    replayed = capsys.readouterr().out
    assert replayed.replace(" (replayed)", "") == recorded

    # a different request (another seed) is not in the trace: a typed error, exit 1
    assert main([*common, "--replay", str(trace), "--seed", "5"]) == 1
    assert "replay" in capsys.readouterr().err.lower()


def test_cli_bad_options_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--reference", str(tmp_path), "--cases", "0"]) == 2
    assert "test_cases" in capsys.readouterr().err
    assert main(["--reference", str(REFERENCE), "--cases", "999"]) == 2
    with pytest.raises(SystemExit):
        main(["--planner", "nope"])

"""Event parser: code extraction, request layout, typed errors as feedback, retries.

The program runner is a fake here (the sandbox and spatial API have their own tests); one
test runs the real ``run_event_program`` on a small scene.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from storyteller.agents.event_parser import (
    ParserInput,
    check_plans,
    extract_program,
    parse_event,
    parser_request,
    run_reply,
    scene_action_labels,
)
from storyteller.agents.messages import CharacterStatus, Event
from storyteller.agents.prompt_templates import PromptLibrary
from storyteller.agents.retry_feedback import AnswerRejectedError, NoCodeError, RetriesExhaustedError
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.character_states import WorldView
from storyteller.tools.errors import UnknownObjectError
from storyteller.tools.scene_graph import SceneGraph
from tests.support.planning_script import Plan
from tests.support.scripted_llm import ScriptedLLM

BODY = '    a = get_character("Ann")\n    a.set_position(get_area_close_to("table_1"))\n'
FUNC = "def parse_event():\n" + BODY


@pytest.mark.parametrize(
    "reply",
    [
        "```python\n" + FUNC + "```",
        "Here you go:\n```py\n" + FUNC + "```\nThis places Ann.",
        "```\n" + FUNC + "```",
        FUNC,
        "Sure!\n" + FUNC + "parse_event()\nDone.",
        "```python\n" + FUNC,  # unclosed fence
        "```python\n" + "a = get_character(\"Ann\")\na.set_position(get_area_close_to(\"table_1\"))\n```",  # bare body
    ],
)
def test_extract_program_variants(reply: str) -> None:
    program = extract_program(reply)
    assert program.startswith("def parse_event():\n")
    assert 'get_character("Ann")' in program and "parse_event()\n" not in program.split("\n", 1)[1]
    compile(program, "<llm>", "exec")


def test_extract_program_without_code_is_typed() -> None:
    with pytest.raises(NoCodeError, match="no parse_event"):
        extract_program("I cannot do this.")


@settings(max_examples=60, deadline=None)
@given(st.text(max_size=300))
@pytest.mark.slow
def test_extract_program_never_crashes(text: str) -> None:
    with contextlib.suppress(NoCodeError):
        assert "parse_event" in extract_program(text)


def test_check_plans_requires_exactly_the_event_characters() -> None:
    event = Event(characters=("Ann", "Bob"), activity="chat")
    with pytest.raises(AnswerRejectedError, match="no position was set for Bob"):
        check_plans(event, [Plan("Ann", "chat", "x", (1, 1), (0, 1))])
    with pytest.raises(AnswerRejectedError, match="Cat not in this event"):
        check_plans(event, [Plan("Ann", "chat", "x", (1, 1), (0, 1)), Plan("Bob", "chat", "x", (2, 1), (0, 1)), Plan("Cat", "idle", "x", (3, 1), (0, 1))])
    ok = check_plans(event, [Plan("Bob", "chat", "x", (2, 1), (0, 1)), Plan("Ann", "chat", "x", (1, 1), (0, 1))])
    assert [p.character for p in ok] == ["Bob", "Ann"]


def scene() -> Scene:
    objs = (
        SceneObject(name="table_1", label="table", idx=1, center=(2.0, 2.0, 0.375), size=(1.2, 0.8, 0.75)),
        SceneObject(name="chair_1", label="chair", idx=1, center=(2.0, 1.2, 0.45), size=(0.5, 0.5, 0.9),
                    has_facing=True, facing=(0.0, 1.0), sit_offset_vertical=0.45),
        SceneObject(name="fridge_1", label="fridge", idx=1, center=(5.0, 5.0, 0.9), size=(0.8, 0.7, 1.8), has_facing=True),
    )
    return Scene(name="t", bounds_min=(0.0, 0.0), bounds_max=(6.0, 6.0), objects=objs)


def make_input() -> ParserInput:
    return ParserInput(
        scene_description="- dining: table_1, chair_1",
        event=Event(characters=("Ann",), activity="eat at table_1"),
        characters=(CharacterStatus(name="Ann", position=(1.0, 1.0)), CharacterStatus(name="Bob", busy=True)),
        action_labels=("idle", "eat"),
        seats_in_use=("chair_9",),
        seed=1,
    )


def test_request_layout() -> None:
    req = parser_request(PromptLibrary(), make_input())
    assert req.node == "event_parser" and req.json_schema is None
    system, user = req.messages[0].content, req.messages[1].content
    assert "get_area_to_sit_on(object)" in system and "Action labels: idle, eat" in system
    assert "- dining: table_1, chair_1" in system
    assert 'characters ["Ann"]' in user and "Seats in use: chair_9" in user and "[1.0" not in user
    assert "Suggested action label: eat" in user


def fake_runner(
    scene: Scene,
    source: str,
    world: WorldView,
    *,
    seed: int,
    action_labels: Sequence[str] | None = None,
    graph: SceneGraph | None = None,
) -> list[Plan]:
    if "tabel_1" in source:
        raise UnknownObjectError("unknown object 'tabel_1'; did you mean 'table_1'?")
    return [Plan("Ann", "eat", "close to table_1", (1.0 + seed, 1.0), (0.0, 1.0))]


async def test_typed_error_becomes_feedback_and_retry_succeeds() -> None:
    port = ScriptedLLM(["no code here", "```python\n" + FUNC.replace("table_1", "tabel_1") + "```", "```python\n" + FUNC + "```"])
    accepted = await parse_event(port, PromptLibrary(), make_input(), scene=scene(), world=WorldView(), seed=5, runner=fake_runner)
    assert accepted.attempts == 3
    assert accepted.value.plans[0].position == (6.0, 1.0)
    feedback = port.requests[2].messages[-1].content
    assert "did you mean 'table_1'" in feedback and feedback.startswith("Running your parse_event() failed")


async def test_parser_retries_bounded() -> None:
    port = ScriptedLLM(["nothing"] * 5)
    with pytest.raises(RetriesExhaustedError):
        await parse_event(port, PromptLibrary(), make_input(), scene=scene(), world=WorldView(), seed=0, runner=fake_runner, max_retries=1)
    assert len(port.requests) == 2


def test_scene_action_labels_drop_absent_appliances() -> None:
    labels = scene_action_labels(scene())
    assert "open_fridge" in labels and "use_toaster" not in labels and "walk" not in labels and "eat" in labels


def test_real_event_program_runner() -> None:
    """The real sandbox + spatial API path (tools/)."""
    from storyteller.orchestrator.session.roster import RosterWorld

    roster = (CharacterStatus(name="Ann", position=(4.0, 1.0)),)
    world = RosterWorld().world_view(roster)
    program = "```python\ndef parse_event():\n    a = get_character(\"Ann\")\n    a.set_position(get_area_to_sit_on(\"chair_1\"))\n    a.set_orientation(\"table_1\")\n    a.set_target_action(\"eat\")\n```"
    result = run_reply(program, scene=scene(), event=Event(characters=("Ann",), activity="eat"), world=world,
                       seed=0, action_labels=("idle", "eat"))
    plan = result.plans[0]
    assert plan.action == "eat" and plan.seat == "chair_1"
    with pytest.raises(UnknownObjectError, match="chair_1"):
        run_reply(program.replace('"chair_1"', '"chiar_1"'), scene=scene(), event=Event(characters=("Ann",), activity="eat"),
                  world=world, seed=0, action_labels=("idle", "eat"))


def test_the_suggested_label_and_the_instruction_part_reach_the_request() -> None:
    from storyteller.agents.event_parser import parser_messages

    inp = make_input()
    labels = ("idle", "watch_tv", "use_laptop", "read_book")
    event = Event(characters=inp.event.characters, activity="take the seat from which it can be reached")
    bare = replace(inp, event=event, action_labels=labels)
    user = parser_messages(PromptLibrary(), bare)[-1].content
    assert "Suggested action label: idle" in user and "part of the instruction" not in user
    part = "Ann types up her notes on the laptop, so she takes the seat from which it can be reached."
    user = parser_messages(PromptLibrary(), replace(bare, instruction_part=part))[-1].content
    assert "Suggested action label: use_laptop" in user
    assert f'It comes from this part of the instruction: "{part}"' in user


async def test_parser_retry_asks_for_the_code_block_only() -> None:
    port = ScriptedLLM(["no code", "```python\n" + FUNC + "```"])
    await parse_event(port, PromptLibrary(), make_input(), scene=scene(), world=WorldView(), seed=0, runner=fake_runner)
    assert port.requests[1].messages[-1].content.endswith("reply with the whole corrected ```python block only.")

"""Narrator: request layout, schema, validation and feedback, retries."""

from __future__ import annotations

import json
from typing import Any

import pytest
from pydantic import ValidationError

from storyteller.agents.messages import CharacterStatus, HistoryEntry
from storyteller.agents.narrator import (
    NarratorInput,
    history_text,
    narrate,
    narrator_request,
    narrator_schema,
    parse_narration,
)
from storyteller.agents.prompt_templates import PromptLibrary
from storyteller.agents.retry_feedback import AnswerRejectedError, RetriesExhaustedError, feedback_from_error
from tests.support.scripted_llm import ScriptedLLM

ROSTER = (
    CharacterStatus(name="Ann"),
    CharacterStatus(name="Bob", busy=True, action="read_book", event_index=0),
    CharacterStatus(name="Cat"),
)
DESCRIPTION = "- kitchen (cook): fridge_1, counter_1\n- dining (eat): table_1, chair_1"


def reply(chars: list[str], activity: str = "eat at table_1") -> str:
    return json.dumps({"reasoning": "r", "event": {"characters": chars, "activity": activity}})


def make_input(**kw: Any) -> NarratorInput:
    base: dict[str, Any] = dict(scene_description=DESCRIPTION, characters=ROSTER, instruction="Ann eats.", seed=3)
    base.update(kw)
    return NarratorInput(**base)


def test_schema_enumerates_only_free_characters_and_bounds_arrays() -> None:
    schema = narrator_schema(["Ann", "Cat"])
    chars = schema["properties"]["event"]["properties"]["characters"]
    assert chars["items"]["enum"] == ["Ann", "Cat"] and chars["maxItems"] == 2
    assert schema["properties"]["reasoning"]["maxLength"] > 0


def test_request_puts_the_stable_part_first() -> None:
    lib = PromptLibrary()
    r1 = narrator_request(lib, make_input())
    r2 = narrator_request(lib, make_input(instruction="Cat cooks.", history=[HistoryEntry(index=0, characters=("Bob",), activity="read", state="ongoing")]))
    assert r1.messages[0] == r2.messages[0]  # system prompt identical across calls
    assert DESCRIPTION in r1.messages[0].content
    assert "Cat cooks." in r2.messages[1].content and "1. [ongoing] Bob: read" in r2.messages[1].content
    assert "Free now: Ann, Cat" in r1.messages[1].content
    assert r1.node == "narrator" and r1.seed == 3 and r1.json_schema is not None


def test_valid_reply_and_wait() -> None:
    out = parse_narration(reply(["Ann"]), ROSTER)
    assert out.event.characters == ("Ann",)
    wait = parse_narration(reply([], ""), ROSTER)
    assert wait.event.is_wait


def test_busy_unknown_and_duplicate_characters_are_named_in_feedback() -> None:
    with pytest.raises(AnswerRejectedError) as info:
        parse_narration(reply(["Bob", "Zed", "Ann", "Ann"]), ROSTER)
    text = feedback_from_error(info.value)
    assert "Bob is busy in event 1" in text
    assert "Zed is not a character" in text
    assert "Ann is listed twice" in text
    assert "free characters are: Ann, Cat" in text


def test_bad_json_and_schema_give_feedback() -> None:
    with pytest.raises(json.JSONDecodeError) as info:
        parse_narration('{"reasoning": "x", "event": {', ROSTER)
    assert "not valid JSON" in feedback_from_error(info.value)
    with pytest.raises(ValidationError) as info2:
        parse_narration('{"event": {"characters": "Ann", "activity": 3}}', ROSTER)
    assert "required JSON format" in feedback_from_error(info2.value)
    with pytest.raises(AnswerRejectedError, match="activity is empty"):
        parse_narration(reply(["Ann"], "  "), ROSTER)


def test_reply_in_fences_is_accepted() -> None:
    assert parse_narration("```json\n" + reply(["Cat"]) + "\n```", ROSTER).event.characters == ("Cat",)


async def test_retries_then_success_and_feedback_in_conversation() -> None:
    port = ScriptedLLM([reply(["Bob"]), "nonsense", reply(["Ann"])])
    accepted = await narrate(port, PromptLibrary(), make_input(), max_retries=3)
    assert accepted.attempts == 3 and accepted.value.event.characters == ("Ann",)
    last = port.requests[-1].messages
    assert [m.role for m in last] == ["system", "user", "assistant", "user", "assistant", "user"]
    assert "Bob is busy" in last[3].content and "not valid JSON" in last[5].content


async def test_retries_are_bounded_and_configurable() -> None:
    port = ScriptedLLM([reply(["Zed"])] * 10)
    with pytest.raises(RetriesExhaustedError) as info:
        await narrate(port, PromptLibrary(), make_input(), max_retries=2)
    assert len(port.requests) == 3 and info.value.attempts == 3


async def test_no_free_character_waits_without_a_call() -> None:
    port = ScriptedLLM([])
    roster = (CharacterStatus(name="Bob", busy=True),)
    accepted = await narrate(port, PromptLibrary(), make_input(characters=roster))
    assert accepted.value.event.is_wait and accepted.attempts == 0 and not port.requests


def test_history_window_keeps_ongoing_events() -> None:
    hist = [HistoryEntry(index=i, characters=("Ann",), activity=f"a{i}", state="completed") for i in range(12)]
    hist.insert(0, HistoryEntry(index=99, characters=("Bob",), activity="long read", state="looping"))
    text = history_text(hist)
    assert "[looping] Bob: long read" in text and "a11" in text and "a0" not in text
    assert "older completed events not shown" in text


def test_instruction_is_numbered_by_sentence() -> None:
    from storyteller.agents.instruction_parts import instruction_text

    assert instruction_text("Ann cooks. Bob eats!") == "\n1) Ann cooks.\n2) Bob eats!"
    assert instruction_text("Ann cooks") == "Ann cooks"
    assert instruction_text("  ") == "(none: continue the story naturally)"


async def test_retries_sample_with_temperature_first_try_does_not() -> None:
    port = ScriptedLLM([reply(["Zed"]), reply(["Ann"])])
    await narrate(port, PromptLibrary(), make_input())
    assert port.requests[0].temperature is None and port.requests[1].temperature == 0.7
    assert port.requests[0].seed == port.requests[1].seed == 3

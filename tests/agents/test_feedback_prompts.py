"""Retry feedback and the schema instruction are prompt files (``prompts/feedback/``,
``prompts/llm/``) rendered strictly, not sentences in code."""

from __future__ import annotations

import json
import shutil
from importlib import resources
from pathlib import Path

import pytest
from pydantic import BaseModel, ValidationError

from storyteller.agents.event_parser import PARSER_RETRY_INSTRUCTION, extract_program
from storyteller.agents.llm_schemas import schema_instruction
from storyteller.agents.prompt_templates import PromptLibrary, PromptTemplateError
from storyteller.agents.retry_feedback import (
    FEEDBACK_FILES,
    AnswerRejectedError,
    NoCodeError,
    Turn,
    ask_until_valid,
    feedback_from_error,
)


class _Reply(BaseModel):
    n: int


def _edited_copy(tmp_path: Path, relpath: str, text: str) -> PromptLibrary:
    copy = tmp_path / "prompts"
    shutil.copytree(Path(str(resources.files("storyteller.prompts"))), copy)
    (copy / relpath).write_text(text, encoding="utf-8")
    return PromptLibrary(copy)


def test_feedback_reads_as_before() -> None:
    with pytest.raises(json.JSONDecodeError) as bad_json:
        json.loads("{")
    assert feedback_from_error(bad_json.value) == (
        "Your reply is not valid JSON (Expecting property name enclosed in double quotes at character 1). "
        "Fix this and answer again."
    )
    with pytest.raises(ValidationError) as bad_shape:
        _Reply.model_validate({"n": "x"})
    assert feedback_from_error(bad_shape.value).startswith("Your reply does not match the required JSON format: field 'n': ")
    rejected = AnswerRejectedError(["Ann is busy", "free characters are: Bob"])
    assert feedback_from_error(rejected, instruction=PARSER_RETRY_INSTRUCTION) == (
        "Your answer was rejected: Ann is busy; free characters are: Bob. "
        "Fix this and reply with the whole corrected ```python block only."
    )
    assert feedback_from_error(RuntimeError("boom")) == "Your answer failed: RuntimeError: boom Fix this and answer again."
    with pytest.raises(NoCodeError, match="no parse_event\\(\\) function"):
        extract_program("I cannot do that.")
    with pytest.raises(NoCodeError, match="longer than 6000 characters"):
        extract_program("def parse_event():\n" + "    x = 1\n" * 1000)


def test_feedback_follows_an_edited_prompt_folder(tmp_path: Path) -> None:
    lib = _edited_copy(tmp_path, "feedback/answer_rejected.md", "Rejected because {{ problems }}!\n")
    assert feedback_from_error(AnswerRejectedError(["x"]), prompts=lib) == "Rejected because x! Fix this and answer again."
    broken = _edited_copy(tmp_path / "b", "feedback/answer_again.md", "Try again, {{ name }}.\n")
    with pytest.raises(PromptTemplateError, match="no value for placeholder"):
        feedback_from_error(AnswerRejectedError(["x"]), prompts=broken)
    no_code = _edited_copy(tmp_path / "c", "feedback/no_code.md", "Write code.\n")
    with pytest.raises(NoCodeError, match=r"^Write code\.$"):
        extract_program("nothing", no_code)


async def test_ask_until_valid_sends_the_feedback_of_its_prompt_folder(tmp_path: Path) -> None:
    from storyteller.agents.llm_port import ChatMessage, LLMRequest, LLMResponse

    lib = _edited_copy(tmp_path, "feedback/answer_again.md", "Once more.\n")
    replies = iter(["nope", '{"n": 3}'])
    seen: list[LLMRequest] = []

    class Port:
        trace = None  # records nothing

        async def complete(self, request: LLMRequest) -> LLMResponse:
            seen.append(request)
            return LLMResponse(text=next(replies), model="fake")

        def close(self) -> None:
            pass

    def build(turns: tuple[Turn, ...]) -> LLMRequest:
        from storyteller.agents.retry_feedback import with_turns

        return LLMRequest(node="narrator", messages=with_turns((ChatMessage(role="user", content="n?"),), turns))

    accepted = await ask_until_valid(
        Port(),
        build,
        _Reply.model_validate_json,
        max_attempts=2,
        node="narrator",
        prompts=lib,
    )
    assert accepted.value.n == 3 and seen[1].messages[-1].content.endswith("Once more.")


def test_every_feedback_file_exists_and_the_schema_instruction_is_a_prompt() -> None:
    lib = PromptLibrary()
    assert all(lib.exists(f) for f in (*FEEDBACK_FILES, PARSER_RETRY_INSTRUCTION, "feedback/no_code.md"))
    text = schema_instruction({"type": "object", "b": 1, "a": 2})
    assert text == 'Reply with exactly one JSON value that matches this JSON schema:\n{"a": 2, "b": 1, "type": "object"}'

"""A pydantic ValidationError said as one user sentence (``storyteller.sim.validation_text``), the one
function every layer's file reader uses."""

from __future__ import annotations

import pytest
from pydantic import BaseModel, ConfigDict, ValidationError, field_validator

from storyteller.orchestrator.safe_text import one_line
from storyteller.sim.validation_text import problem_field, problem_message, user_error


class _Inner(BaseModel):
    model_config = ConfigDict(extra="forbid")

    size: tuple[float, float]


class _Doc(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str
    items: list[_Inner] = []

    @field_validator("name")
    @classmethod
    def _named(cls, value: str) -> str:
        if not value:
            raise ValueError("name must not be empty")
        return value


def _error(data: object) -> ValidationError:
    with pytest.raises(ValidationError) as info:
        _Doc.model_validate(data)
    return info.value


def test_the_sentence_names_the_file_the_dotted_field_and_what_was_wrong() -> None:
    error = _error({"name": "a", "items": [{"size": [1.0, 2.0]}, {"size": [1.0, "x"]}]})
    assert user_error("doc.json", error) == "doc.json: field 'items.1.size.1': " + problem_message(error.errors()[0])
    assert problem_field(error.errors()[0], "top") == "top.items.1.size.1"


def test_pydantic_wording_is_replaced_by_a_users() -> None:
    assert user_error("doc.json", _error({"name": "a", "colour": 1})) == "doc.json: field 'colour': unknown key"
    assert user_error("doc.json", _error({})) == "doc.json: field 'name': required field is missing"
    assert user_error("doc.json", _error({"name": ""})) == "doc.json: field 'name': name must not be empty"


def test_a_document_at_fault_as_a_whole_names_no_field_and_a_prefix_names_the_part() -> None:
    assert user_error("doc.json", _error([1, 2])).startswith("doc.json: Input should be")
    assert user_error("case.json", _error({}), prefix="derivation") == (
        "case.json: field 'derivation.name': required field is missing"
    )


def test_a_key_from_the_file_is_data_the_error_line_escapes() -> None:
    message = user_error("doc.json", _error({"name": "a", "\x1b[31mred\n": 1}))
    assert "\x1b" in message  # the file's own key, quoted as it is spelled...
    assert one_line(message) == "doc.json: field '\\x1b[31mred ': unknown key"  # ...escaped where shown

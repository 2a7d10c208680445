"""Reply schemas come from the pydantic models: what the schema admits, the model accepts."""

from __future__ import annotations

import json

import pytest
from pydantic import BaseModel, ConfigDict, Field

from storyteller.agents.describer import (
    MAX_AREA_NAME_CHARS,
    MAX_AREAS,
    AreaList,
    RegionNaming,
    describer_regions_schema,
    describer_schema,
)
from storyteller.agents.llm_schemas import Refine, SchemaContractError, reply_schema
from storyteller.agents.messages import (
    MAX_ACTIVITY_CHARS,
    MAX_EVENT_CHARACTERS,
    MAX_REASONING_CHARS,
)
from storyteller.agents.narrator import narrator_schema


class Inner(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    label: str = Field(default="", max_length=12, description="A label.")
    tags: tuple[str, ...] = Field(default=(), max_length=3)


class Outer(BaseModel):
    """Developer notes that the model must not see."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    note: str = Field(default="", description="Say why.")
    items: tuple[Inner, ...] = Field(max_length=5)


def _walk(node: object) -> list[dict[str, object]]:
    if isinstance(node, dict):
        return [node, *(d for v in node.values() for d in _walk(v))]
    if isinstance(node, list):
        return [d for v in node for d in _walk(v)]
    return []


def test_the_schema_is_inlined_strict_and_keeps_field_descriptions() -> None:
    schema = reply_schema(Outer)
    text = json.dumps(schema)
    assert "$ref" not in text and "$defs" not in text and "title" not in text and "default" not in text
    assert "Developer notes" not in text
    assert schema["required"] == ["note", "items"]
    assert schema["properties"]["note"]["description"] == "Say why."
    item = schema["properties"]["items"]["items"]
    assert item["required"] == ["label", "tags"] and item["additionalProperties"] is False
    assert item["properties"]["label"] == {"type": "string", "maxLength": 12, "description": "A label."}
    assert schema["properties"]["items"]["maxItems"] == 5


def test_refine_injects_enums_and_only_tightens_bounds() -> None:
    schema = reply_schema(
        Outer,
        {
            "items": Refine(min_items=1, max_items=9),
            "items.tags": Refine(enum=["a", "b", "a"], max_items=2),
            "items.label": Refine(enum=["x"]),
        },
    )
    items = schema["properties"]["items"]
    assert items["minItems"] == 1 and items["maxItems"] == 5  # 9 would loosen the model's 5
    inner = items["items"]["properties"]
    assert inner["tags"]["items"]["enum"] == ["a", "b"] and inner["tags"]["maxItems"] == 2
    assert inner["label"]["enum"] == ["x"]


@pytest.mark.parametrize(
    ("refine", "message"),
    [
        ({"items.nope": Refine(enum=["a"])}, "no field 'items.nope'"),
        ({"note": Refine(max_items=2)}, "not an array"),
        ({"items.tags": Refine(enum=[])}, "empty enum"),
        ({"items": Refine(min_items=4, max_items=2)}, "minItems 4 > maxItems 2"),
    ],
)
def test_bad_refinements_are_errors(refine: dict[str, Refine], message: str) -> None:
    with pytest.raises(SchemaContractError, match=message):
        reply_schema(Outer, refine)


def test_an_unbounded_array_is_an_error() -> None:
    class Loose(BaseModel):
        names: tuple[str, ...]

    with pytest.raises(SchemaContractError, match="no maxItems"):
        reply_schema(Loose)
    assert reply_schema(Loose, {"names": Refine(max_items=4)})["properties"]["names"]["maxItems"] == 4


def test_an_empty_enum_is_left_out_of_an_array_bounded_to_nothing() -> None:
    schema = narrator_schema([])
    characters = schema["properties"]["event"]["properties"]["characters"]
    assert characters["maxItems"] == 0 and characters["items"] == {"type": "string"}


def test_every_array_of_the_agents_schemas_is_bounded() -> None:
    for schema in (narrator_schema(["Ann", "Bob"]), describer_schema(["a_1", "b_1"]), describer_regions_schema(3)):
        arrays = [d for d in _walk(schema) if d.get("type") == "array"]
        assert arrays and all("maxItems" in d for d in arrays)


def test_narrator_schema_carries_the_models_limits_and_the_free_names() -> None:
    names = [f"C{i}" for i in range(MAX_EVENT_CHARACTERS + 2)]
    schema = narrator_schema(names)
    event = schema["properties"]["event"]["properties"]
    assert event["characters"]["items"]["enum"] == names
    assert event["characters"]["maxItems"] == MAX_EVENT_CHARACTERS
    assert event["activity"]["maxLength"] == MAX_ACTIVITY_CHARS
    assert schema["properties"]["reasoning"]["maxLength"] == MAX_REASONING_CHARS
    assert narrator_schema(["Ann", "Ann"])["properties"]["event"]["properties"]["characters"]["maxItems"] == 1


def test_describer_schemas_agree_with_the_models_string_limits() -> None:
    area = describer_schema(["a_1"])["properties"]["areas"]["items"]["properties"]
    assert area["name"]["maxLength"] == MAX_AREA_NAME_CHARS
    AreaList.model_validate({"areas": [{"name": "x" * MAX_AREA_NAME_CHARS, "objects": []}]})
    with pytest.raises(ValueError, match="at most 40 characters"):
        AreaList.model_validate({"areas": [{"name": "x" * (MAX_AREA_NAME_CHARS + 1), "objects": []}]})
    regions = describer_regions_schema(3)["properties"]["regions"]
    assert regions["minItems"] == regions["maxItems"] == 3
    for i, entry in enumerate(regions["prefixItems"], start=1):
        assert entry["properties"]["region"]["const"] == i and entry["properties"]["area"]["maxLength"] == MAX_AREA_NAME_CHARS
    RegionNaming.model_validate({"regions": [{"region": 1, "area": "x" * MAX_AREA_NAME_CHARS}]})
    with pytest.raises(ValueError, match="at most 40 characters"):
        RegionNaming.model_validate({"regions": [{"region": 1, "area": "x" * (MAX_AREA_NAME_CHARS + 1)}]})
    assert describer_schema(["a_1"])["properties"]["areas"]["maxItems"] == MAX_AREAS


def test_the_direct_planners_schema_is_generated_from_its_model() -> None:
    """The Direct Inference schema keeps the constraints it had when it was written by hand
    (one plan per character, closed sets of names, labels and targets), plus descriptions."""
    from storyteller.agents.ablations.direct import direct_schema

    characters, labels, targets = ["Ann", "Bob"], ["idle", "chat"], ["Ann", "Bob", "sofa_1", ""]
    generated = direct_schema(characters, labels, targets)

    def without_descriptions(node: object) -> object:
        if isinstance(node, dict):
            return {k: without_descriptions(v) for k, v in node.items() if k != "description"}
        return [without_descriptions(v) for v in node] if isinstance(node, list) else node

    item = {
        "type": "object",
        "properties": {
            "character": {"type": "string", "enum": characters},
            "action": {"type": "string", "enum": labels},
            "x": {"type": "number"},
            "y": {"type": "number"},
            "look_at": {"type": "string", "enum": targets},
        },
        "required": ["character", "action", "x", "y", "look_at"],
        "additionalProperties": False,
    }
    assert without_descriptions(generated) == {
        "type": "object",
        "properties": {"plans": {"type": "array", "minItems": 2, "maxItems": 2, "items": item}},
        "required": ["plans"],
        "additionalProperties": False,
    }
    assert "description" in generated["properties"]["plans"]["items"]["properties"]["x"]


def test_a_pinned_array_has_one_item_per_value_in_order() -> None:
    schema = reply_schema(Outer, {"items": Refine(pin=("label", ["a", "b"]))})
    items = schema["properties"]["items"]
    assert "items" not in items and items["minItems"] == items["maxItems"] == 2
    assert [e["properties"]["label"]["const"] for e in items["prefixItems"]] == ["a", "b"]
    assert items["prefixItems"][0]["properties"]["tags"]["maxItems"] == 3  # the rest of the item is kept
    with pytest.raises(SchemaContractError, match="cannot pin 'nothing'"):
        reply_schema(Outer, {"items": Refine(pin=("nothing", ["a"]))})
    with pytest.raises(SchemaContractError, match="cannot pin"):
        reply_schema(Outer, {"note": Refine(pin=("label", ["a"]))})
    with pytest.raises(SchemaContractError, match="nothing to pin"):
        reply_schema(Outer, {"items": Refine(pin=("label", []))})

"""JSON schemas of LLM replies, generated from the pydantic models that parse the replies.

A reply model (frozen, ``extra="forbid"``) is the one statement of a reply's contract: field
names and types, string lengths (``max_length`` -> ``maxLength``), tuple lengths
(``max_length`` -> ``maxItems``) and the ``Field(description=...)`` texts written for the model.
:func:`reply_schema` turns it into the schema sent with a request, so the schema can never
allow what the parser refuses or the other way round:

- ``$ref``s are inlined; titles, defaults and class docstrings (written for developers) are
  dropped; field descriptions are kept.
- Every property is required and no other is allowed, so a grammar writes every field, in the
  model's field order (OpenAI's strict mode asks the same). Fields with a default stay optional
  for the parser.
- Facts of one call are injected into named fields with :class:`Refine`: the names a field may
  hold (free characters, scene objects, region numbers, action labels) and array bounds that
  depend on the call. A refinement never loosens a bound the model states.
- An array whose items are known one by one (one entry per region, in order) is pinned with
  ``Refine(pin=(field, values))``: item ``i`` must carry ``values[i]`` in ``field`` (JSON
  schema ``prefixItems`` with a ``const`` each, exactly ``len(values)`` items), so a grammar
  writes every value, in order, and the model only fills in the rest.
- Every array is bounded by ``maxItems``: under llama.cpp's ``json_object`` schema an unbounded
  array lets a small model loop until ``max_tokens`` (see DESIGN.md). An array left unbounded
  is a :class:`SchemaContractError` here, not a silent default.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel, JsonValue

from storyteller.agents.prompt_templates import PromptLibrary, package_prompts

__all__ = ["Refine", "SchemaContractError", "reply_schema", "schema_instruction"]

_DROPPED = ("title", "default")


class SchemaContractError(ValueError):
    """A model or a refinement that cannot give a schema a local model can be held to."""


@dataclass(frozen=True)
class Refine:
    """What one call adds to one field (named by its dotted path, e.g. ``event.characters``;
    arrays are walked through, so ``areas.objects`` is the objects of every area).

    For an array field ``enum`` restricts its items; for a scalar field, the field itself. An
    empty ``enum`` is only allowed on an array bounded to 0 items (it is then left out: an empty
    enum admits nothing)."""

    enum: Sequence[str | int] | None = None
    min_items: int | None = None
    max_items: int | None = None
    pin: tuple[str, Sequence[str | int]] | None = None
    """(field, values): the array has exactly one item per value, item ``i`` with
    ``field == values[i]`` (applied after ``enum`` and the bounds)."""


def reply_schema(model: type[BaseModel], refine: Mapping[str, Refine] | None = None) -> dict[str, Any]:
    """The JSON schema of ``model`` for a request, with ``refine``'s per-call facts injected."""
    raw = model.model_json_schema(mode="validation")
    defs = raw.pop("$defs", {})
    schema: dict[str, Any] = _strict_object(_inline_object(raw, defs), top=True)
    for path, rule in (refine or {}).items():
        _apply(schema, path, rule)
    _check_bounded(schema, model.__name__)
    return schema


def _inline(node: JsonValue, defs: Mapping[str, dict[str, JsonValue]]) -> JsonValue:
    """``node`` with every ``$ref`` replaced by its definition (a class docstring, the
    definition's description, gives way to the referring field's own description)."""
    if isinstance(node, list):
        return [_inline(v, defs) for v in node]
    if not isinstance(node, dict):
        return node
    return _inline_object(node, defs)


def _inline_object(node: dict[str, JsonValue], defs: Mapping[str, dict[str, JsonValue]]) -> dict[str, JsonValue]:
    if "$ref" in node:
        target = dict(defs[str(node["$ref"]).rsplit("/", 1)[-1]])
        target.pop("description", None)
        rest = {k: v for k, v in node.items() if k != "$ref"}
        return _inline_object({**target, **rest}, defs)
    return {k: _inline(v, defs) for k, v in node.items()}


def _strict(node: JsonValue) -> JsonValue:
    if isinstance(node, list):
        return [_strict(v) for v in node]
    if not isinstance(node, dict):
        return node
    return _strict_object(node)


def _strict_object(node: dict[str, JsonValue], *, top: bool = False) -> dict[str, JsonValue]:
    out = {k: _strict(v) for k, v in node.items() if k not in _DROPPED}
    properties = out.get("properties")
    if out.get("type") == "object" and isinstance(properties, dict):
        out["required"] = list(properties)
        out["additionalProperties"] = False
        if top:  # the reply model's own docstring is for developers
            out.pop("description", None)
    return out


def _field(schema: dict[str, Any], path: str) -> dict[str, Any]:
    node = schema
    for name in path.split("."):
        while node.get("type") == "array":
            node = node["items"]
        props = node.get("properties", {})
        if name not in props:
            raise SchemaContractError(f"no field {path!r} in the reply model (at {name!r}; fields: {sorted(props)})")
        node = props[name]
    return node


def _apply(schema: dict[str, Any], path: str, rule: Refine) -> None:
    node = _field(schema, path)
    is_array = node.get("type") == "array"
    if not is_array and (rule.min_items is not None or rule.max_items is not None):
        raise SchemaContractError(f"field {path!r} is not an array; it has no item bounds")
    if is_array and rule.max_items is not None:
        node["maxItems"] = min(node.get("maxItems", rule.max_items), max(0, rule.max_items))
    if is_array and rule.min_items is not None:
        node["minItems"] = max(node.get("minItems", 0), rule.min_items)
    if rule.enum is not None:
        values = list(dict.fromkeys(rule.enum))
        if not values:
            if not (is_array and node.get("maxItems") == 0):
                raise SchemaContractError(f"field {path!r}: an empty enum admits nothing")
            return
        target = node["items"] if is_array else node
        target["enum"] = values
    if is_array and node.get("minItems", 0) > node.get("maxItems", node.get("minItems", 0)):
        raise SchemaContractError(f"field {path!r}: minItems {node['minItems']} > maxItems {node['maxItems']}")
    if rule.pin is not None:
        _pin(node, path, *rule.pin)


def _pin(node: dict[str, Any], path: str, field: str, values: Sequence[str | int]) -> None:
    """Replace the array's ``items`` by one ``prefixItems`` entry per value (llama.cpp's
    schema converter reads ``prefixItems`` only when ``items`` is absent)."""
    items = node.get("items", {})
    if node.get("type") != "array" or field not in items.get("properties", {}):
        raise SchemaContractError(f"field {path!r}: cannot pin {field!r} (not an array of objects with that field)")
    if not values:
        raise SchemaContractError(f"field {path!r}: nothing to pin")
    del node["items"]
    node["prefixItems"] = [
        {**items, "properties": {**items["properties"], field: {**items["properties"][field], "const": v}}} for v in values
    ]
    node["minItems"] = node["maxItems"] = len(values)


def _check_bounded(node: JsonValue, where: str) -> None:
    if isinstance(node, list):
        for v in node:
            _check_bounded(v, where)
    elif isinstance(node, dict):
        if node.get("type") == "array" and "maxItems" not in node:
            raise SchemaContractError(
                f"{where}: an array has no maxItems; give the field a max_length or refine it per call"
            )
        for v in node.values():
            _check_bounded(v, where)


def schema_instruction(schema: Mapping[str, Any], prompts: PromptLibrary | None = None) -> str:
    """The message that carries ``schema`` to a provider that cannot decode under it
    (``prompts/llm/schema_instruction.md``; keys sorted, so the text is stable)."""
    return (prompts or package_prompts()).render_text("llm/schema_instruction.md", schema=json.dumps(schema, sort_keys=True))

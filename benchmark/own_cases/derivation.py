"""Evaluate a case's ``derivation`` block: which objects answer the instruction, from geometry and history.

A case of our set carries, next to the reference format's fields, a block such as::

    "derivation": {
      "plans": [{"character": "Ines", "field": "relationships", "relations": ["sit on"],
                 "count": "any",
                 "objects": {"free": {"and": [{"seats": true},
                                              {"related": "adjacent to", "to": {"label": "table"}}]}}}],
      "wait_for": null
    }

``objects`` is a query over the scene's object names; its value is computed here, never read
from the case. The atoms the case must expect are then every ``<relation> <object>`` (or one
``between a and b`` for two objects), joined by ``||``. Queries (each a JSON object):

- ``{"label": "chair"}`` / ``{"label": ["chair", "stool"]}``: objects with that label;
  ``{"seats": true}``: objects one can sit on;
- ``{"object": "chair_3"}``: one object, allowed only when the instruction names it verbatim
  (so a query cannot smuggle in its answer);
- ``{"related": "adjacent to", "to": Q}``: subjects of a scene-graph edge ``s --relation--> a``
  with ``a`` in Q (``related`` may be a list of relations); ``{"anchors_of": "on", "from": Q}``:
  the other end of such edges;
- ``{"region_of": Q}``: every object in a region cluster (``storyteller.tools.clusters``) holding a member of Q;
- ``{"nearest": Q, "to": R}`` / ``{"farthest": Q, "to": R}``: the members of Q whose footprint is
  nearest to (farthest from) R's; ties within 1 cm are all kept, so a tie shows up as ambiguity;
- ``{"and": [Q, ...]}``, ``{"or": [Q, ...]}``, ``{"minus": [Q, R]}``;
- ``{"free": Q}`` / ``{"in_use": Q}``: members of Q nobody sits on or uses (resp. somebody
  does), in the world the case's history and current states describe;
- ``{"seat_of": "Name"}``: the seat a character of the case sits on.

``wait_for`` (a query or null): the character needs one of these objects first; the case must
allow a null plan exactly when all of them are in use.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from storyteller.benchmark.reference_cases import BenchmarkCase, planning_inputs
from storyteller.sim.scene.model import Scene
from storyteller.sim.validation_text import user_error
from storyteller.tools.character_states import WorldView
from storyteller.tools.scene_graph import SceneGraph, footprint_distance

Query = Mapping[str, Any]
TIE_M = 0.01
"""Footprint distances (m) closer than this count as a tie for ``nearest`` / ``farthest``."""


class DerivationError(ValueError):
    """A derivation block that cannot be evaluated; the message names the case and the query."""


class PlanDerivation(BaseModel):
    """How one expected character's answer is derived."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    character: str
    field: Literal["relationships", "sampled_position"]
    relations: tuple[str, ...] = Field(min_length=1, description="atom relations, e.g. ['sit on']")
    objects: dict[str, Any] = Field(description="query for the answer objects")
    count: Literal["one", "any"] = Field("any", description="'one': the instruction names a single object")


class Derivation(BaseModel):
    """A case's ``derivation`` block."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    plans: tuple[PlanDerivation, ...] = ()
    wait_for: dict[str, Any] | None = None


@dataclass(frozen=True)
class CaseWorld:
    """What queries are evaluated against: the scene and the world of one case at one level."""

    scene: Scene
    graph: SceneGraph
    clusters: tuple[tuple[str, ...], ...]
    world: WorldView
    in_use: frozenset[str]
    instruction: str

    @classmethod
    def of(cls, case: BenchmarkCase, scene: Scene, graph: SceneGraph, clusters: list[list[str]]) -> CaseWorld:
        inputs = planning_inputs(case, scene)
        in_use = frozenset(inputs.seats_in_use) | frozenset(inputs.world.objects_in_use)
        return cls(scene, graph, tuple(tuple(c) for c in clusters), inputs.world, in_use, case.user_instruction)


def derivation_of(case: BenchmarkCase) -> Derivation:
    raw = case.raw.get("derivation")
    if raw is None:
        raise DerivationError(f"{case.source}: no 'derivation' block")
    try:
        return Derivation.model_validate(raw)
    except ValidationError as exc:
        raise DerivationError(user_error(case.source, exc, prefix="derivation")) from None


def _names(value: Any, key: str) -> tuple[str, ...]:
    items = value if isinstance(value, list) else [value]
    if not items or not all(isinstance(v, str) and v for v in items):
        raise DerivationError(f"'{key}' expects a name or a list of names, got {value!r}")
    return tuple(items)


def _distance_to(world: CaseWorld, name: str, targets: frozenset[str]) -> float:
    obj = world.scene.by_name[name]
    return min(footprint_distance(obj, world.scene.by_name[t]) for t in targets)


def evaluate(query: Query, world: CaseWorld) -> frozenset[str]:
    """The object names ``query`` selects (see the module docstring)."""
    if not isinstance(query, Mapping):
        raise DerivationError(f"a query is a JSON object, got {query!r}")
    keys = set(query)
    scene, graph = world.scene, world.graph

    def sub(key: str) -> frozenset[str]:
        if key not in query:
            raise DerivationError(f"query {dict(query)!r} needs '{key}'")
        return evaluate(query[key], world)

    if keys == {"label"}:
        labels = set(_names(query["label"], "label"))
        return frozenset(o.name for o in scene.objects if o.label in labels)
    if keys == {"seats"}:
        return frozenset(o.name for o in scene.objects if o.is_seat)
    if keys == {"object"}:
        (name,) = _names(query["object"], "object")
        if name not in scene.by_name:
            raise DerivationError(f"'object': the scene has no {name!r}")
        if name not in world.instruction:
            raise DerivationError(f"'object': {name!r} is not named in the instruction (describe it by a query)")
        return frozenset({name})
    if keys == {"related", "to"}:
        relations, anchors = set(_names(query["related"], "related")), sub("to")
        return frozenset(s for s, r, a in graph.triples() if r in relations and a in anchors)
    if keys == {"anchors_of", "from"}:
        relations, subjects = set(_names(query["anchors_of"], "anchors_of")), sub("from")
        return frozenset(a for s, r, a in graph.triples() if r in relations and s in subjects)
    if keys == {"region_of"}:
        members = sub("region_of")
        return frozenset(n for c in world.clusters if members & set(c) for n in c)
    if keys in ({"nearest", "to"}, {"farthest", "to"}):
        op = "nearest" if "nearest" in keys else "farthest"
        candidates, targets = sub(op), sub("to")
        if not candidates or not targets:
            raise DerivationError(f"'{op}': empty candidates or targets in {dict(query)!r}")
        sign = 1.0 if op == "nearest" else -1.0
        scored = {n: sign * _distance_to(world, n, targets) for n in candidates}
        best = min(scored.values())
        return frozenset(n for n, d in scored.items() if d <= best + TIE_M)
    if keys in ({"and"}, {"or"}):
        op = next(iter(keys))
        parts = query[op]
        if not isinstance(parts, list) or len(parts) < 2:
            raise DerivationError(f"'{op}' expects a list of at least two queries")
        values = [evaluate(p, world) for p in parts]
        result = values[0]
        for v in values[1:]:
            result = result & v if op == "and" else result | v
        return result
    if keys == {"minus"}:
        parts = query["minus"]
        if not isinstance(parts, list) or len(parts) != 2:
            raise DerivationError("'minus' expects [query, query]")
        return evaluate(parts[0], world) - evaluate(parts[1], world)
    if keys == {"free"}:
        return sub("free") - world.in_use
    if keys == {"in_use"}:
        return sub("in_use") & world.in_use
    if keys == {"seat_of"}:
        (name,) = _names(query["seat_of"], "seat_of")
        character = world.world.character(name)
        if character is None or character.seat is None:
            raise DerivationError(f"'seat_of': {name!r} is not a seated character of the case")
        return frozenset({character.seat})
    raise DerivationError(f"unknown query {dict(query)!r}")


def atoms_of(relations: tuple[str, ...], objects: frozenset[str]) -> frozenset[str]:
    """The expression atoms a derived answer stands for."""
    if relations == ("between",):
        if len(objects) != 2:
            raise DerivationError(f"'between' needs exactly two objects, derived {sorted(objects)}")
        a, b = sorted(objects)
        return frozenset({f"between {a} and {b}"})
    return frozenset(f"{r} {o}" for r in relations for o in objects)


def expression_atoms(expression: str) -> frozenset[str]:
    """Atoms of a disjunction ``a || b || c`` (normalised: spaces, ``between`` operands sorted).

    Our cases expect plain disjunctions; ``&&`` or parentheses are a DerivationError."""
    if "&&" in expression or "(" in expression or ")" in expression:
        raise DerivationError(f"expected a disjunction of atoms, got {expression!r}")
    atoms = set()
    for part in expression.split("||"):
        atom = " ".join(part.split())
        if atom.startswith("between ") and " and " in atom:
            a, b = atom[len("between "):].split(" and ", 1)
            a, b = sorted((a, b))
            atom = f"between {a} and {b}"
        if not atom:
            raise DerivationError(f"empty atom in {expression!r}")
        atoms.add(atom)
    return frozenset(atoms)

"""Writing a :class:`Draft` as a case: named characters, the sentence, the level-1 / level-2
distractors and the expected plan, as the JSON data of a case file.

Guarantee: deterministic (every random draw comes from a stream seeded by
:data:`GENERATOR_SEED`, the draft and the attempt); a distractor never uses or stands at an
object the question is about (:class:`NoDistractorError` when none is left); the expected answer
is the draft's query evaluated in the world of the case written (who sits where).
"""

from __future__ import annotations

import json
import random
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from storyteller.benchmark.own_cases.derivation import CaseWorld, atoms_of, evaluate
from storyteller.benchmark.own_cases.drafts import Draft, Query
from storyteller.benchmark.own_cases.phrasing import DEVICE_USES, NAMES, SEATED, SHAPES, third_person
from storyteller.benchmark.own_cases.scene_facts import SEATS, SceneFacts, activities
from storyteller.benchmark.own_cases.split import Side, on_side
from storyteller.benchmark.reference_cases import BenchmarkCase

GENERATOR_SEED = 24
"""Seed of every random stream of the generator (with the draft, the attempt or the group)."""


def _fill(query: Any, names: list[str]) -> Any:
    """``query`` with ``$k`` placeholders replaced by the k-th occupant's name."""
    if isinstance(query, str) and query.startswith("$"):
        return names[int(query[1:])]
    if isinstance(query, Mapping):
        return {k: _fill(v, names) for k, v in query.items()}
    if isinstance(query, list):
        return [_fill(v, names) for v in query]
    return query


def _join(names: list[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


@dataclass(frozen=True)
class Chore:
    """Something a distractor can be doing (or have done)."""

    action: str
    position: str
    activity: str
    obj: str
    look: str | None


def _chores(facts: SceneFacts) -> list[Chore]:
    out = []
    for label, uses in DEVICE_USES.items():
        for obj in sorted(o.name for o in facts.scene.objects if o.label == label):
            for action, phrases in uses:
                if action in facts.actions:
                    out.append(Chore(action, f"adjacent to {obj}", activities(phrases, label)[-1], obj, obj))
    for seat in sorted(facts.eval(SEATS)):
        for action, phrases in SEATED.items():
            if action in facts.actions:
                out.append(Chore(action, f"sit on {seat}", phrases[-1], seat, None))
    return out


def _answer_objects(draft: Draft, facts: SceneFacts, names: list[str]) -> frozenset[str]:
    found: set[str] = set()
    for query in (draft.objects, draft.wait_for):
        if query is not None:
            found |= facts.eval(_fill(query, names)) if "seat_of" not in json.dumps(query) else set()
    return frozenset(found)


class NoDistractorError(ValueError):
    """The scene has no object left that a distractor could use without touching the question."""


def write_case(draft: Draft, facts: SceneFacts, case_id: int, shape_id: str, side: Side, attempt: int) -> dict[str, Any]:
    """The case of ``draft`` on ``side`` as JSON data (names, distractors and words drawn from
    ``attempt``'s stream; the activity from the phrases dealt to ``side``)."""
    rng = random.Random(f"{GENERATOR_SEED}:{draft.scene}:{draft.recipe}:{draft.key}:{attempt}")
    n_distractors = 2 + rng.randrange(2)
    people = rng.sample(NAMES, 1 + len(draft.occupants) + n_distractors)
    actor, occupant_names, distractors = people[0], people[1:1 + len(draft.occupants)], people[1 + len(draft.occupants):]
    choices = dict(draft.slots)
    if "act" in choices:
        phrases = on_side(choices["act"], "act:" + "|".join(sorted(choices["act"])), side)
        choices["act"] = activities(tuple(phrases), draft.noun)
    slots = {k: rng.choice(v) for k, v in sorted(choices.items())}
    if "act" in slots:
        slots["act3"] = third_person(slots["act"])
    slots |= {"who": actor, "others": _join(occupant_names) if occupant_names else "",
              "friend": occupant_names[0] if occupant_names else "",
              "are": "is" if len(occupant_names) == 1 else "are", "have": "has" if len(occupant_names) == 1 else "have"}
    recipe, letter = shape_id.rsplit(".", 1)
    text = SHAPES[recipe][letter].format(**slots)
    text = text[0].upper() + text[1:]

    history: list[dict[str, Any]] = []
    states: list[dict[str, Any]] = [_state(0, actor, 0, "idle", "idle", [])]
    for name, occ in zip(occupant_names, draft.occupants, strict=True):
        history.append(_event(0, "ongoing" if occ.ongoing else "completed", name, occ.activity, occ.action,
                              occ.position, _look(occ.position)))
        states.append(_state(len(states), name, 0, "interacting" if occ.ongoing else "idle",
                             occ.action if occ.ongoing else "idle", [occ.position]))
    busy = set(draft.avoid) | _answer_objects(draft, facts, occupant_names)
    busy |= {o.position.split(" ", 2)[-1] for o in draft.occupants}
    chores = [c for c in _chores(facts) if c.obj not in busy]
    rng.shuffle(chores)
    used: set[str] = set()
    picked: list[tuple[str, int, Chore, bool]] = []
    for i, name in enumerate(distractors):
        level = 1 if i == 0 else 2
        chore = next((c for c in chores if c.obj not in used), None)
        if chore is None:
            raise NoDistractorError(f"{draft.scene}: no object left for distractor {name} of {draft.recipe} {draft.key}")
        used.add(chore.obj)
        done = level == 2 and i == len(distractors) - 1 and chore.position.startswith("adjacent")
        picked.append((name, level, chore, done))
    for name, level, chore, done in picked:
        history.append(_event(level, "completed" if done else "ongoing", name, chore.activity, chore.action,
                              chore.position, chore.look))
        states.append(_state(len(states), name, level, "idle" if done else "interacting",
                             "idle" if done else chore.action, [chore.position]))
    rng.shuffle(history)
    for i, event in enumerate(history):
        event["idx"] = i

    names = occupant_names
    plans = []
    expected: dict[str, Any] = {"character": actor, "target_action": draft.action, "relationships": None,
                                "sampled_position": None}
    if draft.objects is not None:
        objects = _fill(draft.objects, names)
        plans.append({"character": actor, "field": draft.field, "relations": list(draft.relations),
                      "objects": objects, "count": draft.count})
        expected[draft.field] = " || ".join(sorted(atoms_of(draft.relations, _world_eval(facts, objects, states, history))))
    return {
        "id": case_id,
        "tags": draft.group.split("+"),
        "scene_name": facts.scene_name,
        "action_labels": list(facts.actions),
        "user_instruction": text,
        "planning_history": history,
        "current_states": states,
        "expected_plans": [expected],
        "allow_null_plan": draft.wait_for is not None,
        "derivation": {"plans": plans, "wait_for": _fill(draft.wait_for, names)},
        "generated": {"recipe": draft.recipe, "shape": shape_id, "key": draft.key, "side": side},
    }


def _world_eval(facts: SceneFacts, query: Query, states: list[dict[str, Any]], history: list[dict[str, Any]]) -> frozenset[str]:
    """``query`` evaluated in the world of the case being written (who sits where)."""
    case = as_case({"id": 0, "tags": ["OA"], "scene_name": facts.scene_name, "action_labels": [],
                     "user_instruction": "", "planning_history": history, "current_states": states,
                     "expected_plans": []}, "x")
    world = CaseWorld.of(case, facts.scene, facts.graph, facts.clusters)
    return evaluate(query, world)


def _look(position: str) -> str | None:
    return None if position.startswith("sit on") else position.split(" ", 2)[-1]


def _event(level: int, state: str, name: str, activity: str, action: str, position: str, look: str | None) -> dict[str, Any]:
    return {"idx": 0, "type": "essential" if level == 0 else "distractor", "distraction_level": level, "state": state,
            "characters": [name], "activity": activity,
            "details": [{"character": name, "target_action": action, "position": [position],
                         "orientation": [f"look at {look}"] if look else []}]}


def _state(idx: int, name: str, level: int, state: str, action: str, position: list[str]) -> dict[str, Any]:
    return {"idx": idx, "type": "essential" if level == 0 else "distractor", "distraction_level": level, "name": name,
            "state": state, "current_action": action, "position": position, "orientation": []}


def as_case(data: dict[str, Any], folder: str) -> BenchmarkCase:
    source = f"{folder}/testcase_{data['id']}.json"
    return BenchmarkCase.model_validate({**data, "source": source, "raw": data})

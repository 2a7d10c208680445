"""The evaluator (``storyteller.benchmark.plan_scoring.score_outcome``) agrees with an independent scorer
(``tests/support/independent_scorer.py``, written from the benchmark rules alone) on plans
neither was written against.

For every case of the authors' set and of ours, a seeded generator writes many plans: the
expected plan (each ``||`` alternative), and mutations of it: another action label, a label
from an ``||`` alternative, another seat of the same kind, a seat someone else sits on,
positions just inside and just outside each atom's threshold (5 mm either side), a character
left out, an extra character, two characters on one seat, null plans and planning failures,
positions inside furniture, and random points in the room. Both scorers must give the same
verdict, and the evaluator's failure classes (action, relationship, collision with an object or
a character, a missing character, a null plan) must be the independent scorer's.
"""

from __future__ import annotations

import math
import random
import re
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import cache, partial
from pathlib import Path
from typing import Any

import pytest

from storyteller.agents.messages import Event, ParsedEvent, PlannedCharacter, PlanningFailure
from storyteller.benchmark.plan_scoring import CaseScore, score_outcome
from storyteller.benchmark.reference_cases import BenchmarkCase, load_cases, planning_inputs, scene_dir
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene
from storyteller.tools.character_states import WorldView
from tests.support import independent_scorer as ind
from tests.support.reference import reference_or_skip

OURS = Path(__file__).resolve().parents[2] / "benchmark" / "cases" / "ours"
EPS = 0.005
"""Metres either side of a threshold for the jittered positions (the two agree at 2 mm too)."""
RANDOM_POINTS = 12
"""Random standing points per case and level (on top of the targeted mutations)."""

_SEAT_ATOM = re.compile(r"^(?:sit on|lie on) (\S+)$")


@dataclass(frozen=True)
class Trial:
    """One generated plan: what it is (for messages) and the outcome both scorers judge."""

    what: str
    plans: tuple[ind.Plan, ...] | None
    failed: bool = False


# ----------------------------------------------------------------------------- the two verdicts


def _outcome(trial: Trial) -> ParsedEvent | PlanningFailure | None:
    if trial.failed:
        return PlanningFailure(index=0, node="event_parser", attempts=4, feedback="no program")
    if trial.plans is None:
        return None
    plans = tuple(PlannedCharacter(character=p.character, action=p.action, position=p.position,
                                   facing=(1.0, 0.0), seat=p.seat) for p in trial.plans)
    return ParsedEvent(index=0, event=Event(characters=tuple(p.character for p in plans), activity="generated"),
                       plans=plans)


def evaluator_classes(score: CaseScore, people: set[str]) -> frozenset[str]:
    """The failure classes of a :class:`CaseScore`, read from its reason texts."""
    if score.kind == "failure":
        return frozenset({"failure"})
    if score.kind == "wait":
        return frozenset({"wait"} if score.passed else {"null_plan"})
    found: set[str] = set()
    for v in score.characters:
        if v.passed:
            continue
        if v.reason.startswith("no plan for"):
            found.add("missing_character")
        if "action '" in v.reason:
            found.add("action")
        if " is not '" in v.reason:
            found.add("relationship")
        if v.collision is not None:
            found.add("collision_character" if v.collision in people else "collision_object")
    return frozenset(found)


def comparable(reasons: frozenset[str]) -> frozenset[str]:
    """The evaluator names one collision per character (an object before a character): drop a
    character collision that comes with an object collision."""
    if "collision_object" in reasons:
        return reasons - {"collision_character"}
    return reasons


# ----------------------------------------------------------------------------- generating plans


def _tree_alternatives(tree: ind.Node) -> list[ind.Node]:
    return list(tree.kids) if tree.op == "or" else [tree]


def _march(f: Callable[[ind.Point], float], start: ind.Point, target: float,
           rng: random.Random) -> ind.Point | None:
    """A point on a random ray from ``start`` (where ``f`` is 0) at which ``f`` equals ``target``
    (bisection; ``f`` is a distance to a convex region, so it grows along the ray)."""
    a = rng.uniform(0.0, 2.0 * math.pi)
    d = (math.cos(a), math.sin(a))

    def at(r: float) -> ind.Point:
        return (start[0] + r * d[0], start[1] + r * d[1])

    lo, hi = 0.0, 0.5
    while f(at(hi)) < target:
        lo, hi = hi, hi * 2.0
        if hi > 64.0:
            return None
    for _ in range(50):
        mid = (lo + hi) / 2.0
        if f(at(mid)) < target:
            lo = mid
        else:
            hi = mid
    return at((lo + hi) / 2.0)


def _inner_point(boxes: dict[str, ind.Box], text: str) -> ind.Point | None:
    """A point where the atom's raw distance is 0 (the start of the jitter rays)."""
    m = ind._ATOM.match(text)
    if m is None:
        return None
    if m.group(3):
        a, b = boxes[m.group(3)].c, boxes[m.group(4)].c
        return ((a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0)
    rel, box = m.group(1), boxes[m.group(2)]
    if rel in ("sit on", "lie on"):
        return None
    side = ind._SIDES.get(rel)
    if side is None:
        return box.c
    s = side[0] * (box.hd + 0.3)
    t = side[1] * (box.hw + 0.3)
    return box.world(s, t)


def _standing_candidates(boxes: dict[str, ind.Box], tree: ind.Node, rng: random.Random,
                         bounds: tuple[float, float, float, float], n: int = 400) -> list[ind.Point]:
    """Random points near the expression's anchors (and anywhere in the room)."""
    names = [w for t in ind.atom_texts(tree) for w in t.split() if w in boxes]
    x0, y0, x1, y1 = bounds
    points = []
    for _ in range(n):
        if names and rng.random() < 0.85:
            c = boxes[rng.choice(names)].c
            r, a = rng.uniform(0.0, 2.5), rng.uniform(0.0, 2.0 * math.pi)
            points.append((c[0] + r * math.cos(a), c[1] + r * math.sin(a)))
        else:
            points.append((rng.uniform(x0, x1), rng.uniform(y0, y1)))
    return points


def _bounds(boxes: dict[str, ind.Box]) -> tuple[float, float, float, float]:
    xs = [p[0] for b in boxes.values() for p in b.corners()]
    ys = [p[1] for b in boxes.values() for p in b.corners()]
    return min(xs), min(ys), max(xs), max(ys)


def generate(case: dict[str, Any], boxes: dict[str, ind.Box], others: dict[str, list[ind.Point]],
             rng: random.Random) -> Iterator[Trial]:
    """The plans of one case (see the module docstring), deterministic for ``rng``'s seed."""
    expected = case["expected_plans"]
    labels = list(case["action_labels"])
    names = [c["name"] for c in case["current_states"]]
    bounds = _bounds(boxes)
    occupied = ind.occupied_seats(case)

    def passes_alone(character: str, plan: ind.Plan, fixed: Sequence[ind.Plan]) -> bool:
        return ind.score({**case, "expected_plans": [e for e in expected if e["character"] == character]},
                         boxes, [*fixed, plan], others).passed

    def first_action(e: dict[str, Any]) -> str:
        if not e.get("target_action"):
            return str(rng.choice(labels))
        return next(iter(ind.atom_texts(ind.parse(str(e["target_action"])))))

    # one good plan per alternative of the first character, the others fixed to a good plan
    base: list[ind.Plan] = []
    options: dict[str, list[ind.Plan]] = {}
    for e in expected:
        expr = e.get("relationships") or e.get("sampled_position")
        action = first_action(e)
        good: list[ind.Plan] = []
        if expr:
            tree = ind.parse(expr)
            for alt in _tree_alternatives(tree):
                seats = [m.group(1) for t in ind.atom_texts(alt) if (m := _SEAT_ATOM.match(t))]
                if seats:
                    plan = ind.Plan(e["character"], action, boxes[seats[0]].seat_point(), seats[0])
                    if passes_alone(e["character"], plan, base):
                        good.append(plan)
                    continue
                sub = ind.Node("or", kids=(alt,))
                for p in _standing_candidates(boxes, sub, rng, bounds):
                    plan = ind.Plan(e["character"], action, p)
                    if passes_alone(e["character"], plan, base):
                        good.append(plan)
                        break
        else:
            for p in _standing_candidates(boxes, ind.Node("atom", text=""), rng, bounds):
                plan = ind.Plan(e["character"], action, p)
                if passes_alone(e["character"], plan, base):
                    good.append(plan)
                    break
        options[e["character"]] = good
        if good:
            base.append(good[0])

    def with_plan(plan: ind.Plan) -> tuple[ind.Plan, ...]:
        return tuple(plan if q.character == plan.character else q for q in base)

    yield Trial("expected", tuple(base))
    first = expected[0]["character"]
    for i, plan in enumerate(options.get(first, [])[1:], 1):
        yield Trial(f"alternative {i}", with_plan(plan))

    for e in expected:
        mine = next((q for q in base if q.character == e["character"]), None)
        if mine is None:
            continue
        # actions: every other label once in a while, every || alternative
        if e.get("target_action"):
            alts = list(ind.atom_texts(ind.parse(e["target_action"])))
            for label in alts[1:]:
                yield Trial(f"action alternative {label}", with_plan(ind.Plan(mine.character, label, mine.position, mine.seat)))
            wrong = [x for x in labels if x not in alts]
            for label in rng.sample(wrong, min(3, len(wrong))):
                yield Trial(f"action {label}", with_plan(ind.Plan(mine.character, label, mine.position, mine.seat)))
        # seats: another of the same kind, one someone sits on
        if mine.seat is not None:
            kind = mine.seat.rsplit("_", 1)[0]
            same = [b for b in boxes if b.rsplit("_", 1)[0] == kind and b != mine.seat]
            for seat in rng.sample(same, min(3, len(same))):
                yield Trial(f"seat {seat}", with_plan(ind.Plan(mine.character, mine.action, boxes[seat].seat_point(), seat)))
            seats = sorted(b.name for b in boxes.values() if b.sit_offset > 0.0 and b.name != mine.seat)
            for seat in rng.sample(seats, min(2, len(seats))):
                yield Trial(f"any seat {seat}", with_plan(ind.Plan(mine.character, mine.action, boxes[seat].seat_point(), seat)))
            for seat, holder in occupied.items():
                if holder != mine.character and seat in boxes:
                    yield Trial(f"seat {seat} of {holder}",
                                with_plan(ind.Plan(mine.character, mine.action, boxes[seat].seat_point(), seat)))
            yield Trial("stands at its seat", with_plan(ind.Plan(mine.character, mine.action, mine.position)))
        # thresholds: 2 cm inside and outside each geometric atom
        expr = e.get("relationships") or e.get("sampled_position")
        for text in sorted(set(ind.atom_texts(ind.parse(expr)))) if expr else []:
            start = _inner_point(boxes, text)
            if start is None:
                continue
            assert ind.atom_error(boxes, text, start, None) == 0.0
            tolerance = ind.tolerance(text)
            for k in range(3):
                for sign, word in ((-1.0, "inside"), (1.0, "outside")):
                    edge = _march(partial(ind.atom_distance, boxes, text), start, tolerance + sign * EPS, rng)
                    if edge is not None:
                        yield Trial(f"{word} '{text}' #{k}", with_plan(ind.Plan(mine.character, mine.action, edge)))
        # inside furniture
        for box in rng.sample(sorted(boxes.values(), key=lambda b: b.name), min(4, len(boxes))):
            yield Trial(f"inside {box.name}", with_plan(ind.Plan(mine.character, mine.action, box.c)))
        # random standing points
        for k in range(RANDOM_POINTS):
            p = (rng.uniform(bounds[0], bounds[2]), rng.uniform(bounds[1], bounds[3]))
            yield Trial(f"random #{k}", with_plan(ind.Plan(mine.character, mine.action, p)))
        # a character left out
        yield Trial(f"without {mine.character}", tuple(q for q in base if q.character != mine.character) or None)

    # extra characters: a case character that is not expected, or a stranger; two on one seat
    spare = [n for n in names if n not in {e["character"] for e in expected}] + ["Stranger"]
    for name in spare[:3]:
        for k in range(2):
            p = (rng.uniform(bounds[0], bounds[2]), rng.uniform(bounds[1], bounds[3]))
            yield Trial(f"extra {name} #{k}", (*base, ind.Plan(name, rng.choice(labels), p)))
        if base:
            near = base[0].position
            yield Trial(f"extra {name} next to {base[0].character}",
                        (*base, ind.Plan(name, "idle", (near[0] + 0.3, near[1]))))
    if len(base) >= 2 and base[0].seat is not None:
        yield Trial("two on one seat", (base[0], ind.Plan(base[1].character, base[1].action, base[0].position, base[0].seat)))
    # null plans and failures
    yield Trial("null plan", None)
    yield Trial("event with no plans", ())
    yield Trial("failure", None, failed=True)


# ----------------------------------------------------------------------------- running both


@dataclass(frozen=True)
class Disagreement:
    case: int
    level: int
    what: str
    evaluator: tuple[bool, frozenset[str]]
    independent: tuple[bool, frozenset[str]]
    reason: str


@cache
def _scene(path: Path) -> tuple[Scene, dict[str, ind.Box]]:
    return load_scene(path), ind.load_boxes(path)


def compare_case(root: Path, case: BenchmarkCase, level: int, seed: int,
                 tally: Counter[str]) -> list[Disagreement]:
    """Judge every generated plan of ``case`` at ``level`` with both scorers."""
    case = case.at_level(level)
    scene, boxes = _scene(scene_dir(root, case))
    world: WorldView = planning_inputs(case, scene).world
    others = {c.name: [p for p in (c.position, c.target_position) if p is not None] for c in world.characters}
    people = set(others) | {e.character for e in case.expected_plans} | {"Stranger"}
    found = []
    for trial in generate(case.raw, boxes, others, random.Random(seed)):
        ours = score_outcome(case, scene, _outcome(trial), world=world)
        theirs = ind.score(case.raw, boxes, trial.plans, others, failed=trial.failed)
        a = (ours.passed, comparable(evaluator_classes(ours, people)))
        b = (theirs.passed, comparable(theirs.reasons))
        tally["plans"] += 1
        tally["pass" if b[0] else "fail"] += 1
        for r in b[1]:
            tally[r] += 1
        if a != b:
            found.append(Disagreement(case.id, level, trial.what, a, b, ours.reason))
    return found


def _run(root: Path, cases: list[BenchmarkCase]) -> tuple[list[Disagreement], Counter[str]]:
    tally: Counter[str] = Counter()
    found: list[Disagreement] = []
    for case in cases:
        levels = range(case.level + 1)
        for level in levels:
            found += compare_case(root, case, level, seed=case.id * 10 + level, tally=tally)
    return found, tally


def _report(found: list[Disagreement], tally: Counter[str]) -> str:
    lines = [f"{len(found)} of {tally['plans']} plans disagree ({dict(tally)})"]
    lines += [f"  case {d.case} level {d.level} {d.what}: evaluator {d.evaluator[0]} {sorted(d.evaluator[1])}, "
              f"independent {d.independent[0]} {sorted(d.independent[1])}; evaluator says: {d.reason[:160]}"
              for d in found[:15]]
    return "\n".join(lines)


def _check_mix(tally: Counter[str]) -> None:
    """The generator must exercise passes and every failure class, or agreement means little."""
    for key in ("pass", "action", "relationship", "collision_object", "collision_character",
                "missing_character", "null_plan", "failure"):
        assert tally[key] >= 3, f"too few plans of class {key}: {dict(tally)}"
    assert tally["pass"] >= tally["plans"] // 10, dict(tally)


def test_agreement_on_reference_cases() -> None:
    root = reference_or_skip()
    found, tally = _run(root, load_cases(root))
    print(_report(found, tally))
    _check_mix(tally)
    assert not found, _report(found, tally)


@pytest.mark.slow
def test_agreement_on_our_cases() -> None:
    found, tally = _run(OURS, load_cases(OURS))
    print(_report(found, tally))
    _check_mix(tally)
    assert not found, _report(found, tally)


def test_the_independent_scorer_imports_no_project_code() -> None:
    """Its independence is structural: only the standard library."""
    import ast
    import sys

    tree = ast.parse(Path(ind.__file__).read_text(encoding="utf-8"))
    modules = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    modules |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert {m.split(".")[0] for m in modules} <= set(sys.stdlib_module_names) | {"__future__"}, modules

"""Score one planning outcome against a reference test case's expected plans.

A run **executes** when the planner returned a plan or a wait (no
:class:`~storyteller.agents.messages.PlanningFailure`: every retry of every role used up, or a model
outage). A run **passes** when it executes and:

- it is a wait (no event, or an event with no plans) and the case allows a null plan
  (``allow_null_plan``); a wait where a plan was expected fails; or
- for every expected character there is a plan for that character whose action matches the
  ``target_action`` expression (labels under ``||``, ``&&``, ``!`` and parentheses; grammar in
  :mod:`storyteller.benchmark.expressions`), and whose sampled position satisfies the ``relationships``
  expression (or, in PI cases, the ``sampled_position`` expression) by
  :func:`storyteller.benchmark.position_check.check_position`, with the reference thresholds (directional
  0.1 m, adjacent 0.7 m, close 1.4 m, inside 0.1 m; "close to X" accepts "adjacent to X",
  "inside X" accepts sitting or lying on X) and without collision: not inside floor-standing
  furniture and not within 0.5 m of another character (where the characters outside the event
  are, from the case's states, and where the other planned characters go). "sit on X" holds
  exactly when the plan took seat X. Each character's verdict carries the error in metres.

Unlike the reference scorer, relationships are judged on the position the spatial API sampled,
not on the text of the area the program named: a program reaching the right spot through
another object passes, a program naming the right area whose sample lands elsewhere fails.

A malformed expected expression is a bug in the case file, not a failed run: it raises
:class:`ExpectedPlanError` naming the file, the character, the field and the column.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field

from storyteller.agents.messages import ParsedEvent, PlannedCharacter, PlanningFailure
from storyteller.benchmark.expressions import Expr, ExpressionError, atoms, evaluate, parse_expression
from storyteller.benchmark.position_check import (
    CHARACTER_CLEARANCE,
    CheckResult,
    check_collision,
    check_position,
    parse_position_expression,
)
from storyteller.benchmark.reference_cases import BenchmarkCase, planning_inputs
from storyteller.sim.scene.model import Scene
from storyteller.tools.character_states import WorldView

Outcome = ParsedEvent | PlanningFailure | None
_LABEL = re.compile(r"[A-Za-z0-9_]+")


class ActionExpressionError(ExpressionError):
    """An action expression that cannot be parsed; the message names the expression and column."""


class ExpectedPlanError(ValueError):
    """A case whose expected plan cannot be judged: names the file, character, field and why."""


def parse_action_expression(expression: str) -> Expr:
    """The tree of an action expression; every atom must be one label (letters, digits, ``_``)."""
    tree = parse_expression(expression, error=ActionExpressionError)
    for atom in atoms(tree):
        if not _LABEL.fullmatch(atom.text):
            raise ActionExpressionError(f"'{atom.text}' is not an action label", expression, atom.column)
    return tree


def action_matches(expression: str, action: str) -> bool:
    """Whether ``action`` satisfies an expression such as ``order_food || !eat``.

    A label holds when it is the action; ``a && b`` over two different labels never holds."""
    return evaluate(parse_action_expression(expression), lambda atom: atom.text == action)


def check_expected_plans(case: BenchmarkCase, scene: Scene) -> None:
    """Raise :class:`ExpectedPlanError` unless every expected expression of ``case`` parses, its
    action labels are among the case's ``action_labels`` and its objects are in ``scene``."""
    for expected in case.expected_plans:
        where = f"{case.source or f'case {case.id}'}: expected plan of {expected.character}"
        if expected.target_action:
            try:
                tree = parse_action_expression(expected.target_action)
            except ActionExpressionError as exc:
                raise ExpectedPlanError(f"{where}, field 'target_action': {exc}") from None
            unknown = [a.text for a in atoms(tree) if a.text not in case.action_labels]
            if unknown:
                raise ExpectedPlanError(f"{where}, field 'target_action': label(s) {unknown} not in the "
                                        "case's action_labels")
        for name, expression in (("relationships", expected.relationships),
                                 ("sampled_position", expected.sampled_position)):
            if expression:
                try:
                    parse_position_expression(scene, expression)
                except ExpressionError as exc:
                    raise ExpectedPlanError(f"{where}, field '{name}': {exc}") from None


@dataclass(frozen=True)
class CharacterVerdict:
    character: str
    passed: bool
    reason: str
    error: float | None = None
    """Metres the position is off its expression (the largest over the expressions checked);
    None when no position expression applied or the character had no plan."""
    collision: str | None = None
    """The object or character the position collides with, if any."""


@dataclass(frozen=True)
class CaseScore:
    """The verdict of one run of one case."""

    case: int
    executed: bool
    passed: bool
    kind: str  # "event", "wait" or "failure"
    reason: str
    characters: tuple[CharacterVerdict, ...] = field(default=())


def others_for(
    character: str, plans: Sequence[PlannedCharacter], world: WorldView
) -> tuple[tuple[str, tuple[float, float]], ...]:
    """Where every other character will be: the other planned characters at their targets, the
    characters outside the event where they are (and where they walk to)."""
    planned = {p.character for p in plans}
    points = [(p.character, p.position) for p in plans if p.character != character]
    for c in world.characters:
        if c.name not in planned:
            points += [(c.name, p) for p in (c.position, c.target_position) if p is not None]
    return tuple(points)


def _judge_character(
    case: BenchmarkCase, scene: Scene, plan: PlannedCharacter, others: Sequence[tuple[str, tuple[float, float]]]
) -> CharacterVerdict:
    expected = next(e for e in case.expected_plans if e.character == plan.character)
    problems: list[str] = []
    if expected.target_action and not action_matches(expected.target_action, plan.action):
        problems.append(f"action '{plan.action}' does not match '{expected.target_action}'")
    where = f"seat {plan.seat}" if plan.seat else f"[{plan.position[0]:.2f}, {plan.position[1]:.2f}]"
    results: list[tuple[str, CheckResult]] = []
    for expression in (expected.relationships, expected.sampled_position):
        if expression:
            try:
                results.append((expression, check_position(scene, expression, plan.position, seat=plan.seat,
                                                           others=others)))
            except ExpressionError as exc:
                raise ExpectedPlanError(f"{case.source}: expected plan of {plan.character}: {exc}") from None
    if not results:  # no position asked for: the plan must still not collide
        results.append(("", check_collision(scene, plan.position, seat=plan.seat, others=others)))
    for expression, result in results:
        if expression and not result.relation_passed:
            off = f" (off by {result.error:.2f} m)" if result.error > 0 else ""
            problems.append(f"{where} is not '{expression}'{off}")
    hit = next((r for _, r in results if r.collision is not None), None)
    if hit is not None:
        if hit.collision_kind == "character":
            problems.append(f"position collides with {hit.collision} ({CHARACTER_CLEARANCE - hit.collision_depth:.2f} m "
                            f"apart, {CHARACTER_CLEARANCE:.2f} m needed)")
        else:
            problems.append(f"position collides with {hit.collision} ({hit.collision_depth:.2f} m inside)")
    error = max((r.error for e, r in results if e), default=None)
    return CharacterVerdict(plan.character, not problems, "; ".join(problems) or "ok", error,
                            None if hit is None else hit.collision)


def score_outcome(
    case: BenchmarkCase, scene: Scene, outcome: Outcome, *, world: WorldView | None = None
) -> CaseScore:
    """Judge one planning outcome (see the module docstring). ``world``: the characters as the
    planner saw them (default: :func:`storyteller.benchmark.reference_cases.planning_inputs` of the case,
    which is what the benchmark gives the planner)."""
    if isinstance(outcome, PlanningFailure):
        return CaseScore(case.id, False, False, "failure",
                         f"{outcome.node} failed after {outcome.attempts} attempts: {outcome.feedback[:200]}")
    if outcome is None or not outcome.plans:
        ok = case.allow_null_plan
        return CaseScore(case.id, True, ok, "wait", "waiting is allowed" if ok else "waited, but a plan was expected")
    if world is None:
        world = planning_inputs(case, scene).world
    plans = {p.character: p for p in outcome.plans}
    verdicts = []
    for expected in case.expected_plans:
        plan = plans.get(expected.character)
        if plan is None:
            verdicts.append(CharacterVerdict(expected.character, False,
                                             f"no plan for {expected.character} (event: {', '.join(outcome.event.characters) or 'none'})"))
            continue
        verdicts.append(_judge_character(case, scene, plan, others_for(plan.character, outcome.plans, world)))
    passed = all(v.passed for v in verdicts)
    reason = "ok" if passed else "; ".join(f"{v.character}: {v.reason}" for v in verdicts if not v.passed)
    return CaseScore(case.id, True, passed, "event", reason, tuple(verdicts))


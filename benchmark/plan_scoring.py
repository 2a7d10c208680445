"""Score one planning outcome against a reference test case's expected plans.

A run **executes** when the planner returned a plan or a wait (no
:class:`~agents.messages.PlanningFailure`: every retry of every role used up, or a model
outage). A run **passes** when it executes and:

- it is a wait and the case allows a null plan; or
- for every expected character there is a plan for that character whose action matches the
  ``target_action`` expression (``||`` / ``&&`` / parentheses over labels), and whose sampled
  position satisfies the ``relationships`` expression (or, in PI cases, the
  ``sampled_position`` expression) by :func:`benchmark.position_check.check_position`, with
  the reference thresholds (directional 0.1 m, adjacent 0.7 m, close 1.4 m; "close to X"
  accepts "adjacent to X") and without collision. "sit on X" holds exactly when the plan took
  seat X.

Unlike the reference scorer, relationships are judged on the position the spatial API sampled,
not on the text of the area the program named: a program reaching the right spot through
another object passes, a program naming the right area whose sample lands elsewhere fails.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from agents.messages import ParsedEvent, PlanningFailure
from benchmark.position_check import PositionExpressionError, check_position
from benchmark.reference_cases import BenchmarkCase
from sim.scene.model import Scene

Outcome = ParsedEvent | PlanningFailure | None
_TOKENS = re.compile(r"(\|\||&&|\(|\))")


class ActionExpressionError(ValueError):
    """An action expression that cannot be parsed."""


def action_matches(expression: str, action: str) -> bool:
    """Whether ``action`` satisfies an expression such as ``order_food || order_drink``.

    ``&&`` binds tighter than ``||``; ``a && b`` over single labels only holds when a == b."""
    tokens = [t.strip() for t in _TOKENS.split(expression) if t.strip()]
    pos = 0

    def parse_or() -> bool:
        nonlocal pos
        value = parse_and()
        while pos < len(tokens) and tokens[pos] == "||":
            pos += 1
            value = parse_and() or value
        return value

    def parse_and() -> bool:
        nonlocal pos
        value = parse_atom()
        while pos < len(tokens) and tokens[pos] == "&&":
            pos += 1
            value = parse_atom() and value
        return value

    def parse_atom() -> bool:
        nonlocal pos
        if pos >= len(tokens):
            raise ActionExpressionError(f"expression ends too early: {expression!r}")
        token = tokens[pos]
        pos += 1
        if token == "(":
            value = parse_or()
            if pos >= len(tokens) or tokens[pos] != ")":
                raise ActionExpressionError(f"missing ')' in {expression!r}")
            pos += 1
            return value
        if token in ("||", "&&", ")") or not re.fullmatch(r"[A-Za-z0-9_]+", token):
            raise ActionExpressionError(f"unexpected {token!r} in {expression!r}")
        return token == action

    if not tokens:
        raise ActionExpressionError("empty action expression")
    result = parse_or()
    if pos != len(tokens):
        raise ActionExpressionError(f"unexpected {tokens[pos]!r} in {expression!r}")
    return result


@dataclass(frozen=True)
class CharacterVerdict:
    character: str
    passed: bool
    reason: str


@dataclass(frozen=True)
class CaseScore:
    """The verdict of one run of one case."""

    case: int
    executed: bool
    passed: bool
    kind: str  # "event", "wait" or "failure"
    reason: str
    characters: tuple[CharacterVerdict, ...] = field(default=())


def score_outcome(case: BenchmarkCase, scene: Scene, outcome: Outcome) -> CaseScore:
    """Judge one planning outcome (see the module docstring)."""
    if isinstance(outcome, PlanningFailure):
        return CaseScore(case.id, False, False, "failure",
                         f"{outcome.node} failed after {outcome.attempts} attempts: {outcome.feedback[:200]}")
    if outcome is None:
        ok = case.allow_null_plan
        return CaseScore(case.id, True, ok, "wait", "waiting is allowed" if ok else "waited, but a plan was expected")
    plans = {p.character: p for p in outcome.plans}
    verdicts = []
    for expected in case.expected_plans:
        plan = plans.get(expected.character)
        if plan is None:
            verdicts.append(CharacterVerdict(expected.character, False,
                                             f"no plan for {expected.character} (event: {', '.join(outcome.event.characters) or 'none'})"))
            continue
        problems = []
        if expected.target_action and not action_matches(expected.target_action, plan.action):
            problems.append(f"action {plan.action!r} does not match {expected.target_action!r}")
        for expression in (expected.relationships, expected.sampled_position):
            if not expression:
                continue
            try:
                result = check_position(scene, expression, plan.position, seat=plan.seat)
            except PositionExpressionError as exc:
                raise ValueError(f"{case.source}: bad expected expression {expression!r}: {exc}") from None
            if not result.relation_passed:
                where = f"seat {plan.seat}" if plan.seat else f"[{plan.position[0]:.2f}, {plan.position[1]:.2f}]"
                problems.append(f"{where} is not '{expression}' (off by {result.error:.2f} m)")
            elif result.collision is not None:
                problems.append(f"position collides with {result.collision}")
        verdicts.append(CharacterVerdict(expected.character, not problems, "; ".join(problems) or "ok"))
    passed = all(v.passed for v in verdicts)
    reason = "ok" if passed else "; ".join(f"{v.character}: {v.reason}" for v in verdicts if not v.passed)
    return CaseScore(case.id, True, passed, "event", reason, tuple(verdicts))

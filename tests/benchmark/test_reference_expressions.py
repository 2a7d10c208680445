"""Every distinct action and relationship / position expression of the authors' 40 cases parses
and is judged right on at least one plan made to pass and one made to fail.

The plans are built from the meaning of each atom, not from the evaluator: "sit on X" is a plan
seated on X (every alternative seat of an expected answer must pass: the cases name only free
seats); "in front of X" is a point straight out from X's front face, "to the left of X" one out
from its left side, "adjacent to" / "close to" points out from each side, "between X and Y"
points around the midpoint; a failing point is on the floor more than 1.5 m from every object
the expression names, a failing seat one the expression does not name, a failing action a label
of the case the expression does not name. Skipped with the resolver's reason without the data.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache

import numpy as np
import pytest
from numpy.typing import NDArray

from storyteller.agents.messages import Event, ParsedEvent, PlannedCharacter
from storyteller.benchmark.expressions import atoms, parse_expression
from storyteller.benchmark.plan_scoring import CaseScore, action_matches, check_expected_plans, score_outcome
from storyteller.benchmark.position_check import PositionAtom, read_atom
from storyteller.benchmark.reference_cases import BenchmarkCase, ExpectedPlan, load_cases, scene_dir
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.scene_graph import point_footprint_distance
from tests.support.reference import reference_or_skip

OFFSETS = (0.3, 0.4, 0.5, 0.6, 0.2)  # metres out from a face, tried in this order
ACROSS = (0.0, 0.5, -0.5, 0.9, -0.9)  # where along the face, as a fraction of its half length
HAND_PICKED = {  # expressions no single atom can satisfy: a point checked by hand on the map
    "(in front of couch_1 || in front of couch_2) && in front of couch_3": [(2.8, 2.9)],
}


def _xy(v: Sequence[float] | NDArray[np.float64]) -> tuple[float, float]:
    """A point as two plain floats (from an array or a sequence)."""
    return float(v[0]), float(v[1])


@cache
def _cases() -> tuple[BenchmarkCase, ...]:
    return tuple(c.at_level(2) for c in load_cases(reference_or_skip()))


@cache
def _scene(name: str) -> Scene:
    case = next(c for c in _cases() if c.scene_name == name)
    return load_scene(scene_dir(reference_or_skip(), case))


def _distinct(field: str) -> dict[str, tuple[BenchmarkCase, ExpectedPlan]]:
    """Each distinct expression of ``field`` with the first case and expected plan using it."""
    found: dict[str, tuple[BenchmarkCase, ExpectedPlan]] = {}
    for case in _cases():
        for expected in case.expected_plans:
            text = getattr(expected, field)
            if text and text not in found:
                found[text] = (case, expected)
    return found


def _score(case: BenchmarkCase, expected: ExpectedPlan, action: str, position: tuple[float, float],
           seat: str | None) -> CaseScore:
    alone = case.model_copy(update={"expected_plans": (expected,)})
    plan = PlannedCharacter(character=expected.character, action=action, position=position, facing=(1.0, 0.0),
                            seat=seat)
    event = ParsedEvent(index=0, event=Event(characters=(expected.character,), activity="x"), plans=(plan,))
    return score_outcome(alone, _scene(case.scene_name), event)


def _right_action(expected: ExpectedPlan, case: BenchmarkCase) -> str:
    if not expected.target_action:
        return case.action_labels[0]
    return next(atoms(parse_expression(expected.target_action))).text


def _candidates(obj: SceneObject, relation: str) -> list[tuple[float, float]]:
    """Points that stand in ``relation`` to ``obj`` by its definition (see the module docstring)."""
    front, right = np.asarray(obj.facing, dtype=float), np.asarray(obj.right, dtype=float)
    faces = {"in front of": [(front, obj.depth, right, obj.width)], "behind": [(-front, obj.depth, right, obj.width)],
             "to the right of": [(right, obj.width, front, obj.depth)],
             "to the left of": [(-right, obj.width, front, obj.depth)]}
    out = faces.get(relation) or [*faces["in front of"], *faces["behind"], *faces["to the right of"],
                                  *faces["to the left of"]]
    return [_xy(obj.center_xy + d * (size / 2 + o) + k * along * span / 2)
            for k in ACROSS for o in OFFSETS for d, size, along, span in out]


def _passing_points(scene: Scene, read: PositionAtom) -> list[tuple[float, float]]:
    if read.relation == "between":
        a, b = (scene.by_name[n].center_xy for n in read.anchors)
        mid, along = (a + b) / 2, (b - a) / float(np.linalg.norm(b - a))
        across = np.array([-along[1], along[0]])
        return [_xy(mid + s * o * across) for o in (0.0, *OFFSETS) for s in (1, -1)]
    return _candidates(scene.by_name[read.anchors[0]], read.relation)


def _far_point(scene: Scene, names: set[str]) -> tuple[float, float]:
    xs = np.arange(scene.bounds_min[0] + 0.3, scene.bounds_max[0] - 0.3, 0.25)
    ys = np.arange(scene.bounds_min[1] + 0.3, scene.bounds_max[1] - 0.3, 0.25)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    far = np.ones(len(grid), dtype=bool)
    for name in names:
        far &= point_footprint_distance(scene.by_name[name], grid) > 1.5
    for obj in scene.objects:  # on free floor, so the failure is the relation's, not a collision's
        far &= point_footprint_distance(obj, grid) > 0.3
    assert far.any(), f"no free point 1.5 m from {sorted(names)}"
    return _xy(grid[np.flatnonzero(far)[0]])


def test_the_forty_cases_have_the_expressions_this_file_covers() -> None:
    cases = _cases()
    assert len(cases) == 40
    for case in cases:
        check_expected_plans(case, _scene(case.scene_name))  # every expression parses, names known things
    assert len(_distinct("target_action")) >= 10 and len(_distinct("relationships")) >= 20
    assert len(_distinct("sampled_position")) == 10


def test_every_action_expression_passes_and_fails() -> None:
    for text, (case, _) in _distinct("target_action").items():
        tree = parse_expression(text)
        named = {a.text for a in atoms(tree)}
        assert "!" not in text and "&&" not in text  # as the authors wrote them: alternatives only
        wrong = next(label for label in case.action_labels if label not in named)
        for right in named:
            assert action_matches(text, right), (text, right)
        assert not action_matches(text, wrong), (text, wrong)


@pytest.mark.parametrize("field", ["relationships", "sampled_position"])
@pytest.mark.slow
def test_every_position_expression_passes_and_fails(field: str) -> None:
    checked = 0
    for text, (case, expected) in _distinct(field).items():
        scene = _scene(case.scene_name)
        tree = parse_expression(text)
        read = {a: read_atom(scene, a, text) for a in atoms(tree)}
        action = _right_action(expected, case)
        seats = [r.anchors[0] for r in read.values() if r.relation in ("sit on", "lie on")]
        if seats:  # every alternative seat passes; a seat the expression does not name fails
            for seat in seats:
                point = _xy(scene.by_name[seat].seat_point())
                score = _score(case, expected, action, point, seat)
                assert score.passed, (case.id, text, seat, score.reason)
            other = next(o for o in scene.objects if o.is_seat and o.name not in seats)
            point = _xy(other.seat_point())
            failed = _score(case, expected, action, point, other.name)
            assert not failed.passed and f"is not '{text}'" in failed.reason, (case.id, text, failed.reason)
        else:
            points = HAND_PICKED.get(text) or [p for r in read.values() for p in _passing_points(scene, r)]
            scores = [(p, _score(case, expected, action, p, None)) for p in points]
            passing = [(p, s) for p, s in scores if s.passed]
            assert passing, (case.id, text, [s.reason for _, s in scores[:4]])
            point = passing[0][0]
            far = _far_point(scene, {n for r in read.values() for n in r.anchors})
            failed = _score(case, expected, action, far, None)
            assert not failed.passed and f"is not '{text}'" in failed.reason, (case.id, text, failed.reason)
            assert failed.characters[0].error is not None and failed.characters[0].error > 0.0
        if expected.target_action:  # the right place with the wrong action fails on the action alone
            wrong = next(label for label in case.action_labels if label not in expected.target_action)
            first_seat = seats[0] if seats else None
            where = _xy(scene.by_name[first_seat].seat_point()) if first_seat else point
            score = _score(case, expected, wrong, where, first_seat)
            assert not score.passed and score.reason.endswith(f"does not match '{expected.target_action}'"), score.reason
        checked += 1
    assert checked == len(_distinct(field)) > 0

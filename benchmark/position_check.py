"""Check a sampled position against a reference position expression.

Expressions are written as in the reference test cases: atoms such as "in front of fridge_1",
"adjacent to coffee_maker_1", "close to table_3", "sit on chair_6", "between chair_1 and
chair_3", combined with ``||``, ``&&``, ``!`` and parentheses (grammar and precedence in
:mod:`storyteller.benchmark.expressions`: ``!`` over ``&&`` over ``||``).

Each atom has a distance (metres, 0 when fully satisfied) and a tolerance (the reference
thresholds); the atom holds when distance <= tolerance:

- directional ("in front of", "behind", "to the left of", "to the right of"), tolerance 0.1 m:
  the distance from the point to the half-strip swept outward by that face of the anchor's
  footprint rectangle, in the anchor's own frame (front = its facing, right = facing turned
  clockwise). For "in front of X" the strip is {|x| <= width/2, y >= depth/2} in X's frame: a
  point straight in front at any distance has distance 0; a point 0.05 m past the side edge
  or 0.05 m behind the front face has distance 0.05 and still passes.
- "adjacent to" (0.7 m), "close to" (1.4 m), "inside" (0.1 m): distance to the anchor's
  footprint rectangle. "close to X" accepts "adjacent to X" (every point within 0.7 m is within
  1.4 m). "inside X" also holds when the plan sits or lies on X (the paper's equivalence).
- "sit on X" / "lie on X" (0.1 m): when the plan says which seat it took, the atom holds
  exactly when that seat is X; otherwise by the distance to X's footprint.
- "between X and Y" (0.1 m): how far the point's projection falls outside the segment between
  the centres (in metres along it) plus how far the point is beyond 0.5 m off that line.

The **error** is reported in metres with the verdict. Each atom measures an excess, distance
minus tolerance (<= 0 when it holds); ``||`` takes the smallest excess of its operands, ``&&``
the largest, ``!`` negates it (how far inside the excluded region the point is). The error of
a failing expression is its excess clipped at 0; a passing one has error 0.

A position also fails on **collision**: strictly inside the footprint of a floor-standing
object (bottom within 0.1 m of the floor), except the plan's own seat, objects named by
"inside" in the expression and, only when the seat is not given, objects named by "sit on" /
"lie on" (a plan that says it stands inside a chair's footprint collides with the chair); or closer than two body radii (0.5 m) to another
character (``others``: where the characters that do not move are, and where the other planned
characters go), the clearance the project's sampler keeps between characters.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, TypedDict

import numpy as np

from storyteller.benchmark.expressions import And, Atom, Expr, ExpressionError, Not, Or, atoms, parse_expression
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.position_sampling import BODY_RADIUS
from storyteller.tools.scene_graph import point_footprint_distance

if TYPE_CHECKING:
    from storyteller.tools.scene_graph import SceneGraph

TOLERANCES: dict[str, float] = {
    "in front of": 0.1,
    "behind": 0.1,
    "to the left of": 0.1,
    "to the right of": 0.1,
    "adjacent to": 0.7,
    "close to": 1.4,
    "inside": 0.1,
    "sit on": 0.1,
    "lie on": 0.1,
    "between": 0.1,
}
"""Metres: an atom holds when its distance is at most this (the reference thresholds)."""
DIRECTIONAL = ("in front of", "behind", "to the left of", "to the right of")
SEATING = ("sit on", "lie on")
FLOOR_SUPPORT = 0.10
"""Metres: an object whose bottom is this close to the floor stands on it (an obstacle)."""
BETWEEN_OFF_LINE = 0.5
"""Metres: how far off the centre line a point may be and still be "between"."""
CHARACTER_CLEARANCE = 2.0 * BODY_RADIUS
"""Metres between two characters' positions below which their bodies overlap."""
UNKNOWN_SEAT = object()
"""``check_position(seat=...)`` default: judge "sit on X" by the position alone."""

_ATOM = re.compile(
    r"^(?P<rel>in front of|behind|to the left of|to the right of|adjacent to|close to|inside|sit on|lie on)"
    r" (?P<a>\S+)$|^between (?P<b1>\S+) and (?P<b2>\S+)$"
)


class PositionExpressionError(ExpressionError):
    """A position expression that cannot be parsed or names an unknown object; the message
    names the expression and the column."""


@dataclass(frozen=True)
class PositionAtom:
    """One atom read: its relation and the object(s) it names."""

    relation: str
    anchors: tuple[str, ...]


@dataclass(frozen=True)
class CheckResult:
    """Outcome of ``check_position``: ``passed`` = relation holds and no collision."""

    passed: bool
    relation_passed: bool
    error: float
    """Metres the position is off the expression (0 when it holds; see the module docstring)."""
    collision: str | None
    """The object or character collided with, else None."""
    collision_kind: Literal["object", "character"] | None = None
    collision_depth: float = 0.0
    """Metres: how deep inside the object's footprint, or how much closer than the clearance."""


def read_atom(scene: Scene, atom: Atom, expression: str) -> PositionAtom:
    """The relation and anchors of ``atom``; raises :class:`PositionExpressionError` naming the
    column when it is not a known relation or names an object ``scene`` does not have."""
    m = _ATOM.match(atom.text)
    if m is None:
        raise PositionExpressionError(f"cannot read '{atom.text}' (expected e.g. 'close to table_1')",
                                      expression, atom.column)
    anchors: tuple[str, ...]
    if m.group("b1"):
        relation, anchors = "between", (m.group("b1"), m.group("b2"))
    else:
        relation, anchors = m.group("rel"), (m.group("a"),)
    for name in anchors:
        if name not in scene.by_name:
            raise PositionExpressionError(f"unknown object '{name}'", expression, atom.column)
    return PositionAtom(relation, anchors)


def parse_position_expression(scene: Scene, expression: str) -> tuple[Expr, dict[Atom, PositionAtom]]:
    """The tree of ``expression`` and every atom read against ``scene`` (all errors up front)."""
    tree = parse_expression(expression, error=PositionExpressionError)
    return tree, {atom: read_atom(scene, atom, expression) for atom in atoms(tree)}


def directional_distance(obj: SceneObject, relation: str, xy: np.ndarray) -> float:
    """Distance (m) from a point to the half-strip beyond one face of ``obj`` (see module doc)."""
    x, y = (float(v) for v in obj.to_local(np.asarray(xy, dtype=float)))
    hw, hd = obj.width / 2.0, obj.depth / 2.0
    if relation == "in front of":
        along, across, half_along, half_across = y, x, hd, hw
    elif relation == "behind":
        along, across, half_along, half_across = -y, x, hd, hw
    elif relation == "to the right of":
        along, across, half_along, half_across = x, y, hw, hd
    elif relation == "to the left of":
        along, across, half_along, half_across = -x, y, hw, hd
    else:
        raise ValueError(f"not a directional relation: '{relation}'")
    d_along = max(half_along - along, 0.0)
    d_across = max(abs(across) - half_across, 0.0)
    return float(np.hypot(d_along, d_across))


def between_distance(a: SceneObject, b: SceneObject, xy: np.ndarray) -> float:
    """Metres outside the 'between' region of two objects (0 inside; see module doc)."""
    c1, c2 = a.center_xy, b.center_xy
    v = c2 - c1
    length = float(np.linalg.norm(v))
    if length < 1e-9:
        return float(np.linalg.norm(np.asarray(xy) - c1))
    t = float((np.asarray(xy) - c1) @ v) / (length * length)
    off = float(np.linalg.norm(np.asarray(xy) - (c1 + t * v)))
    along = 0.0 if 0.0 <= t <= 1.0 else length * (t - 1.0 if t > 1.0 else -t)
    return along + max(off - BETWEEN_OFF_LINE, 0.0)


def atom_distance(scene: Scene, atom: PositionAtom, xy: np.ndarray) -> float:
    """Metres from ``xy`` to where ``atom`` holds exactly (0 inside; see the module docstring)."""
    if atom.relation == "between":
        return between_distance(scene.by_name[atom.anchors[0]], scene.by_name[atom.anchors[1]], xy)
    obj = scene.by_name[atom.anchors[0]]
    if atom.relation in DIRECTIONAL:
        return directional_distance(obj, atom.relation, xy)
    return float(point_footprint_distance(obj, xy))


def _measure(
    scene: Scene, tree: Expr, read: dict[Atom, PositionAtom], xy: np.ndarray, seat: str | object | None
) -> tuple[bool, float]:
    """(holds, excess in metres) of ``tree`` at ``xy`` (see the module docstring)."""
    if isinstance(tree, Atom):
        atom = read[tree]
        excess = atom_distance(scene, atom, xy) - TOLERANCES[atom.relation]
        holds = excess <= 0.0
        if seat is not UNKNOWN_SEAT and atom.relation in SEATING:  # the plan says which seat it took
            holds = seat == atom.anchors[0]
        elif atom.relation == "inside" and seat == atom.anchors[0]:
            holds = True
        return holds, (min(excess, 0.0) if holds else max(excess, 0.0))
    if isinstance(tree, Not):
        holds, excess = _measure(scene, tree.operand, read, xy, seat)
        return not holds, -excess
    results = [_measure(scene, operand, read, xy, seat) for operand in tree.operands]
    if isinstance(tree, Or):
        return any(h for h, _ in results), min(e for _, e in results)
    assert isinstance(tree, And)
    return all(h for h, _ in results), max(e for _, e in results)


def collision(
    scene: Scene, xy: np.ndarray, ignore: set[str] | frozenset[str] = frozenset()
) -> str | None:
    """The first floor-standing object whose footprint strictly contains ``xy``, else None."""
    hit = object_collision(scene, xy, ignore)
    return None if hit is None else hit[0]


def object_collision(
    scene: Scene, xy: np.ndarray, ignore: set[str] | frozenset[str] = frozenset()
) -> tuple[str, float] | None:
    """(name, metres inside its footprint) of the first floor-standing object whose footprint
    strictly contains ``xy``, else None."""
    for obj in scene.objects:
        if obj.name in ignore or abs(obj.z_min - scene.floor_z) > FLOOR_SUPPORT:
            continue
        x, y = (float(v) for v in obj.to_local(xy))
        if abs(x) < obj.width / 2.0 and abs(y) < obj.depth / 2.0:
            return obj.name, min(obj.width / 2.0 - abs(x), obj.depth / 2.0 - abs(y))
    return None


def character_collision(
    xy: np.ndarray, others: Sequence[tuple[str, tuple[float, float]]]
) -> tuple[str, float] | None:
    """(name, metres closer than the clearance) of the nearest character in ``others`` whose
    position is closer than :data:`CHARACTER_CLEARANCE` to ``xy``, else None."""
    nearest: tuple[str, float] | None = None
    for name, point in others:
        d = float(np.hypot(xy[0] - point[0], xy[1] - point[1]))
        if d < CHARACTER_CLEARANCE and (nearest is None or CHARACTER_CLEARANCE - d > nearest[1]):
            nearest = (name, CHARACTER_CLEARANCE - d)
    return nearest


def check_collision(
    scene: Scene, position: tuple[float, float] | list[float], seat: str | None = None,
    *,
    others: Sequence[tuple[str, tuple[float, float]]] = (),
) -> CheckResult:
    """The collision check of :func:`check_position` alone, for a plan with no position
    expression to meet (``relation_passed`` is True, ``error`` 0)."""
    xy = np.asarray(position, dtype=float).reshape(2)
    hit = object_collision(scene, xy, {seat} if seat else frozenset())
    if hit is not None:
        return CheckResult(False, True, 0.0, hit[0], "object", hit[1])
    near = character_collision(xy, others)
    if near is not None:
        return CheckResult(False, True, 0.0, near[0], "character", near[1])
    return CheckResult(True, True, 0.0, None)


def check_position(
    scene: Scene, expression: str, position: tuple[float, float] | list[float],
    seat: str | object | None = UNKNOWN_SEAT,
    *,
    others: Sequence[tuple[str, tuple[float, float]]] = (),
) -> CheckResult:
    """Whether ``position`` (x, y in metres) satisfies ``expression`` without collision.

    ``seat``: the seat the plan took (None: standing). When given, "sit on X" / "lie on X"
    hold exactly when the plan took X, whatever the point (a standing point on a couch's
    footprint is not sitting on it). ``others``: (name, position) of the other characters
    where they will be. Raises :class:`PositionExpressionError` for a malformed expression."""
    tree, read = parse_position_expression(scene, expression)
    xy = np.asarray(position, dtype=float).reshape(2)
    if not np.all(np.isfinite(xy)):
        return CheckResult(False, False, float("inf"), None)
    holds, excess = _measure(scene, tree, read, xy, seat)
    error = 0.0 if holds else max(excess, 0.0)
    # "inside X" puts the point in X's footprint, so X is no obstacle; "sit on X" does only while
    # the seat is unknown (judged by the point): a plan that says it stands collides with X
    exempt_relations = ("inside", *SEATING) if seat is UNKNOWN_SEAT else ("inside",)
    exempt = {a.anchors[0] for a in read.values() if a.relation in exempt_relations}
    if isinstance(seat, str):
        exempt.add(seat)  # a seat is not an obstacle to its sitter
    hit = object_collision(scene, xy, exempt)
    if hit is not None:
        return CheckResult(False, holds, error, hit[0], "object", hit[1])
    near = character_collision(xy, others)
    if near is not None:
        return CheckResult(False, holds, error, near[0], "character", near[1])
    return CheckResult(holds, holds, error, None)


class PiCaseTiming(TypedDict):
    """One PI case measured by :func:`measure_pi_cases`."""

    case: int
    passed: int
    seeds: int
    ms_per_plan: float
    sampling_ms_per_plan: float


def measure_pi_cases(reference: str, programs: str, seeds: int = 20) -> list[PiCaseTiming]:
    """Run each PI case's program (``programs/testcase_<id>.py``) for ``seeds`` seeds; per case:
    passes, mean milliseconds per plan for the whole run (sandbox + sampling) and for sampling
    alone (``SpatialAPI.resolve``)."""
    import json
    import time
    from pathlib import Path

    from storyteller.sim.scene.files import load_scene
    from storyteller.tools.character_states import world_view_from_reference_case
    from storyteller.tools.sandbox import execute
    from storyteller.tools.scene_graph import build_scene_graph
    from storyteller.tools.spatial_api import SpatialAPI

    ref = Path(reference)
    rows: list[PiCaseTiming] = []
    cache: dict[str, tuple[Scene, SceneGraph]] = {}
    for case in sorted((ref / "benchmark" / "test_cases" / "6_PI").glob("testcase_*.json")):
        data = json.loads(case.read_text())
        if data["scene_name"] not in cache:
            scene = load_scene(ref / "configs" / "scenes" / data["scene_name"])
            cache[data["scene_name"]] = (scene, build_scene_graph(scene))
        scene, graph = cache[data["scene_name"]]
        world = world_view_from_reference_case(data, scene)
        source = (Path(programs) / f"testcase_{data['id']}.py").read_text()
        (expected,) = data["expected_plans"]
        passed, total_s, sample_s = 0, 0.0, 0.0
        for seed in range(seeds):
            t0 = time.perf_counter()
            api = SpatialAPI(scene, graph, world, data["action_labels"])
            execute(source, api.namespace(), entry="parse_event")
            t1 = time.perf_counter()
            plans = api.resolve(seed)
            t2 = time.perf_counter()
            total_s += t2 - t0
            sample_s += t2 - t1
            plan = next(p for p in plans if p.character == expected["character"])
            passed += check_position(scene, expected["sampled_position"], plan.position).passed
        rows.append({"case": data["id"], "passed": passed, "seeds": seeds,
                     "ms_per_plan": 1000 * total_s / seeds, "sampling_ms_per_plan": 1000 * sample_s / seeds})  # fmt: skip
    return rows


if (
    __name__ == "__main__"
):  # python -m storyteller.benchmark.position_check ../shared/reference/event-driven-storytelling tests/pi_programs
    import sys

    results = measure_pi_cases(
        sys.argv[1], sys.argv[2], int(sys.argv[3]) if len(sys.argv) > 3 else 20
    )
    for row in results:
        print(f"PI case {row['case']}: {row['passed']}/{row['seeds']} pass; {row['ms_per_plan']:.2f} ms per plan "
              f"(sampling {row['sampling_ms_per_plan']:.2f} ms)")  # fmt: skip
    n = len(results)
    print(
        f"mean: {sum(r['ms_per_plan'] for r in results) / n:.2f} ms per plan, "
        f"sampling {sum(r['sampling_ms_per_plan'] for r in results) / n:.2f} ms"
    )

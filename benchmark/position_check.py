"""Check a sampled position against a reference position expression.

Expressions are written as in the reference test cases: atoms such as "in front of fridge_1",
"adjacent to coffee_maker_1", "close to table_3", "sit on chair_6", "between chair_1 and
chair_3", combined with ``||``, ``&&`` and parentheses (``&&`` binds tighter than ``||``).

Each atom has a distance (metres, 0 when fully satisfied) and a tolerance (the reference
thresholds); the atom passes when distance <= tolerance:

- directional ("in front of", "behind", "to the left of", "to the right of"), tolerance 0.1 m:
  the distance from the point to the half-strip swept outward by that face of the anchor's
  footprint rectangle, in the anchor's own frame (front = its facing, right = facing turned
  clockwise). For "in front of X" the strip is {|x| <= width/2, y >= depth/2} in X's frame: a
  point straight in front at any distance has distance 0; a point 0.05 m past the side edge
  or 0.05 m behind the front face has distance 0.05 and still passes.
- "adjacent to" (0.7 m), "close to" (1.4 m), "inside" (0.1 m): distance to the anchor's
  footprint rectangle. "close to X" also accepts "adjacent to X" (implied: 0.7 < 1.4).
- "sit on X" / "lie on X" (0.1 m): distance to X's footprint; X itself is then not an obstacle.
- "between X and Y" (0.1 m): how far the point's projection falls outside the segment between
  the centres (in metres along it) plus how far the point is beyond 0.5 m off that line.

``||`` passes when any side passes (error: the smaller), ``&&`` when both pass (error: the
larger). A position also fails on collision: strictly inside the footprint of a floor-standing
object (bottom within 0.1 m of the floor), except objects sat / lain on in the expression.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypedDict

import numpy as np

from sim.scene.model import Scene, SceneObject
from tools.scene_graph import point_footprint_distance

if TYPE_CHECKING:
    from tools.scene_graph import SceneGraph

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
FLOOR_SUPPORT = 0.10
BETWEEN_OFF_LINE = 0.5
UNKNOWN_SEAT = object()
"""``check_position(seat=...)`` default: judge "sit on X" by the position alone."""

_ATOM = re.compile(
    r"^(?P<rel>in front of|behind|to the left of|to the right of|adjacent to|close to|inside|sit on|lie on)"
    r" (?P<a>\S+)$|^between (?P<b1>\S+) and (?P<b2>\S+)$"
)
_TOKENS = re.compile(r"(\|\||&&|\(|\))")  # capturing: split keeps the operators


class PositionExpressionError(ValueError):
    """An expression that cannot be parsed or names an unknown object."""


@dataclass(frozen=True)
class CheckResult:
    """Outcome of ``check_position``: ``passed`` = relation holds and no collision."""

    passed: bool
    relation_passed: bool
    error: float
    collision: str | None


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
        raise PositionExpressionError(f"not a directional relation: '{relation}'")
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


class _Parser:
    def __init__(self, scene: Scene, expression: str, xy: np.ndarray, seat: str | object | None = UNKNOWN_SEAT):
        self.scene = scene
        self.xy = xy
        self.seat = seat
        self.tokens = [t.strip() for t in _TOKENS.split(expression) if t.strip()]
        self.i = 0
        self.seats: set[str] = set()

    def parse(self) -> tuple[bool, float]:
        if not self.tokens:
            raise PositionExpressionError("empty expression")
        result = self._or()
        if self.i != len(self.tokens):
            raise PositionExpressionError(f"unexpected '{self.tokens[self.i]}'")
        return result

    def _or(self) -> tuple[bool, float]:
        ok, err = self._and()
        while self.i < len(self.tokens) and self.tokens[self.i] == "||":
            self.i += 1
            ok2, err2 = self._and()
            ok, err = ok or ok2, min(err, err2)
        return ok, err

    def _and(self) -> tuple[bool, float]:
        ok, err = self._factor()
        while self.i < len(self.tokens) and self.tokens[self.i] == "&&":
            self.i += 1
            ok2, err2 = self._factor()
            ok, err = ok and ok2, max(err, err2)
        return ok, err

    def _factor(self) -> tuple[bool, float]:
        if self.i >= len(self.tokens):
            raise PositionExpressionError("expression ends too early")
        token = self.tokens[self.i]
        self.i += 1
        if token == "(":
            result = self._or()
            if self.i >= len(self.tokens) or self.tokens[self.i] != ")":
                raise PositionExpressionError("missing ')'")
            self.i += 1
            return result
        if token in ("||", "&&", ")"):
            raise PositionExpressionError(f"unexpected '{token}'")
        return self._atom(token)

    def _object(self, name: str) -> SceneObject:
        if name not in self.scene.by_name:
            raise PositionExpressionError(f"unknown object '{name}'")
        return self.scene.by_name[name]

    def _atom(self, text: str) -> tuple[bool, float]:
        m = _ATOM.match(text)
        if m is None:
            raise PositionExpressionError(f"cannot read '{text}'")
        if m.group("b1"):
            relation = "between"
            distance = between_distance(
                self._object(m.group("b1")), self._object(m.group("b2")), self.xy
            )
        else:
            relation, obj = m.group("rel"), self._object(m.group("a"))
            if relation in ("sit on", "lie on"):
                self.seats.add(obj.name)
                if self.seat is not UNKNOWN_SEAT:  # the plan says which seat it took
                    return self.seat == obj.name, 0.0 if self.seat == obj.name else float("inf")
            if relation in ("in front of", "behind", "to the left of", "to the right of"):
                distance = directional_distance(obj, relation, self.xy)
            else:
                distance = float(point_footprint_distance(obj, self.xy))
        tolerance = TOLERANCES[relation]
        return distance <= tolerance, max(0.0, distance - tolerance)


def collision(
    scene: Scene, xy: np.ndarray, ignore: set[str] | frozenset[str] = frozenset()
) -> str | None:
    """The first floor-standing object whose footprint strictly contains ``xy``, else None."""
    for obj in scene.objects:
        if obj.name in ignore or abs(obj.z_min - scene.floor_z) > FLOOR_SUPPORT:
            continue
        x, y = (float(v) for v in obj.to_local(xy))
        if abs(x) < obj.width / 2.0 and abs(y) < obj.depth / 2.0:
            return obj.name
    return None


def check_position(
    scene: Scene, expression: str, position: tuple[float, float] | list[float],
    seat: str | object | None = UNKNOWN_SEAT,
) -> CheckResult:
    """Whether ``position`` (x, y in metres) satisfies ``expression`` without collision.

    ``seat``: the seat the plan took (None: standing). When given, "sit on X" / "lie on X"
    hold exactly when the plan took X, whatever the point (a standing point on a couch's
    footprint is not sitting on it)."""
    xy = np.asarray(position, dtype=float).reshape(2)
    if not np.all(np.isfinite(xy)):
        return CheckResult(False, False, float("inf"), None)
    parser = _Parser(scene, expression, xy, seat)
    ok, error = parser.parse()
    sat_on = parser.seats | ({seat} if isinstance(seat, str) else set())  # a seat is not an obstacle to its sitter
    hit = collision(scene, xy, sat_on)
    return CheckResult(ok and hit is None, ok, error, hit)


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

    from sim.scene.files import load_scene
    from tools.character_states import world_view_from_reference_case
    from tools.sandbox import execute
    from tools.scene_graph import build_scene_graph
    from tools.spatial_api import SpatialAPI

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
):  # python -m benchmark.position_check ../shared/reference/event-driven-storytelling tests/pi_programs
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

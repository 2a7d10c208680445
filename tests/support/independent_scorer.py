"""A second, deliberately simple scorer of one planning step: the oracle that
``tests/benchmark/test_scorer_agreement.py`` holds ``storyteller.benchmark.plan_scoring`` against.

Written from the benchmark rules only (issue 9, item 3, and the reference data's README), never
from the evaluator's code: it imports nothing from ``benchmark/``, ``sim/`` or ``tools/``. It reads
the case JSON and the scene file itself (its own expression parser, its own footprint geometry),
so a shared misreading of a file or a shared geometry bug cannot make the two agree.

The rules as read here. Where the issue's text leaves a choice open (marked *reading*), the
choice follows the authors' published evaluator and area definitions (rms0329/Event-Driven-
Storytelling, ``benchmark/evaluator*.py``, ``src/scene/relationships.py``), restated here in
our own words:

- A case lists expected plans, one per character: an action expression over action labels, a
  relationship expression (OA / RC / SS cases) or a ``sampled_position`` expression (PI cases).
  Expressions combine atoms with ``||``, ``&&``, ``!`` and parentheses (``!`` binds tightest,
  then ``&&``, then ``||``). A missing (null) expression accepts anything.
- A null plan (no outcome, or an event with no characters) passes exactly when the case has
  ``allow_null_plan``. A planning failure never passes.
- Every expected character must be planned; *reading*: a planned character the case does not
  expect does not fail the step (the authors' evaluator only looks up the expected ones), but
  it is a character the others must not collide with.
- Atoms. ``sit on X`` / ``lie on X`` hold exactly when the plan took seat X. ``inside X`` holds
  when the plan sits or lies on X, or the point is within 0.1 m of X's footprint. ``adjacent to X``:
  within 0.7 m of X's footprint; ``close to X``: within 1.4 m (so every adjacent point is close,
  the paper's "close accepts adjacent"). Directional atoms (``in front of``, ``behind``,
  ``to the left of``, ``to the right of``; left and right are X's own, seen along its facing):
  within 0.1 m of the half-strip swept outward from that face of X, as wide (or deep) as X;
  *reading*: the strip has no far end. ``between X and Y`` (*reading*: the authors' area, with
  the directional tolerance 0.1 m): the metres by which the point's projection on the line
  joining the centres falls beyond them, plus the metres it is past ``BETWEEN_WIDTH`` off that line.
- An atom's error is the metres by which the point misses its tolerance (0 when it holds); an
  ``||`` takes the smallest error of its operands, ``&&`` the largest, so the expression holds
  exactly when its error is 0. ``!A`` holds when A does not (error 0, else 1).
- Collision (*reading*: the issue gives no sizes): a point strictly inside the footprint of
  a floor-standing object (bottom within ``FLOOR_SUPPORT`` of the floor; not the plan's own
  seat nor an ``inside`` anchor of its own expression) collides with it, seated or not (a seat
  point inside another object's footprint puts the sitter in it). Two characters collide when
  closer than ``CHARACTER_CLEARANCE``; taking a single seat (a chair, a stool) that another
  character sits on (per the case's ``current_states``) or that another planned character takes
  is a character collision too. Collisions apply to every case, not only PI (the project's
  rule; the authors' evaluator checks objects in PI cases only).

A failed character may fail for several reasons at once; :class:`Verdict` keeps them all
(``reasons``), so a comparison does not depend on which one an evaluator reports first.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ADJACENT = 0.7
CLOSE = 1.4
DIRECTIONAL = 0.1
INSIDE = 0.1
BETWEEN_WIDTH = 0.5
"""Metres off the line joining two centres that is still 'between' them (the authors' area)."""
FLOOR_SUPPORT = 0.1
"""Metres: an object whose bottom is this close to the floor stands on it (an obstacle)."""
SINGLE_SEAT = 1.0
"""Metres: a seat narrower than this holds one person (a chair, a stool); wider ones (a couch, a
bench) hold several and are shared by distance alone."""
CHARACTER_CLEARANCE = 0.5
"""Metres two characters' points must be apart (*reading*: the reference sampler's spacing)."""

Point = tuple[float, float]


# ----------------------------------------------------------------------------- scene


@dataclass(frozen=True)
class Box:
    """One object's footprint: a rectangle with centre ``c``, facing ``u``, left ``v`` = u turned
    +90 degrees, half depth ``hd`` along u and half width ``hw`` along v."""

    name: str
    c: Point
    u: Point
    hd: float
    hw: float
    bottom: float
    sit_offset: float

    @property
    def v(self) -> Point:
        return (-self.u[1], self.u[0])

    def local(self, p: Point) -> Point:
        dx, dy = p[0] - self.c[0], p[1] - self.c[1]
        return (dx * self.u[0] + dy * self.u[1], dx * self.v[0] + dy * self.v[1])

    def world(self, s: float, t: float) -> Point:
        return (self.c[0] + s * self.u[0] + t * self.v[0], self.c[1] + s * self.u[1] + t * self.v[1])

    def corners(self) -> list[Point]:
        return [self.world(s, t) for s, t in ((self.hd, self.hw), (-self.hd, self.hw),
                                             (-self.hd, -self.hw), (self.hd, -self.hw))]

    def distance(self, p: Point) -> float:
        """Metres from ``p`` to the footprint (0 inside)."""
        s, t = self.local(p)
        return math.hypot(max(abs(s) - self.hd, 0.0), max(abs(t) - self.hw, 0.0))

    def contains(self, p: Point) -> bool:
        s, t = self.local(p)
        return abs(s) < self.hd and abs(t) < self.hw

    def seat_point(self) -> Point:
        """Where a sitter's pelvis goes: centre + facing * depth * sit offset."""
        return self.world(2 * self.hd * self.sit_offset, 0.0)


def _unit(x: float, y: float) -> Point:
    n = math.hypot(x, y)
    return (x / n, y / n)


def _box_from_reference(o: Mapping[str, Any]) -> Box:
    bottom = [(float(c[0]), float(c[1])) for c in o["bbox"][:4]]
    cx = sum(p[0] for p in bottom) / 4
    cy = sum(p[1] for p in bottom) / 4
    e1 = (bottom[1][0] - bottom[0][0], bottom[1][1] - bottom[0][1])
    e2 = (bottom[3][0] - bottom[0][0], bottom[3][1] - bottom[0][1])
    f = _unit(float(o["orientation"][0]), float(o["orientation"][1]))
    # the edge most parallel to the facing is the depth edge
    if abs(e1[0] * f[0] + e1[1] * f[1]) / math.hypot(*e1) > abs(e2[0] * f[0] + e2[1] * f[1]) / math.hypot(*e2):
        depth_edge, width_edge = e1, e2
    else:
        depth_edge, width_edge = e2, e1
    u = _unit(*depth_edge)
    if u[0] * f[0] + u[1] * f[1] < 0:
        u = (-u[0], -u[1])
    return Box(f"{o['label']}_{o['idx']}", (cx, cy), u, math.hypot(*depth_edge) / 2,
               math.hypot(*width_edge) / 2, min(float(c[2]) for c in o["bbox"]),
               float(o.get("sit_offset_horizontal", 0.0)))


def _box_from_bundled(o: Mapping[str, Any], floor: float) -> Box:
    cx, cy, cz = (float(v) for v in o["center"])
    w, d, h = (float(v) for v in o["size"])
    return Box(str(o["name"]), (cx, cy), _unit(float(o["facing"][0]), float(o["facing"][1])),
               d / 2, w / 2, cz - h / 2 - floor, float(o.get("sit_offset_horizontal", 0.0)))


def load_boxes(path: str | Path) -> dict[str, Box]:
    """Footprints by object name: ``path`` is a reference scene folder (``objects.json``) or a
    bundled scene file (``storyteller-scene/1``)."""
    path = Path(path)
    if path.is_dir():
        objects = json.loads((path / "objects.json").read_text(encoding="utf-8"))
        boxes = [_box_from_reference(o) for o in objects]
    else:
        data = json.loads(path.read_text(encoding="utf-8"))
        boxes = [_box_from_bundled(o, float(data.get("floor_z", 0.0))) for o in data["objects"]]
    return {b.name: b for b in boxes}


# ----------------------------------------------------------------------------- expressions


@dataclass(frozen=True)
class Node:
    op: str  # "atom", "not", "and", "or"
    text: str = ""
    kids: tuple[Node, ...] = ()


_TOKEN = re.compile(r"\s*(\|\||&&|!|\(|\))\s*")


def parse(expression: str) -> Node:
    """``||`` / ``&&`` / ``!`` / parentheses over atoms (any other text, trimmed)."""
    parts = [p for p in _TOKEN.split(expression) if p is not None]
    tokens = [p.strip() for p in parts if p.strip()]
    pos = 0

    def peek() -> str | None:
        return tokens[pos] if pos < len(tokens) else None

    def take() -> str:
        nonlocal pos
        if pos >= len(tokens):
            raise ValueError(f"unexpected end of {expression!r}")
        pos += 1
        return tokens[pos - 1]

    def disjunction() -> Node:
        kids = [conjunction()]
        while peek() == "||":
            take()
            kids.append(conjunction())
        return kids[0] if len(kids) == 1 else Node("or", kids=tuple(kids))

    def conjunction() -> Node:
        kids = [unary()]
        while peek() == "&&":
            take()
            kids.append(unary())
        return kids[0] if len(kids) == 1 else Node("and", kids=tuple(kids))

    def unary() -> Node:
        tok = take()
        if tok == "!":
            return Node("not", kids=(unary(),))
        if tok == "(":
            inner = disjunction()
            if take() != ")":
                raise ValueError(f"missing ')' in {expression!r}")
            return inner
        if tok in ("||", "&&", ")"):
            raise ValueError(f"unexpected {tok!r} in {expression!r}")
        return Node("atom", text=" ".join(tok.split()))

    tree = disjunction()
    if pos != len(tokens):
        raise ValueError(f"unexpected {tokens[pos]!r} in {expression!r}")
    return tree


def atom_texts(tree: Node) -> Iterable[str]:
    if tree.op == "atom":
        yield tree.text
    for k in tree.kids:
        yield from atom_texts(k)


def error_of(tree: Node, atom_error: Any) -> float:
    """Metres the expression misses by (0: it holds): ``||`` smallest, ``&&`` largest."""
    if tree.op == "atom":
        return float(atom_error(tree.text))
    if tree.op == "not":
        inner = error_of(tree.kids[0], atom_error)
        return 1.0 if inner == 0.0 else 0.0
    errors = [error_of(k, atom_error) for k in tree.kids]
    return min(errors) if tree.op == "or" else max(errors)


# ----------------------------------------------------------------------------- atoms

_SIDES = {"in front of": (1.0, 0.0), "behind": (-1.0, 0.0),
          "to the left of": (0.0, 1.0), "to the right of": (0.0, -1.0)}
_ATOM = re.compile(r"^(sit on|lie on|inside|adjacent to|close to|in front of|behind|to the left of|"
                   r"to the right of) (\S+)$|^between (\S+) and (\S+)$")


def _strip_distance(box: Box, side: Point, p: Point) -> float:
    """Metres from ``p`` to the half-strip swept outward by that ``side`` of ``box`` (0 inside)."""
    s, t = box.local(p)
    if side[0]:  # front / behind: s beyond the face on that side, |t| within the half width
        along, across, face, half = side[0] * s, t, box.hd, box.hw
    else:  # left / right
        along, across, face, half = side[1] * t, s, box.hw, box.hd
    return math.hypot(max(face - along, 0.0), max(abs(across) - half, 0.0))


def _between_distance(a: Box, b: Box, p: Point) -> float:
    """Metres outside the authors' 'between' area: how far the point's projection falls beyond
    the segment joining the two centres, plus how far the point is past ``BETWEEN_WIDTH`` off
    that line."""
    ab = (b.c[0] - a.c[0], b.c[1] - a.c[1])
    length = math.hypot(*ab)
    k = ((p[0] - a.c[0]) * ab[0] + (p[1] - a.c[1]) * ab[1]) / (length * length)
    off = abs((p[0] - a.c[0]) * ab[1] - (p[1] - a.c[1]) * ab[0]) / length
    beyond = length * (k - 1.0) if k > 1.0 else (-k * length if k < 0.0 else 0.0)
    return beyond + max(off - BETWEEN_WIDTH, 0.0)


def atom_distance(boxes: Mapping[str, Box], text: str, p: Point) -> float:
    """Metres from ``p`` to the region of a geometric atom (0 inside), before its tolerance."""
    m = _ATOM.match(text)
    if m is None:
        raise ValueError(f"unknown atom {text!r}")
    if m.group(3):
        return _between_distance(boxes[m.group(3)], boxes[m.group(4)], p)
    rel, box = m.group(1), boxes[m.group(2)]
    if rel in _SIDES:
        return _strip_distance(box, _SIDES[rel], p)
    return box.distance(p)


def tolerance(text: str) -> float:
    """Metres an atom's distance may reach and the atom still hold."""
    for prefix, tol in (("adjacent to", ADJACENT), ("close to", CLOSE), ("inside", INSIDE)):
        if text.startswith(prefix):
            return tol
    return DIRECTIONAL


def atom_error(boxes: Mapping[str, Box], text: str, p: Point, seat: str | None) -> float:
    """Metres by which (``p``, ``seat``) misses the atom's tolerance; 0 when the atom holds."""
    m = _SEATED.match(text)
    if m is not None:
        return 0.0 if seat == m.group(1) else 1.0
    if text.startswith("inside ") and seat == text.split(" ", 1)[1]:
        return 0.0
    return max(atom_distance(boxes, text, p) - tolerance(text), 0.0)


# ----------------------------------------------------------------------------- verdict


@dataclass(frozen=True)
class Plan:
    """One planned character, as the scorer needs it."""

    character: str
    action: str
    position: Point
    seat: str | None = None


@dataclass(frozen=True)
class Verdict:
    passed: bool
    reasons: frozenset[str] = field(default_factory=frozenset)
    """Every failure class that applies (empty when passed): null_plan, failure,
    missing_character, action, relationship, collision_object, collision_character. A passing
    null plan has ``{"wait"}``."""


_SEATED = re.compile(r"^(?:sit on|lie on) (\S+)$")


def occupied_seats(case: Mapping[str, Any]) -> dict[str, str]:
    """Seat -> the character the case's ``current_states`` puts on it."""
    seats: dict[str, str] = {}
    for c in case.get("current_states", []):
        for text in c.get("position") or []:
            if m := _SEATED.match(text.strip()):
                seats[m.group(1)] = c["name"]
    return seats


def score(case: Mapping[str, Any], boxes: Mapping[str, Box], plans: Sequence[Plan] | None,
          others: Mapping[str, Sequence[Point]] | None = None, *, failed: bool = False) -> Verdict:
    """The verdict of one planning step of ``case`` (its JSON as read).

    ``plans``: None or empty for a null plan (waiting). ``others``: where the characters the
    plan does not move stand (and walk to), by name; ``failed``: planning gave up."""
    if failed:
        return Verdict(False, frozenset({"failure"}))
    if not plans:
        ok = bool(case.get("allow_null_plan", False))
        return Verdict(ok, frozenset({"wait"} if ok else {"null_plan"}))
    expected = {e["character"]: e for e in case["expected_plans"]}
    planned = {p.character: p for p in plans}
    reasons: set[str] = set()
    if set(expected) - set(planned):
        reasons.add("missing_character")
    seats = occupied_seats(case)
    for plan in plans:
        exp = expected.get(plan.character)
        if exp is None:
            continue
        action = exp.get("target_action")
        if action and error_of(parse(action), lambda a, plan=plan: 0.0 if a == plan.action else 1.0):
            reasons.add("action")
        inside: set[str] = set()
        for key in ("relationships", "sampled_position"):
            if exp.get(key):
                tree = parse(exp[key])
                inside |= {t.split(" ", 1)[1] for t in atom_texts(tree) if t.startswith("inside ")}
                if error_of(tree, lambda t, plan=plan: atom_error(boxes, t, plan.position, plan.seat)):
                    reasons.add("relationship")
        for box in boxes.values():
            if (box.name not in inside and box.name != plan.seat and box.bottom <= FLOOR_SUPPORT
                    and box.contains(plan.position)):
                reasons.add("collision_object")
        if plan.seat is not None and plan.seat in boxes and 2 * boxes[plan.seat].hw < SINGLE_SEAT:
            holder = seats.get(plan.seat)
            if holder is not None and holder != plan.character and holder not in planned:
                reasons.add("collision_character")
            if any(q.seat == plan.seat for q in plans if q.character != plan.character):
                reasons.add("collision_character")
        points = [q.position for q in plans if q.character != plan.character]
        points += [pt for name, pts in (others or {}).items() if name not in planned for pt in pts]
        if any(math.dist(plan.position, q) < CHARACTER_CLEARANCE for q in points):
            reasons.add("collision_character")
    return Verdict(not reasons, frozenset(reasons))

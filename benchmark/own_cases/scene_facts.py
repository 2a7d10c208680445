"""What the recipes of :mod:`.generate` know of one scene: :class:`SceneFacts` (its objects,
scene graph, region clusters and action labels, with queries evaluated in an empty world) and
the small query and phrase helpers every recipe shares.

Guarantee: :func:`clear_extreme` names a nearest / farthest object only when the runner-up is
at least :data:`MARGIN_M` farther (nearer), so the answer is clear to a reader too.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from storyteller.benchmark.own_cases.derivation import CaseWorld, evaluate
from storyteller.benchmark.own_cases.drafts import Query
from storyteller.benchmark.own_cases.phrasing import LANDMARK_EXCLUDED, NOUNS, PLURALS, SEATED, SEATED_USES
from storyteller.benchmark.reference_cases import BUNDLED_PREFIX
from storyteller.sim.scene.model import Scene
from storyteller.tools.scene_graph import SceneGraph, footprint_distance

MARGIN_M = 0.3
"""A nearest / farthest answer must beat the runner-up by this much (metres of footprint distance)."""

SEATS: Query = {"seats": True}


def of_label(label: str) -> Query:
    return {"label": label}


def seats_by(unit: Query) -> Query:
    return {"and": [SEATS, {"related": "adjacent to", "to": unit}]}


@dataclass
class SceneFacts:
    name: str
    scene: Scene
    graph: SceneGraph
    clusters: list[list[str]]
    actions: tuple[str, ...]
    scene_name: str = ""
    """The cases' ``scene_name`` (default ``bundled:<name>``)."""
    world: CaseWorld = field(init=False)

    def __post_init__(self) -> None:
        from storyteller.tools.character_states import WorldView

        if not self.scene_name:
            self.scene_name = BUNDLED_PREFIX + self.name
        self.world = CaseWorld(self.scene, self.graph, tuple(tuple(c) for c in self.clusters), WorldView(),
                               frozenset(), "")

    def eval(self, query: Query) -> frozenset[str]:
        return evaluate(query, self.world)

    def count(self, label: str) -> int:
        return sum(1 for o in self.scene.objects if o.label == label)

    def landmarks(self) -> list[str]:
        """Labels with one instance and a noun, that one can steer by."""
        return sorted(lb for lb in {o.label for o in self.scene.objects}
                      if lb in NOUNS and lb not in LANDMARK_EXCLUDED and self.count(lb) == 1)

    def seat_kinds(self, least: int = 2) -> list[str]:
        return sorted(lb for lb in {o.label for o in self.scene.objects if o.is_seat}
                      if lb in PLURALS and self.count(lb) >= least)

    def distance(self, a: str, b: str) -> float:
        return footprint_distance(self.scene.by_name[a], self.scene.by_name[b])

    def single(self, label: str) -> str:
        return next(o.name for o in self.scene.objects if o.label == label)

    def floor_standing(self, name: str) -> bool:
        return abs(self.scene.by_name[name].z_min - self.scene.floor_z) < 0.1


def clear_extreme(facts: SceneFacts, candidates: frozenset[str], landmark: str, op: str) -> str | None:
    """The candidate clearly nearest to (farthest from) the landmark object, or None when the
    runner-up is within :data:`MARGIN_M`."""
    if len(candidates) < 2:
        return None
    sign = 1.0 if op == "nearest" else -1.0
    ranked = sorted((sign * facts.distance(c, landmark), c) for c in candidates)
    return ranked[0][1] if ranked[1][0] - ranked[0][0] >= MARGIN_M else None


def nouns_of(label: str) -> list[str]:
    return list(NOUNS[label])


def activities(phrases: tuple[str, ...] | list[str], noun_label: str | None = None) -> list[str]:
    nouns = NOUNS.get(noun_label or "", ("",))
    return [p.replace("{noun}", n) for p in phrases for n in (nouns if "{noun}" in p else nouns[:1])]


def seated_activities(facts: SceneFacts) -> list[tuple[str, list[str]]]:
    return [(a, list(p)) for a, p in SEATED.items() if a in facts.actions]


@dataclass(frozen=True)
class SeatedUse:
    """A seated activity whose seats follow from the objects it needs."""

    action: str
    units: Query
    """The places the activity happens at (tables, desks), or the seats themselves."""
    seats_are_units: bool = False

    def seats(self, unit: Query) -> Query:
        return {"and": [SEATS, unit]} if self.seats_are_units else seats_by(unit)


def seated_uses(facts: SceneFacts) -> list[SeatedUse]:
    uses = [
        SeatedUse("use_laptop", {"anchors_of": "on", "from": of_label("laptop")}),
        SeatedUse("work_on_computer", {"anchors_of": "on", "from": of_label("monitor")}),
        SeatedUse("eat", {"anchors_of": "on", "from": of_label("plate")}),
        SeatedUse("order_drink", seats_by(of_label("bar_counter")), seats_are_units=True),
        SeatedUse("watch_tv", {"and": [SEATS, {"anchors_of": "in front of", "from": {"anchors_of": "on", "from": of_label("tv")}}]},
                  seats_are_units=True),
        SeatedUse("attend_meeting", {"and": [of_label("table"), {"region_of": of_label("white_board")}]}),
    ]
    out = []
    for use in uses:
        if use.action not in facts.actions or use.action not in SEATED_USES:
            continue
        try:
            if facts.eval(use.units) and facts.eval(use.seats(use.units)):
                out.append(use)
        except Exception:  # a label the scene lacks
            continue
    return out

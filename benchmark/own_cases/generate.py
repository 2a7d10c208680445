"""Generate our case pool's templated cases from the bundled scenes' geometry.

``python -m benchmark.own_cases.generate`` writes the generated cases (ids from
:data:`FIRST_ID`) into ``benchmark/cases/ours/<k>_<TAGS>/`` next to the 40 hand-written ones,
removing generated files of an earlier run; ``--check`` only compares and exits 1 when the
folder differs from what the code generates. ``--pool ours_ref`` does the same on the authors'
three reference scenes (:data:`REF_SCENES`, loaded through the reference-data lookup; absent:
one line, exit 2) into ``benchmark/cases/ours_ref/`` (ids from :data:`REF_FIRST_ID`, all
generated).

How a case is made: a *recipe* (one per kind of question, e.g. "the seat of a kind nearest a
landmark", "join a friend's table", "wait for a device in use") looks at a scene (objects,
:mod:`tools.scene_graph` relations, region clusters) and proposes *drafts*: the tags, the
answer as a derivation query (:mod:`.derivation`), the action, the characters already in
place, and the slot values of its sentence shapes (:mod:`.phrasing`). A draft is kept only
when the answer is clear to a reader as well as to the code: for nearest / farthest the runner-up
is at least :data:`MARGIN_M` farther (nearer); a ``count: one`` query selects exactly one
object. Each kept draft is then written as a case with named characters and level-1 / level-2
distractors (characters and history events that touch none of the objects the question is
about) and checked by :func:`benchmark.own_cases.check.check_case`; a draft whose case fails
the check with every distractor choice tried is dropped.

Guarantee: deterministic (the same code gives the same files, byte for byte); every case
written passes the check (its expected answer is what the geometry and the history derive, the
same at levels 0, 1 and 2); per tag group the cases come round-robin from the scenes and the
recipes, each recipe's shapes taken in turn, so no shape dominates; no text is taken from any
benchmark case.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path
from typing import Any

from benchmark.own_cases.check import _Scenes, check_case, ours_folder, ours_ref_folder
from benchmark.own_cases.derivation import CaseWorld, atoms_of, evaluate
from benchmark.own_cases.phrasing import (
    DEVICE_USES,
    LANDMARK_EXCLUDED,
    NAMES,
    NOUNS,
    PLURALS,
    SEATED,
    SEATED_USES,
    SHAPES,
    STANDING,
    third_person,
)
from benchmark.own_cases.split import SIDES, Side, first_side, on_side
from benchmark.reference_cases import BUNDLED_PREFIX, BenchmarkCase
from orchestrator.reference_data import ReferenceDataNotFound
from sim.scene.bundled import load_bundled_scene
from sim.scene.files import load_scene
from sim.scene.model import Scene
from tools.clusters import cluster_objects
from tools.scene_graph import SceneGraph, build_scene_graph, footprint_distance

SCENES: tuple[str, ...] = ("home", "office", "restaurant")
FIRST_ID = 200
"""Generated cases are numbered from here (the hand-written ones are 100-169)."""
REF_SCENES: tuple[str, ...] = ("House", "Office", "Restaurant")
"""The authors' reference scenes (``configs/scenes/<name>`` of the reference data)."""
REF_FIRST_ID = 500
"""The reference-scene pool's cases are numbered from here (no id shared with ``ours``)."""
GENERATOR_SEED = 24
MARGIN_M = 0.3
"""A nearest / farthest answer must beat the runner-up by this much (metres of footprint distance)."""
MULTI_SEAT = frozenset({"couch", "bench"})
"""Seats several people share: never the answer of an occupancy question."""
ATTEMPTS = 6
"""Distractor choices tried per draft before it is dropped."""

GROUPS: tuple[str, ...] = ("OA", "RC", "SS", "OA+RC", "OA+SS", "RC+SS", "PI")
FOLDERS: dict[str, str] = {g: f"{i}_{g.replace('+', '_')}" for i, g in enumerate(GROUPS)}
TARGETS: dict[str, int] = {"OA": 25, "RC": 25, "SS": 25, "OA+RC": 25, "OA+SS": 25, "RC+SS": 25, "PI": 50}
"""Generated cases per group: with the 40 hand-written ones the pool keeps the reference's
mix (an eighth per single tag and per pair, a quarter PI)."""

ACTION_LABELS: dict[str, tuple[str, ...]] = {
    "home": ("idle", "drink", "eat", "watch_tv", "dance", "chat", "handshake", "listen_to_music",
             "turn_on_record_player", "turn_off_record_player", "turn_on_tv", "turn_off_tv", "open_fridge",
             "close_fridge", "open_cabinet", "close_cabinet", "use_coffee_maker", "use_toaster", "use_microwave",
             "use_dishwasher", "use_smartphone", "use_laptop", "read_book"),
    "office": ("idle", "chat", "discuss", "attend_meeting", "handshake", "drink", "work_on_computer", "use_laptop",
               "use_smartphone", "read_book", "eat", "open_fridge", "close_fridge", "open_cabinet", "close_cabinet",
               "use_coffee_maker", "use_microwave", "use_water_dispenser", "take_out_document", "take_out_book",
               "clean_white_board", "write_on_white_board", "turn_on_tv", "turn_off_tv"),
    "restaurant": ("idle", "eat", "drink", "chat", "order_food", "order_drink", "pay_bill", "take_order",
                   "serve_food", "serve_drink", "deliver_menu", "clean_table", "use_coffee_maker", "use_smartphone",
                   "open_cabinet", "close_cabinet"),
}
"""The action labels each scene's cases offer (as the hand-written cases of that scene)."""

REF_ACTIONS: dict[str, str] = {"House": "home", "Office": "office", "Restaurant": "restaurant"}
"""A reference scene's cases offer the labels of the bundled scene of the same kind."""


@dataclass(frozen=True)
class Pool:
    """One generated case pool: its scenes, where they load from, its folder and its ids."""

    name: str
    """``ours`` (bundled scenes, next to the hand-written cases) or ``ours_ref`` (the authors' scenes)."""
    scenes: tuple[str, ...]
    first_id: int
    reference: bool
    """Whether the scenes are the reference data's (found by :func:`locate_reference`), not bundled."""

    def folder(self) -> Path:
        return ours_ref_folder() if self.reference else ours_folder()

    def scenes_root(self) -> Path:
        """Where :class:`_Scenes` finds the pool's scenes (raises ``ReferenceDataNotFound``
        with the lookup's one-line reason when a reference pool's data is absent)."""
        if not self.reference:
            return ours_folder()
        from orchestrator.reference_data import locate_reference

        return locate_reference().require()

    def scene_name(self, scene: str) -> str:
        return scene if self.reference else BUNDLED_PREFIX + scene

    def actions(self, scene: str) -> tuple[str, ...]:
        return ACTION_LABELS[REF_ACTIONS[scene] if self.reference else scene]


OURS_POOL = Pool("ours", SCENES, FIRST_ID, reference=False)
REF_POOL = Pool("ours_ref", REF_SCENES, REF_FIRST_ID, reference=True)
POOLS: dict[str, Pool] = {p.name: p for p in (OURS_POOL, REF_POOL)}

Query = dict[str, Any]
SEATS: Query = {"seats": True}


def _label(label: str) -> Query:
    return {"label": label}


def _seats_by(unit: Query) -> Query:
    return {"and": [SEATS, {"related": "adjacent to", "to": unit}]}


# ----- drafts -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Occupant:
    """A level-0 character already in the scene (named when the case is written)."""

    action: str
    position: str
    activity: str
    ongoing: bool = True


@dataclass(frozen=True)
class Draft:
    """One question about one scene, before names, distractors and a shape are chosen."""

    group: str
    scene: str
    recipe: str
    key: str
    slots: dict[str, list[str]]
    """Slot -> candidate words (one is drawn per case)."""
    action: str | None
    field: str = "relationships"
    relations: tuple[str, ...] = ("sit on",)
    objects: Query | None = None
    count: str = "any"
    wait_for: Query | None = None
    occupants: tuple[Occupant, ...] = ()
    avoid: frozenset[str] = frozenset()
    """Objects no distractor may use or stand at."""
    noun: str | None = None
    """The label whose nouns fill ``{noun}`` in the activity phrases."""


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
        from tools.character_states import WorldView

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


def _extreme(facts: SceneFacts, candidates: frozenset[str], landmark: str, op: str) -> str | None:
    """The candidate clearly nearest to (farthest from) the landmark object, or None when the
    runner-up is within :data:`MARGIN_M`."""
    if len(candidates) < 2:
        return None
    sign = 1.0 if op == "nearest" else -1.0
    ranked = sorted((sign * facts.distance(c, landmark), c) for c in candidates)
    return ranked[0][1] if ranked[1][0] - ranked[0][0] >= MARGIN_M else None


def _nouns(label: str) -> list[str]:
    return list(NOUNS[label])


def _acts(phrases: tuple[str, ...] | list[str], noun_label: str | None = None) -> list[str]:
    nouns = NOUNS.get(noun_label or "", ("",))
    return [p.replace("{noun}", n) for p in phrases for n in (nouns if "{noun}" in p else nouns[:1])]


def _seated_acts(facts: SceneFacts) -> list[tuple[str, list[str]]]:
    return [(a, list(p)) for a, p in SEATED.items() if a in facts.actions]


@dataclass(frozen=True)
class SeatedUse:
    """A seated activity whose seats follow from the objects it needs."""

    action: str
    units: Query
    """The places the activity happens at (tables, desks), or the seats themselves."""
    seats_are_units: bool = False

    def seats(self, unit: Query) -> Query:
        return {"and": [SEATS, unit]} if self.seats_are_units else _seats_by(unit)


def _seated_uses(facts: SceneFacts) -> list[SeatedUse]:
    uses = [
        SeatedUse("use_laptop", {"anchors_of": "on", "from": _label("laptop")}),
        SeatedUse("work_on_computer", {"anchors_of": "on", "from": _label("monitor")}),
        SeatedUse("eat", {"anchors_of": "on", "from": _label("plate")}),
        SeatedUse("order_drink", _seats_by(_label("bar_counter")), seats_are_units=True),
        SeatedUse("watch_tv", {"and": [SEATS, {"anchors_of": "in front of", "from": {"anchors_of": "on", "from": _label("tv")}}]},
                  seats_are_units=True),
        SeatedUse("attend_meeting", {"and": [_label("table"), {"region_of": _label("white_board")}]}),
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


# ----- recipes ----------------------------------------------------------------------------------
def oa_device(facts: SceneFacts) -> Iterator[Draft]:
    for label, uses in DEVICE_USES.items():
        if facts.count(label) != 1:
            continue
        name = facts.single(label)
        relations = ("adjacent to", "in front of") if facts.scene.by_name[name].has_facing else ("adjacent to",)
        for action, phrases in uses:
            if action not in facts.actions:
                continue
            for copy in (1, 2):
                yield Draft("OA", facts.name, "oa.device", f"{action}:{copy}", {"act": list(phrases)}, action,
                            relations=relations, objects=_label(label), count="one", avoid=frozenset({name}),
                            noun=label)


def oa_seated_use(facts: SceneFacts) -> Iterator[Draft]:
    for use in _seated_uses(facts):
        seats = facts.eval(use.seats(use.units))
        for copy in (1, 2):
            yield Draft("OA", facts.name, "oa.seated_use", f"{use.action}:{copy}", {"act": list(SEATED_USES[use.action])},
                        use.action, objects=use.seats(use.units), count="one" if len(seats) == 1 else "any", avoid=seats)


def rc_seat_extreme(facts: SceneFacts) -> Iterator[Draft]:
    for kind in facts.seat_kinds():
        seats = facts.eval(_label(kind))
        for lm in facts.landmarks():
            landmark = facts.single(lm)
            for op in ("nearest", "farthest"):
                if _extreme(facts, seats, landmark, op) is None:
                    continue
                for action, acts in _seated_acts(facts):
                    recipe = "rc.seat_near" if op == "nearest" else "rc.seat_far"
                    yield Draft("RC", facts.name, recipe, f"{kind}:{lm}:{op}:{action}",
                                {"seat": list(NOUNS[kind]), "seats": list(PLURALS[kind]), "lm": _nouns(lm), "act": acts},
                                action, objects={op: _label(kind), "to": _label(lm)}, count="one",
                                avoid=seats | {landmark})


def rc_table_extreme(facts: SceneFacts) -> Iterator[Draft]:
    for unit_label in ("table", "desk"):
        units = frozenset(u for u in facts.eval(_label(unit_label))
                          if any(s == u for s in facts.eval({"anchors_of": "adjacent to", "from": SEATS})))
        if len(units) < 2:
            continue
        with_seats: Query = {"and": [_label(unit_label), {"anchors_of": "adjacent to", "from": SEATS}]}
        all_seats = facts.eval(_seats_by(with_seats))
        for lm in facts.landmarks():
            landmark = facts.single(lm)
            for op in ("nearest", "farthest"):
                if _extreme(facts, units, landmark, op) is None:
                    continue
                query = _seats_by({op: with_seats, "to": _label(lm)})
                answer = facts.eval(query)
                for action, acts in _seated_acts(facts):
                    recipe = "rc.table_near" if op == "nearest" else "rc.table_far"
                    yield Draft("RC", facts.name, recipe, f"{unit_label}:{lm}:{op}:{action}",
                                {"table": list(NOUNS[unit_label]), "lm": _nouns(lm), "act": acts}, action,
                                objects=query, count="one" if len(answer) == 1 else "any",
                                avoid=all_seats | {landmark})


def _pairs(facts: SceneFacts) -> Iterator[tuple[str, str]]:
    for a, b in combinations(facts.landmarks(), 2):
        na, nb = facts.single(a), facts.single(b)
        if not (facts.floor_standing(na) and facts.floor_standing(nb)):
            continue
        ca, cb = facts.scene.by_name[na].center_xy, facts.scene.by_name[nb].center_xy
        if 1.5 <= float(((ca - cb) ** 2).sum() ** 0.5) <= 4.5:
            yield a, b


def rc_between(facts: SceneFacts) -> Iterator[Draft]:
    for a, b in _pairs(facts):
        for action, phrases in STANDING.items():
            if action not in facts.actions:
                continue
            yield Draft("RC", facts.name, "rc.between", f"{a}:{b}:{action}",
                        {"lm": _nouns(a), "lm2": _nouns(b), "act": list(phrases)}, action,
                        relations=("between",), objects={"or": [_label(a), _label(b)]},
                        avoid=frozenset({facts.single(a), facts.single(b)}))


def rc_facing(facts: SceneFacts) -> Iterator[Draft]:
    every = facts.eval(SEATS)
    for lm in facts.landmarks():
        query: Query = {"and": [SEATS, {"anchors_of": "in front of", "from": _label(lm)}]}
        answer = facts.eval(query)
        if not answer or len(answer) * 2 > len(every) or facts.single(lm) in answer:
            continue
        for action, acts in _seated_acts(facts):
            yield Draft("RC", facts.name, "rc.facing", f"{lm}:{action}", {"lm": _nouns(lm), "act": acts}, action,
                        objects=query, count="one" if len(answer) == 1 else "any",
                        avoid=answer | {facts.single(lm)})


def rc_region(facts: SceneFacts) -> Iterator[Draft]:
    every = facts.eval(SEATS)
    for lm in facts.landmarks():
        query: Query = {"and": [SEATS, {"region_of": _label(lm)}]}
        answer = facts.eval(query)
        if not answer or len(answer) > 4 or len(answer) * 2 > len(every) or facts.single(lm) in answer:
            continue
        for action, acts in _seated_acts(facts):
            yield Draft("RC", facts.name, "rc.region", f"{lm}:{action}", {"lm": _nouns(lm), "act": acts}, action,
                        objects=query, count="one" if len(answer) == 1 else "any", avoid=answer | {facts.single(lm)})


def oarc_use_extreme(facts: SceneFacts) -> Iterator[Draft]:
    for use in _seated_uses(facts):
        units = facts.eval(use.units)
        for lm in facts.landmarks():
            landmark = facts.single(lm)
            if landmark in units:
                continue
            for op in ("nearest", "farthest"):
                if _extreme(facts, units, landmark, op) is None:
                    continue
                query = use.seats({op: use.units, "to": _label(lm)})
                answer = facts.eval(query)
                recipe = "oarc.use_near" if op == "nearest" else "oarc.use_far"
                yield Draft("OA+RC", facts.name, recipe, f"{use.action}:{lm}:{op}",
                            {"lm": _nouns(lm), "act": list(SEATED_USES[use.action])}, use.action, objects=query,
                            count="one" if len(answer) == 1 else "any",
                            avoid=facts.eval(use.seats(use.units)) | {landmark})


def _sitting(action: str, seat: str, facts: SceneFacts) -> Occupant:
    phrases = SEATED_USES.get(action) or SEATED.get(action) or ("sit for a while",)
    return Occupant(action, f"sit on {seat}", phrases[len(seat) % len(phrases)])


def _single_seats(facts: SceneFacts, seats: Iterable[str]) -> bool:
    """Whether every seat holds one person (a couch or a bench taken by one is not full)."""
    return all(facts.scene.by_name[s].label not in MULTI_SEAT for s in seats)


def oass_free_use(facts: SceneFacts) -> Iterator[Draft]:
    for use in _seated_uses(facts):
        seats = sorted(facts.eval(use.seats(use.units)))
        if len(seats) < 2 or not _single_seats(facts, seats):
            continue
        for k in range(1, min(3, len(seats) - 1) + 1):
            for taken in combinations(seats, k):
                occupants = tuple(_sitting(use.action, s, facts) for s in taken)
                free = len(seats) - k
                yield Draft("OA+SS", facts.name, "oass.free_use", f"{use.action}:{','.join(taken)}",
                            {"act": list(SEATED_USES[use.action])}, use.action,
                            objects={"free": use.seats(use.units)}, count="one" if free == 1 else "any",
                            occupants=occupants, avoid=frozenset(seats))


def oass_wait_use(facts: SceneFacts) -> Iterator[Draft]:
    for use in _seated_uses(facts):
        seats = sorted(facts.eval(use.seats(use.units)))
        if len(seats) > 4 or not _single_seats(facts, seats):
            continue
        occupants = tuple(_sitting(use.action, s, facts) for s in seats)
        yield Draft("OA+SS", facts.name, "oass.wait_use", use.action, {"act": list(SEATED_USES[use.action])}, "idle",
                    wait_for=use.seats(use.units), occupants=occupants, avoid=frozenset(seats))


def oass_switch(facts: SceneFacts) -> Iterator[Draft]:
    for label, device in (("tv", "tv"), ("record_player", "record_player")):
        on, off = f"turn_on_{device}", f"turn_off_{device}"
        if facts.count(label) != 1 or on not in facts.actions or off not in facts.actions:
            continue
        name = facts.single(label)
        relations = ("adjacent to", "in front of") if facts.scene.by_name[name].has_facing else ("adjacent to",)
        switcher = Occupant(on, f"adjacent to {name}", f"switch on the {NOUNS[label][0]}", ongoing=False)
        yield Draft("OA+SS", facts.name, "oass.switch", label, {"thing": _nouns(label)}, off, relations=relations,
                    objects=_label(label), count="one", occupants=(switcher,), avoid=frozenset({name}))


def ss_wait_device(facts: SceneFacts) -> Iterator[Draft]:
    for label, uses in DEVICE_USES.items():
        if facts.count(label) != 1:
            continue
        name = facts.single(label)
        for action, phrases in uses:
            if action not in facts.actions:
                continue
            user = Occupant(action, f"adjacent to {name}", _acts(phrases, label)[0])
            yield Draft("SS", facts.name, "ss.wait_device", action, {"act": list(phrases)}, "idle",
                        wait_for=_label(label), occupants=(user,), avoid=frozenset({name}), noun=label)


def ss_free_kind(facts: SceneFacts) -> Iterator[Draft]:
    for kind in facts.seat_kinds(least=3):
        seats = sorted(facts.eval(_label(kind)))
        if len(seats) > 6:
            continue
        for action, acts in _seated_acts(facts):
            for k in (1, 2, 3):
                if k >= len(seats):
                    continue
                taken = tuple(seats[(i * 2 + len(action)) % len(seats)] for i in range(k))
                if len(set(taken)) < k:
                    continue
                occupants = tuple(_sitting(action, s, facts) for s in taken)
                free = len(seats) - k
                yield Draft("SS", facts.name, "ss.free_kind", f"{kind}:{action}:{k}",
                            {"seat": list(NOUNS[kind]), "act": acts}, action, objects={"free": _label(kind)},
                            count="one" if free == 1 else "any", occupants=occupants, avoid=frozenset(seats))


def _tables_with_seats(facts: SceneFacts, least: int) -> list[tuple[str, list[str]]]:
    out = []
    for table in sorted(facts.eval(_label("table"))):
        seats = sorted(s for s in facts.eval(SEATS) if (s, "adjacent to", table) in set(facts.graph.triples()))
        if len(seats) >= least:
            out.append((table, seats))
    return out


def ss_join_table(facts: SceneFacts) -> Iterator[Draft]:
    for table, seats in _tables_with_seats(facts, 3):
        for k in (1, 2):
            for taken in combinations(seats, k):
                if k == 2 and taken != (seats[0], seats[-1]) and taken != tuple(seats[:2]):
                    continue
                action = "eat" if "eat" in facts.actions else "drink"
                occupants = tuple(_sitting(action, s, facts) for s in taken)
                query: Query = {"free": _seats_by({"and": [_label("table"),
                                                           {"anchors_of": "adjacent to", "from": {"seat_of": "$0"}}]})}
                yield Draft("SS", facts.name, "ss.join_table", f"{table}:{','.join(taken)}", {"table": ["table"]},
                            "eat || chat" if "chat" in facts.actions else "eat", objects=query,
                            count="one" if len(seats) - k == 1 else "any", occupants=occupants,
                            avoid=frozenset(seats) | {table})


def rcss_free_extreme(facts: SceneFacts) -> Iterator[Draft]:
    for kind in facts.seat_kinds(least=3):
        seats = facts.eval(_label(kind))
        for lm in facts.landmarks():
            landmark = facts.single(lm)
            best = _extreme(facts, seats, landmark, "nearest")
            if best is None:
                continue
            free = seats - {best}
            answer = _extreme(facts, free, landmark, "nearest")
            if answer is None:
                continue
            for action, acts in _seated_acts(facts):
                occupants = (_sitting(action, best, facts),)
                yield Draft("RC+SS", facts.name, "rcss.free_near", f"{kind}:{lm}:{action}",
                            {"seat": list(NOUNS[kind]), "seats": list(PLURALS[kind]), "lm": _nouns(lm), "act": acts},
                            action, objects={"nearest": {"free": _label(kind)}, "to": _label(lm)}, count="one",
                            occupants=occupants, avoid=seats | {landmark})


def rcss_beside(facts: SceneFacts) -> Iterator[Draft]:
    triples = set(facts.graph.triples())
    for seat in sorted(facts.eval(SEATS)):
        label = facts.scene.by_name[seat].label
        sides = sorted(s for s in facts.eval(_label(label))
                       if (s, "to the left of", seat) in triples or (s, "to the right of", seat) in triples)
        if not sides:
            continue
        for action, acts in _seated_acts(facts):
            occupants: tuple[Occupant, ...] = (_sitting(action, seat, facts),)
            if len(sides) == 2:
                occupants += (_sitting(action, sides[len(action) % 2], facts),)
            query: Query = {"free": {"and": [SEATS, {"related": ["to the left of", "to the right of"],
                                                     "to": {"seat_of": "$0"}}]}}
            left = len(sides) - (len(occupants) - 1)
            yield Draft("RC+SS", facts.name, "rcss.beside", f"{seat}:{action}", {"act": acts}, action, objects=query,
                        count="one" if left == 1 else "any", occupants=occupants,
                        avoid=frozenset(sides) | {seat})


def rcss_across(facts: SceneFacts) -> Iterator[Draft]:
    triples = set(facts.graph.triples())
    tables = facts.eval(_label("table"))
    for seat in sorted(facts.eval(SEATS)):
        if not any((seat, "adjacent to", t) in triples for t in tables):
            continue
        opposite = sorted(s for s in facts.eval(SEATS) if (s, "in front of", seat) in triples)
        if len(opposite) != 1:
            continue
        for action, acts in _seated_acts(facts):
            query: Query = {"free": {"and": [SEATS, {"related": "in front of", "to": {"seat_of": "$0"}}]}}
            yield Draft("RC+SS", facts.name, "rcss.across", f"{seat}:{action}", {"act": acts}, action, objects=query,
                        count="one", occupants=(_sitting(action, seat, facts),), avoid=frozenset(opposite) | {seat})


def pi_place(facts: SceneFacts) -> Iterator[Draft]:
    for lm in facts.landmarks():
        name = facts.single(lm)
        obj = facts.scene.by_name[name]
        places: list[tuple[str, str, dict[str, list[str]]]] = [("pi.beside", "adjacent to", {})]
        if obj.has_facing:
            places += [("pi.front", "in front of", {}), ("pi.behind", "behind", {}),
                       ("pi.side", "to the left of", {"side": ["left"], "other_side": ["right"]}),
                       ("pi.side", "to the right of", {"side": ["right"], "other_side": ["left"]})]
        for recipe, relation, extra in places:
            yield Draft("PI", facts.name, recipe, f"{lm}:{relation}", {"lm": _nouns(lm), **extra}, None,
                        field="sampled_position", relations=(relation,), objects=_label(lm), count="one",
                        avoid=frozenset({name}))
    for a, b in _pairs(facts):
        yield Draft("PI", facts.name, "pi.between", f"{a}:{b}", {"lm": _nouns(a), "lm2": _nouns(b)}, None,
                    field="sampled_position", relations=("between",), objects={"or": [_label(a), _label(b)]},
                    avoid=frozenset({facts.single(a), facts.single(b)}))


RECIPES: dict[str, tuple[Callable[[SceneFacts], Iterator[Draft]], ...]] = {
    "OA": (oa_device, oa_seated_use),
    "RC": (rc_seat_extreme, rc_table_extreme, rc_between, rc_facing, rc_region),
    "SS": (ss_wait_device, ss_free_kind, ss_join_table),
    "OA+RC": (oarc_use_extreme,),
    "OA+SS": (oass_free_use, oass_wait_use, oass_switch),
    "RC+SS": (rcss_free_extreme, rcss_beside, rcss_across),
    "PI": (pi_place,),
}


# ----- writing a case ---------------------------------------------------------------------------
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
                    out.append(Chore(action, f"adjacent to {obj}", _acts(phrases, label)[-1], obj, obj))
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
        choices["act"] = _acts(tuple(phrases), draft.noun)
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
    case = _as_case({"id": 0, "tags": ["OA"], "scene_name": facts.scene_name, "action_labels": [],
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


def _as_case(data: dict[str, Any], folder: str) -> BenchmarkCase:
    source = f"{folder}/testcase_{data['id']}.json"
    return BenchmarkCase.model_validate({**data, "source": source, "raw": data})


# ----- the pool ---------------------------------------------------------------------------------
def _facts(pool: Pool = OURS_POOL) -> dict[str, SceneFacts]:
    out = {}
    for name in pool.scenes:
        scene = load_scene(pool.scenes_root() / "configs" / "scenes" / name) if pool.reference \
            else load_bundled_scene(name)
        out[name] = SceneFacts(name, scene, build_scene_graph(scene), cluster_objects(scene), pool.actions(name),
                               pool.scene_name(name))
    return out


def _order(drafts: list[Draft], rng: random.Random, scenes: tuple[str, ...] = SCENES) -> list[Draft]:
    """Round-robin over scenes, and within a scene over recipes, each list shuffled."""
    by_scene: dict[str, dict[str, list[Draft]]] = {}
    for d in drafts:
        by_scene.setdefault(d.scene, {}).setdefault(d.recipe, []).append(d)
    streams = []
    for scene in scenes:
        recipes = by_scene.get(scene, {})
        for lst in recipes.values():
            rng.shuffle(lst)
        queues = [recipes[r] for r in sorted(recipes)]
        merged = []
        while any(queues):
            for q in queues:
                if q:
                    merged.append(q.pop(0))
        streams.append(merged)
    out = []
    while any(streams):
        for s in streams:
            if s:
                out.append(s.pop(0))
    return out


def generate(pool: Pool = OURS_POOL) -> list[dict[str, Any]]:
    """Every generated case of ``pool``, in id order (see the module docstring)."""
    facts = _facts(pool)
    scenes = _Scenes(pool.scenes_root())
    cases: list[dict[str, Any]] = []
    next_id = pool.first_id
    for group in GROUPS:
        rng = random.Random(f"{GENERATOR_SEED}:{group}")
        drafts = [d for f in facts.values() for recipe in RECIPES[group] for d in recipe(f)]
        made: dict[str, int] = {}
        turn: dict[tuple[str, str], int] = {}
        kept = 0
        for draft in _order(drafts, rng, pool.scenes):
            if kept == TARGETS[group]:
                break
            stream = f"{draft.recipe}:{draft.scene}"
            side = SIDES[(first_side(stream) + made.get(stream, 0)) % 2]
            shapes = on_side(sorted(SHAPES[draft.recipe]), f"shape:{draft.recipe}", side)
            shape_id = f"{draft.recipe}.{shapes[turn.get((draft.recipe, side), 0) % len(shapes)]}"
            for attempt in range(ATTEMPTS):
                try:
                    data = write_case(draft, facts[draft.scene], next_id, shape_id, side, attempt)
                except NoDistractorError:
                    continue  # another attempt may draw fewer distractors
                if not check_case(_as_case(data, FOLDERS[group]), scenes).problems:
                    cases.append(data)
                    made[stream] = made.get(stream, 0) + 1
                    turn[(draft.recipe, side)] = turn.get((draft.recipe, side), 0) + 1
                    next_id += 1
                    kept += 1
                    break
    return cases


def render(data: dict[str, Any]) -> str:
    return json.dumps(data, indent=2, ensure_ascii=False) + "\n"


def write_pool(folder: Path, cases: list[dict[str, Any]], first_id: int = FIRST_ID) -> list[Path]:
    """Write ``cases`` under ``folder`` (removing generated files not among them); the paths written."""
    wanted = {folder / FOLDERS["+".join(c["tags"])] / f"testcase_{c['id']}.json": render(c) for c in cases}
    for old in folder.glob("*/testcase_*.json"):
        if int(old.stem.split("_")[-1]) >= first_id and old not in wanted:
            old.unlink()
    for path, text in wanted.items():
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")
    return sorted(wanted)


def differences(folder: Path, cases: list[dict[str, Any]], first_id: int = FIRST_ID) -> list[str]:
    """Files of ``folder`` that differ from ``cases`` (missing, changed or extra generated files)."""
    wanted = {folder / FOLDERS["+".join(c["tags"])] / f"testcase_{c['id']}.json": render(c) for c in cases}
    out = [f"{p}: missing" for p in wanted if not p.exists()]
    out += [f"{p}: differs" for p, t in wanted.items() if p.exists() and p.read_text(encoding="utf-8") != t]
    out += [f"{p}: not generated" for p in folder.glob("*/testcase_*.json")
            if int(p.stem.split("_")[-1]) >= first_id and p not in wanted]
    return sorted(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmark.own_cases.generate", description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only compare the folder with what the code generates")
    parser.add_argument("--pool", choices=sorted(POOLS), default=OURS_POOL.name,
                        help="ours: the bundled scenes (default); ours_ref: the authors' scenes (needs the reference data)")
    parser.add_argument("folder", nargs="?", type=Path, default=None,
                        help="case folder (default: the pool's, benchmark/cases/ours or benchmark/cases/ours_ref)")
    args = parser.parse_args(argv)
    pool = POOLS[args.pool]
    folder = args.folder or pool.folder()
    try:
        cases = generate(pool)
    except ReferenceDataNotFound as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.check:
        diffs = differences(folder, cases, pool.first_id)
        for d in diffs:
            print(d)
        print(f"{len(cases)} generated cases; {len(diffs)} file(s) differ")
        return 1 if diffs else 0
    write_pool(folder, cases, pool.first_id)
    counts: dict[str, int] = {}
    for c in cases:
        counts["+".join(c["tags"])] = counts.get("+".join(c["tags"]), 0) + 1
    print(f"{len(cases)} generated cases written to {folder}: " + ", ".join(f"{g} {counts.get(g, 0)}" for g in GROUPS))
    return 0


if __name__ == "__main__":
    sys.exit(main())

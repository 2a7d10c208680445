"""The recipes: one per kind of question, each a function of a scene's :class:`SceneFacts`
that yields the :class:`Draft` s it can ask there (:data:`RECIPES`, per tag group).

A recipe proposes only questions whose answer is clear: a nearest / farthest answer through
:func:`clear_extreme`, an occupancy question never on a seat several people share
(:data:`MULTI_SEAT`). Which drafts become cases is :mod:`.generate`'s choice.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from itertools import combinations

from storyteller.benchmark.own_cases.drafts import Draft, Occupant, Query
from storyteller.benchmark.own_cases.phrasing import DEVICE_USES, NOUNS, PLURALS, SEATED, SEATED_USES, STANDING
from storyteller.benchmark.own_cases.scene_facts import (
    SEATS,
    SceneFacts,
    activities,
    clear_extreme,
    nouns_of,
    of_label,
    seated_activities,
    seated_uses,
    seats_by,
)

MULTI_SEAT = frozenset({"couch", "bench"})
"""Seats several people share: never the answer of an occupancy question."""


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
                            relations=relations, objects=of_label(label), count="one", avoid=frozenset({name}),
                            noun=label)


def oa_seated_use(facts: SceneFacts) -> Iterator[Draft]:
    for use in seated_uses(facts):
        seats = facts.eval(use.seats(use.units))
        for copy in (1, 2):
            yield Draft("OA", facts.name, "oa.seated_use", f"{use.action}:{copy}", {"act": list(SEATED_USES[use.action])},
                        use.action, objects=use.seats(use.units), count="one" if len(seats) == 1 else "any", avoid=seats)


def _clear_extremes(facts: SceneFacts, candidates: frozenset[str], *, landmarks_among: bool = True
                    ) -> Iterator[tuple[str, str, str]]:
    """(landmark label, landmark object, "nearest" or "farthest") for every landmark and
    direction in which one of ``candidates`` is clearly the extreme (:func:`clear_extreme`);
    ``landmarks_among=False`` passes over a landmark that is itself a candidate."""
    for lm in facts.landmarks():
        landmark = facts.single(lm)
        if not landmarks_among and landmark in candidates:
            continue
        for op in ("nearest", "farthest"):
            if clear_extreme(facts, candidates, landmark, op) is not None:
                yield lm, landmark, op


def rc_seat_extreme(facts: SceneFacts) -> Iterator[Draft]:
    for kind in facts.seat_kinds():
        seats = facts.eval(of_label(kind))
        for lm, landmark, op in _clear_extremes(facts, seats):
            for action, acts in seated_activities(facts):
                recipe = "rc.seat_near" if op == "nearest" else "rc.seat_far"
                yield Draft("RC", facts.name, recipe, f"{kind}:{lm}:{op}:{action}",
                            {"seat": list(NOUNS[kind]), "seats": list(PLURALS[kind]), "lm": nouns_of(lm), "act": acts},
                            action, objects={op: of_label(kind), "to": of_label(lm)}, count="one",
                            avoid=seats | {landmark})


def rc_table_extreme(facts: SceneFacts) -> Iterator[Draft]:
    for unit_label in ("table", "desk"):
        units = frozenset(u for u in facts.eval(of_label(unit_label))
                          if any(s == u for s in facts.eval({"anchors_of": "adjacent to", "from": SEATS})))
        if len(units) < 2:
            continue
        with_seats: Query = {"and": [of_label(unit_label), {"anchors_of": "adjacent to", "from": SEATS}]}
        all_seats = facts.eval(seats_by(with_seats))
        for lm, landmark, op in _clear_extremes(facts, units):
            query = seats_by({op: with_seats, "to": of_label(lm)})
            answer = facts.eval(query)
            for action, acts in seated_activities(facts):
                recipe = "rc.table_near" if op == "nearest" else "rc.table_far"
                yield Draft("RC", facts.name, recipe, f"{unit_label}:{lm}:{op}:{action}",
                            {"table": list(NOUNS[unit_label]), "lm": nouns_of(lm), "act": acts}, action,
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
                        {"lm": nouns_of(a), "lm2": nouns_of(b), "act": list(phrases)}, action,
                        relations=("between",), objects={"or": [of_label(a), of_label(b)]},
                        avoid=frozenset({facts.single(a), facts.single(b)}))


def rc_facing(facts: SceneFacts) -> Iterator[Draft]:
    every = facts.eval(SEATS)
    for lm in facts.landmarks():
        query: Query = {"and": [SEATS, {"anchors_of": "in front of", "from": of_label(lm)}]}
        answer = facts.eval(query)
        if not answer or len(answer) * 2 > len(every) or facts.single(lm) in answer:
            continue
        for action, acts in seated_activities(facts):
            yield Draft("RC", facts.name, "rc.facing", f"{lm}:{action}", {"lm": nouns_of(lm), "act": acts}, action,
                        objects=query, count="one" if len(answer) == 1 else "any",
                        avoid=answer | {facts.single(lm)})


def rc_region(facts: SceneFacts) -> Iterator[Draft]:
    every = facts.eval(SEATS)
    for lm in facts.landmarks():
        query: Query = {"and": [SEATS, {"region_of": of_label(lm)}]}
        answer = facts.eval(query)
        if not answer or len(answer) > 4 or len(answer) * 2 > len(every) or facts.single(lm) in answer:
            continue
        for action, acts in seated_activities(facts):
            yield Draft("RC", facts.name, "rc.region", f"{lm}:{action}", {"lm": nouns_of(lm), "act": acts}, action,
                        objects=query, count="one" if len(answer) == 1 else "any", avoid=answer | {facts.single(lm)})


def oarc_use_extreme(facts: SceneFacts) -> Iterator[Draft]:
    for use in seated_uses(facts):
        units = facts.eval(use.units)
        for lm, landmark, op in _clear_extremes(facts, units, landmarks_among=False):
            query = use.seats({op: use.units, "to": of_label(lm)})
            answer = facts.eval(query)
            recipe = "oarc.use_near" if op == "nearest" else "oarc.use_far"
            yield Draft("OA+RC", facts.name, recipe, f"{use.action}:{lm}:{op}",
                        {"lm": nouns_of(lm), "act": list(SEATED_USES[use.action])}, use.action, objects=query,
                        count="one" if len(answer) == 1 else "any",
                        avoid=facts.eval(use.seats(use.units)) | {landmark})


def _sitting(action: str, seat: str, facts: SceneFacts) -> Occupant:
    phrases = SEATED_USES.get(action) or SEATED.get(action) or ("sit for a while",)
    return Occupant(action, f"sit on {seat}", phrases[len(seat) % len(phrases)])


def _single_seats(facts: SceneFacts, seats: Iterable[str]) -> bool:
    """Whether every seat holds one person (a couch or a bench taken by one is not full)."""
    return all(facts.scene.by_name[s].label not in MULTI_SEAT for s in seats)


def oass_free_use(facts: SceneFacts) -> Iterator[Draft]:
    for use in seated_uses(facts):
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
    for use in seated_uses(facts):
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
        yield Draft("OA+SS", facts.name, "oass.switch", label, {"thing": nouns_of(label)}, off, relations=relations,
                    objects=of_label(label), count="one", occupants=(switcher,), avoid=frozenset({name}))


def ss_wait_device(facts: SceneFacts) -> Iterator[Draft]:
    for label, uses in DEVICE_USES.items():
        if facts.count(label) != 1:
            continue
        name = facts.single(label)
        for action, phrases in uses:
            if action not in facts.actions:
                continue
            user = Occupant(action, f"adjacent to {name}", activities(phrases, label)[0])
            yield Draft("SS", facts.name, "ss.wait_device", action, {"act": list(phrases)}, "idle",
                        wait_for=of_label(label), occupants=(user,), avoid=frozenset({name}), noun=label)


def ss_free_kind(facts: SceneFacts) -> Iterator[Draft]:
    for kind in facts.seat_kinds(least=3):
        seats = sorted(facts.eval(of_label(kind)))
        if len(seats) > 6:
            continue
        for action, acts in seated_activities(facts):
            for k in (1, 2, 3):
                if k >= len(seats):
                    continue
                taken = tuple(seats[(i * 2 + len(action)) % len(seats)] for i in range(k))
                if len(set(taken)) < k:
                    continue
                occupants = tuple(_sitting(action, s, facts) for s in taken)
                free = len(seats) - k
                yield Draft("SS", facts.name, "ss.free_kind", f"{kind}:{action}:{k}",
                            {"seat": list(NOUNS[kind]), "act": acts}, action, objects={"free": of_label(kind)},
                            count="one" if free == 1 else "any", occupants=occupants, avoid=frozenset(seats))


def _tables_with_seats(facts: SceneFacts, least: int) -> list[tuple[str, list[str]]]:
    out = []
    for table in sorted(facts.eval(of_label("table"))):
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
                query: Query = {"free": seats_by({"and": [of_label("table"),
                                                           {"anchors_of": "adjacent to", "from": {"seat_of": "$0"}}]})}
                yield Draft("SS", facts.name, "ss.join_table", f"{table}:{','.join(taken)}", {"table": ["table"]},
                            "eat || chat" if "chat" in facts.actions else "eat", objects=query,
                            count="one" if len(seats) - k == 1 else "any", occupants=occupants,
                            avoid=frozenset(seats) | {table})


def rcss_free_extreme(facts: SceneFacts) -> Iterator[Draft]:
    for kind in facts.seat_kinds(least=3):
        seats = facts.eval(of_label(kind))
        for lm in facts.landmarks():
            landmark = facts.single(lm)
            best = clear_extreme(facts, seats, landmark, "nearest")
            if best is None:
                continue
            free = seats - {best}
            answer = clear_extreme(facts, free, landmark, "nearest")
            if answer is None:
                continue
            for action, acts in seated_activities(facts):
                occupants = (_sitting(action, best, facts),)
                yield Draft("RC+SS", facts.name, "rcss.free_near", f"{kind}:{lm}:{action}",
                            {"seat": list(NOUNS[kind]), "seats": list(PLURALS[kind]), "lm": nouns_of(lm), "act": acts},
                            action, objects={"nearest": {"free": of_label(kind)}, "to": of_label(lm)}, count="one",
                            occupants=occupants, avoid=seats | {landmark})


def rcss_beside(facts: SceneFacts) -> Iterator[Draft]:
    triples = set(facts.graph.triples())
    for seat in sorted(facts.eval(SEATS)):
        label = facts.scene.by_name[seat].label
        sides = sorted(s for s in facts.eval(of_label(label))
                       if (s, "to the left of", seat) in triples or (s, "to the right of", seat) in triples)
        if not sides:
            continue
        for action, acts in seated_activities(facts):
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
    tables = facts.eval(of_label("table"))
    for seat in sorted(facts.eval(SEATS)):
        if not any((seat, "adjacent to", t) in triples for t in tables):
            continue
        opposite = sorted(s for s in facts.eval(SEATS) if (s, "in front of", seat) in triples)
        if len(opposite) != 1:
            continue
        for action, acts in seated_activities(facts):
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
            yield Draft("PI", facts.name, recipe, f"{lm}:{relation}", {"lm": nouns_of(lm), **extra}, None,
                        field="sampled_position", relations=(relation,), objects=of_label(lm), count="one",
                        avoid=frozenset({name}))
    for a, b in _pairs(facts):
        yield Draft("PI", facts.name, "pi.between", f"{a}:{b}", {"lm": nouns_of(a), "lm2": nouns_of(b)}, None,
                    field="sampled_position", relations=("between",), objects={"or": [of_label(a), of_label(b)]},
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

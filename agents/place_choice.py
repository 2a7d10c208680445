"""The seat of a sitting event as a choice among the seats the scene allows, checked by geometry.

A 0.5B model writing ``get_area_to_sit_on("chair_1")`` picks a seat of the asked kind, but often
not the one the instruction's relations single out ("the chair farthest from the couch",
"opposite Goran"). Here the seat is decided before the program is written, in three steps:

1. **Candidates** (code): the free seats the event's words are about, read with the landmarks
   taken out (:func:`storyteller.agents.relation_words.without_relations`, so "the desk farthest from the
   couch" is about desks, not the couch) by :func:`storyteller.agents.shortlist.event_shortlist`; every free
   seat when the words single none out. At most :data:`MAX_CANDIDATES`.
2. **The model's ranking**: one prompt lists each candidate with its relations to what the
   words name (gaps in metres to the named things and characters, which of them it faces, the
   table it is at and who sits there: :func:`candidate_notes`), and the model scores every
   candidate's name as its reply (:mod:`storyteller.agents.scored_choice`: log-likelihoods from the logits
   for the embedded model, an enum-constrained reply elsewhere).
3. **The check** (code): the relations the words state (nearest / near / farthest / facing /
   between, :func:`storyteller.agents.relation_words.stated_relations`) are computed from the scene
   (:func:`storyteller.tools.place_relations.keep_satisfying`); the chosen seat is the model's best-ranked
   candidate that meets them. When they leave one candidate, no model call is made.

The chosen seat then is the only one the event's program grammar offers, and the parser's
request names it. Events of one character that sit (the grammar would offer seats only) get a
choice; a group's seats, and standing places, are left to the program as before.
"""

from __future__ import annotations

import re
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from storyteller.agents.area_words import DescribedArea, named_areas
from storyteller.agents.llm_port import ChatMessage, LLMRequest
from storyteller.agents.prompt_templates import PromptLibrary, package_prompts
from storyteller.agents.relation_words import (
    CLAUSE_ENDS,
    RelationMention,
    back_references,
    joined_labels,
    stated_relations,
    without_relations,
)
from storyteller.agents.scored_choice import ScoredChoice, choice_request
from storyteller.agents.shortlist import CLOSE_M, event_shortlist, mentioned_labels
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.place_relations import (
    FACING_DEG,
    Reference,
    StatedRelation,
    facing_angle,
    gap,
    group_gap,
    keep_satisfying,
    sits_at,
    table_of,
)
from storyteller.tools.scene_graph import footprint_distance

MAX_CANDIDATES = 10
"""Seats offered to the model at most (those meeting the stated relations first)."""
"""What one sits at: a non-seat object this tall (m) with a footprint this large (m²): tables,
desks, counters; not lamps or loudspeakers."""
WITH_M = 1.5
"""Characters within this distance (m) of a seat are with it ("with Hakon")."""
MAX_NOTES = 4
"""Named things whose gap each candidate's line gives."""


@dataclass(frozen=True)
class SeatCandidates:
    """The seats an event may take, what the prompt says of each, and those meeting the
    relations the words state (``allowed``, a subset of ``candidates``, never empty)."""

    candidates: tuple[str, ...]
    notes: Mapping[str, str]
    allowed: tuple[str, ...]
    relations: tuple[StatedRelation, ...]


SEATED_MARGIN_M = 0.15
"""A character whose point lies within this of a seat's footprint sits on it (and faces its way)."""


def _character(scene: Scene, name: str, xy: tuple[float, float]) -> Reference:
    """A character as a reference: their point, and the facing of the seat they sit on, if any
    (what "to the right of Kim" is measured in)."""
    point = np.asarray(xy, dtype=float)
    seat = next((o for o in scene.objects if o.is_seat and bool(o.contains_xy(point, SEATED_MARGIN_M))), None)
    return Reference(name, point=xy, facing=None if seat is None else (float(seat.facing[0]), float(seat.facing[1])))


def references_of(
    scene: Scene, mention: RelationMention, others: Mapping[str, tuple[float, float]]
) -> tuple[tuple[Reference, ...], ...]:
    groups: list[tuple[Reference, ...]] = []
    for thing in mention.references:
        if thing and thing[0].startswith("@"):
            name = thing[0][1:]
            groups.append((_character(scene, name, others[name]),) if name in others else ())
        else:
            groups.append(tuple(Reference(o.name, obj=o) for o in scene.objects if o.label in thing))
    return tuple(groups)


def _named_things(
    scene: Scene, text: str, others: Mapping[str, tuple[float, float]], seats: set[str]
) -> list[tuple[str, tuple[Reference, ...]]]:
    """What the words name that a seat can stand in relation to: characters outside the event,
    then object labels (not the candidates' own kinds), in order of mention."""
    words = set(re.findall(r"[A-Za-z0-9_]+", text))
    out: list[tuple[str, tuple[Reference, ...]]] = [
        (name, (Reference(name, point=xy),)) for name, xy in others.items() if name in words
    ]
    for label in mentioned_labels(text, scene.labels):
        group = tuple(Reference(o.name, obj=o) for o in scene.objects if o.label == label and o.name not in seats)
        if group:
            out.append((label.replace("_", " "), group))
    return out[:MAX_NOTES]


OTHER_WORDS = frozenset({"other", "another", "different", "second", "next", "new", "separate"})
"""Words before a table that mean not the one already named ("sits at the other table")."""


def _another(text: str, things: Sequence[str]) -> bool:
    """Whether ``text`` asks for another of ``things`` ("at a different table")."""
    words = re.findall(r"[a-z]+", text.lower())
    heads = {label.split("_")[-1] for label in things}
    return any(w in heads and i > 0 and words[i - 1] in OTHER_WORDS for i, w in enumerate(words))


def candidate_notes(
    scene: Scene, seat: SceneObject, named: Sequence[tuple[str, tuple[Reference, ...]]],
    others: Mapping[str, tuple[float, float]], prompts: PromptLibrary,
) -> str:
    """One candidate's line: the thing it is at and who is with it, its gap to each named thing
    and whether it faces it (``prompts/event_parser/choose_seat_*.md``)."""
    parts: list[str] = []
    if (at := table_of(scene, seat)) is not None:
        parts.append(prompts.render_text("event_parser/choose_seat_at.md", thing=at.name))
    company = [n for n, xy in others.items() if gap(seat, Reference(n, point=xy)) <= WITH_M]
    if company:
        parts.append(prompts.render_text("event_parser/choose_seat_with.md", names=", ".join(company)))
    for _, group in named:
        best = min(group, key=lambda r: gap(seat, r))
        parts.append(prompts.render_text(
            "event_parser/choose_seat_gap.md", metres=f"{group_gap(seat, group):.1f}", thing=best.name,
        ))
        if facing_angle(seat, best) <= FACING_DEG:
            parts.append(prompts.render_text("event_parser/choose_seat_faces.md", thing=best.name))
    return "; ".join(parts)


def _seat_kinds(scene: Scene, text: str) -> set[str]:
    """The seat labels ``text`` names, the most specific only ("office chair" names office
    chairs, not every chair)."""
    seat_labels = {o.label for o in scene.objects if o.is_seat}
    named = [label for label in mentioned_labels(text, scene.labels) if label in seat_labels]
    return {a for a in named if not any(b != a and b.endswith("_" + a) for b in named)}


AT_SPAN = 5
"""Words after "at" that may name the place one sits at ("at the long oak table")."""


def places_sat_at(text: str, scene: Scene) -> tuple[str, ...]:
    """The labels of things people sit at (:func:`sits_at`) that ``text`` names right after
    "at" ("finds a free chair at the conference table", "settles at the bar"), in order."""
    words = re.findall(r"[a-z0-9_]+|[,.;:!?]", text.lower())
    out: list[str] = []
    for i, w in enumerate(words):
        if w != "at":
            continue
        span: list[str] = []
        for t in words[i + 1 : i + 1 + AT_SPAN]:
            if not t[0].isalnum() or (span and t in CLAUSE_ENDS):
                break
            span.append(t)
        for label in mentioned_labels(" ".join(span), scene.labels):
            if label not in out and any(o.label == label and sits_at(o) for o in scene.objects):
                out.append(label)
    return tuple(out)


def seat_candidates(
    scene: Scene, text: str, free_seats: Sequence[str], others: Mapping[str, tuple[float, float]],
    action_labels: Sequence[str] = (), prompts: PromptLibrary | None = None, before: str = "",
    areas: Sequence[DescribedArea] = (), unusable: Collection[str] = (),
) -> SeatCandidates:
    """The candidates of an event whose words are ``text`` (see the module docstring);
    ``others``: where the characters outside the event are; ``before``: the instruction's words
    before ``text``, which a place word pointing back ("sits down there too") refers to when the
    words state no relation of their own (:func:`storyteller.agents.relation_words.back_references`);
    ``areas``: the scene description's areas (:func:`storyteller.agents.area_words.described_areas`): when
    the words name one ("naps in the den"), the candidates are its seats; ``unusable``: seats
    the instruction rules out ("stool_2 is wobbly", :func:`storyteller.agents.out_of_use.out_of_use`), left
    out unless no other seat is free."""
    lib = prompts or package_prompts()
    by_name = {o.name: o for o in scene.objects}
    mentions = stated_relations(text, scene.labels, list(others))
    if not mentions:
        mentions = back_references(text, before, scene.labels, list(others))
    about = without_relations(text, mentions, scene.labels)
    free = [by_name[s] for s in free_seats if s in by_name]
    free = [s for s in free if s.name not in unusable] or free
    short = event_shortlist(scene, about, [s.name for s in free], action_labels, others=others).seats
    pool = [by_name[s] for s in short if s in by_name] or free
    kinds = _seat_kinds(scene, about)
    in_area = {n for a in named_areas(about, areas, lib, scene.labels) for n in a.objects}
    if area_seats := [s for s in free if s.name in in_area and (not kinds or s.label in kinds)]:
        pool = [s for s in pool if s.name in in_area] or area_seats  # a named seat kind outweighs the area
    at_places = places_sat_at(about, scene)
    if at_places and not _another(about, at_places):  # "a free chair at the long table": the seats at one
        pool = [s for s in pool if (t := table_of(scene, s)) is not None and t.label in at_places
                and (not kinds or s.label in kinds)] or pool
    pool = [s for s in pool if s.label in kinds] or pool if kinds else pool
    landmarks = {r.name for m in mentions for g in references_of(scene, m, others) for r in g}
    pool = [s for s in pool if s.name not in landmarks] or pool  # "beside the couch" is not the couch
    at_things = tuple(label for label in mentioned_labels(about, scene.labels)
                      if any(o.label == label and not o.is_seat and sits_at(o) for o in scene.objects))
    if at_things and not _another(about, at_things) and (ruled_out := [by_name[n] for n in unusable if n in by_name]):
        # "stool_2 is wobbly, so she takes a free seat by that table": the table of the seat ruled out
        tables = {t.name for seat in ruled_out if (t := table_of(scene, seat)) is not None}
        pool = [s for s in pool if (t := table_of(scene, s)) is not None and t.name in tables] or pool
    relations: list[StatedRelation] = []
    for m in mentions:
        refs = references_of(scene, m, others)
        if not any(refs):
            continue
        relation = StatedRelation(m.kind, refs)
        relations.append(relation)  # the seat meets it too: the chair at the table nearest X is near X
        # "the table beside the couch", or a relation of its own about "a seat at the table" ("away
        # from the bar, a seat at the most distant table"): the relation picks among the tables
        things = [
            o for o in scene.objects if o.label in (m.subject or at_things) and not o.is_seat
            and any(footprint_distance(s, o) <= CLOSE_M for s in pool)
        ]
        if things:
            kept = keep_satisfying([relation], things)
            pool = [s for s in pool if any(footprint_distance(s, t) <= CLOSE_M for t in kept)] or pool
    allowed = keep_satisfying(relations, pool)
    ordered = [*allowed, *(s for s in pool if s not in allowed)][:MAX_CANDIDATES]
    named = _named_things(scene, joined_labels(text, scene.labels), others, {s.name for s in ordered})
    notes = {s.name: candidate_notes(scene, s, named, others, lib) for s in ordered}
    return SeatCandidates(
        candidates=tuple(sorted((s.name for s in ordered), key=lambda n: [o.name for o in scene.objects].index(n))),
        notes=notes,
        allowed=tuple(s.name for s in allowed if s.name in notes),
        relations=tuple(relations),
    )


def seat_choice_request(
    prompts: PromptLibrary, seats: SeatCandidates, character: str, activity: str, instruction_part: str,
    *, seed: int | None = None, sim_frame: int | None = None,
) -> LLMRequest:
    """The one prompt whose reply scores each candidate (``prompts/event_parser/choose_seat*.md``)."""
    lines = "\n".join(
        prompts.render_text("event_parser/choose_seat_line.md", seat=s, notes=seats.notes[s] or "-") for s in seats.candidates
    )
    system = prompts.render("event_parser/choose_seat_system.md")
    user = prompts.render(
        "event_parser/choose_seat.md", character=character, activity=activity.strip(),
        instruction=(instruction_part or activity).strip(), seats=lines,
    )
    return choice_request(
        "event_parser", (ChatMessage(role="system", content=system), ChatMessage(role="user", content=user)),
        seats.candidates, seed=seed, sim_frame=sim_frame,
    )


def checked_choice(seats: SeatCandidates, ranked: ScoredChoice | None) -> str:
    """The model's best-ranked candidate that meets the stated relations (the only allowed one
    when there is no ranking)."""
    if ranked is None:
        return seats.allowed[0]
    return next((c for c in ranked.ranked if c in seats.allowed), seats.allowed[0])


def needs_model(seats: SeatCandidates) -> bool:
    """Whether the choice is the model's to make: more than one candidate meets the relations."""
    return len(seats.allowed) > 1


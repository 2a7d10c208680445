"""The seat of a sitting event as a choice among the seats the scene allows, checked by geometry:
relation words, the geometric checks (property tests on random scenes), the candidate builder,
the typed choice through a port, and the planning graph's ``choose_seat`` node."""

from __future__ import annotations

import json
import math

import anyio
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from storyteller.agents.instruction_parts import split_instruction
from storyteller.agents.llm_port import ChatMessage, LLMRequest, LLMResponse
from storyteller.agents.part_span import words_before, words_so_far
from storyteller.agents.place_choice import checked_choice, needs_model, seat_candidates, seat_choice_request
from storyteller.agents.prompt_templates import package_prompts
from storyteller.agents.relation_words import (
    RelationMention,
    back_references,
    points_back,
    stated_relations,
    without_relations,
)
from storyteller.agents.scored_choice import ChoiceError, choice_request, choose, read_choice
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.place_relations import (
    FACING_DEG,
    Reference,
    RelationKind,
    StatedRelation,
    facing_angle,
    group_gap,
    keep_satisfying,
    satisfying,
)
from storyteller.tools.scene_graph import footprint_distance


def obj(label: str, idx: int, x: float, y: float, *, seat: bool = False, facing: tuple[float, float] = (0.0, 1.0),
        size: tuple[float, float, float] = (0.5, 0.5, 0.9)) -> SceneObject:
    return SceneObject(
        name=f"{label}_{idx}", label=label, idx=idx, center=(x, y, size[2] / 2), size=size, facing=facing,
        has_facing=seat, sit_offset_vertical=0.45 if seat else 0.0,
    )


def room() -> Scene:
    """A row of four chairs facing north along y=0, a couch at the west end, a fridge at the
    east end, a table north of the chairs and a TV north of the table."""
    chairs = [obj("chair", i + 1, 1.0 + 1.5 * i, 0.0, seat=True) for i in range(4)]
    return Scene(name="room", bounds_min=(-4.0, -4.0), bounds_max=(10.0, 7.0), objects=(
        *chairs,
        obj("couch", 1, -1.5, 0.0, seat=True, size=(1.8, 0.8, 0.8)),
        obj("fridge", 1, 8.5, 0.0, size=(0.7, 0.7, 1.8)),
        obj("table", 1, 3.25, 1.2, size=(5.0, 0.9, 0.75)),
        obj("tv", 1, 3.25, 5.0, facing=(0.0, -1.0), size=(1.2, 0.2, 0.7)),
    ))


ROOM = room()
LABELS = ROOM.labels


# ----- relation words -----------------------------------------------------------------------
def test_relation_words_name_their_kind_and_landmark() -> None:
    (far,) = stated_relations("Mo sits on the chair farthest from the fridge.", LABELS)
    assert (far.kind, far.references) == ("farthest", (("fridge",),))
    (near,) = stated_relations("Mo takes the seat closest to the couch and reads.", LABELS)
    assert (near.kind, near.references) == ("nearest", (("couch",),))
    (facing,) = stated_relations("Mo sits down opposite Kim to chat.", LABELS, ["Kim", "Mo"])
    assert (facing.kind, facing.references) == ("facing", (("@Kim",),))
    (mid,) = stated_relations("Mo stands halfway from the couch to the fridge.", LABELS)
    assert (mid.kind, mid.references) == ("between", (("couch",), ("fridge",)))


def test_a_relation_word_before_what_it_describes_takes_its_landmark_after_to_or_from() -> None:
    assert stated_relations("Mo sits at the most distant table.", LABELS) == []  # no landmark: no relation
    (far,) = stated_relations("Mo sits on the most distant chair from the tv.", LABELS)
    assert (far.kind, far.references) == ("farthest", (("tv",),))


def test_the_thing_a_relation_describes_is_read_from_the_words_before_it() -> None:
    (m,) = stated_relations("Mo picks the table beside the couch and sits.", LABELS)
    assert m.subject == ("table",) and m.references == (("couch",),)
    (m,) = stated_relations("Mo sits beside the couch.", LABELS)
    assert m.subject == ()


def test_a_table_picked_by_a_relation_is_one_with_a_seat_to_take() -> None:
    scene = Scene(name="two", bounds_min=(-4.0, -4.0), bounds_max=(10.0, 7.0), objects=(
        *ROOM.objects, obj("table", 2, -1.5, 1.0, size=(1.0, 0.6, 0.45)),  # by the couch, no chair of its own
    ))
    free = tuple(o.name for o in scene.objects if o.is_seat)
    seats = seat_candidates(scene, "Mo picks the table beside the couch and sits down.", free, {})
    assert "couch_1" not in seats.candidates and seats.allowed == ("chair_1",)


def test_words_naming_no_thing_state_no_relation_and_the_rest_says_what_the_place_is() -> None:
    assert stated_relations("Mo sits by himself near nothing in particular.", LABELS) == []
    text = "Mo sits on the chair nearest the couch to read."
    assert without_relations(text, stated_relations(text, LABELS), LABELS) == "Mo sits on the chair to read ."


# ----- geometry (property tests) ------------------------------------------------------------
points = st.tuples(st.floats(-8, 8), st.floats(-8, 8))


@st.composite
def random_seats(draw: st.DrawFn) -> list[SceneObject]:
    n = draw(st.integers(2, 7))
    out = []
    for i in range(n):
        x, y = draw(points)
        angle = draw(st.floats(0, 2 * math.pi))
        out.append(obj("chair", i + 1, x, y, seat=True, facing=(math.cos(angle), math.sin(angle))))
    return out


@settings(max_examples=60, deadline=None, derandomize=True)
@given(random_seats(), points, st.sampled_from(["nearest", "farthest", "near", "facing"]))
def test_checks_keep_what_the_relation_says_and_never_empty_the_set(
    seats: list[SceneObject], at: tuple[float, float], kind: RelationKind
) -> None:
    ref = (Reference("landmark", obj=obj("lamp", 1, *at, size=(0.3, 0.3, 1.5))),)
    relation = StatedRelation(kind, (ref,))
    kept = keep_satisfying([relation], seats)
    assert kept and set(o.name for o in kept) <= {o.name for o in seats}
    gaps = {o.name: group_gap(o, ref) for o in seats}
    if kind == "nearest":
        assert min(gaps, key=gaps.__getitem__) in {o.name for o in kept}
        assert all(gaps[o.name] <= min(gaps.values()) + 0.3 + 1e-9 for o in kept)
    if kind == "farthest":
        assert max(gaps, key=gaps.__getitem__) in {o.name for o in kept}
    if kind == "facing" and satisfying(relation, seats):
        assert all(facing_angle(o, ref[0]) <= FACING_DEG for o in kept)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(random_seats(), points, points)
def test_between_keeps_the_seat_nearest_the_middle(seats: list[SceneObject], a: tuple[float, float], b: tuple[float, float]) -> None:
    first, second = (Reference("a", point=a),), (Reference("b", point=b),)
    kept = satisfying(StatedRelation("between", (first, second)), seats)
    mid = ((a[0] + b[0]) / 2, (a[1] + b[1]) / 2)
    dist = {o.name: math.dist(o.center[:2], mid) for o in seats}
    assert min(dist, key=dist.__getitem__) in {o.name for o in kept}


def test_a_relation_nobody_meets_or_without_landmark_leaves_the_set_alone() -> None:
    seats = [o for o in ROOM.objects if o.label == "chair"]
    behind = (Reference("x", point=(3.0, -9.0)),)  # every chair faces away from it
    assert keep_satisfying([StatedRelation("facing", (behind,))], seats) == seats
    assert keep_satisfying([StatedRelation("nearest", ((),))], seats) == seats


# ----- candidates ---------------------------------------------------------------------------
FREE = tuple(o.name for o in ROOM.objects if o.is_seat)


def test_the_landmark_is_no_candidate_and_the_stated_relation_decides() -> None:
    seats = seat_candidates(ROOM, "Mo sits on a chair farthest from the couch.", FREE, {})
    assert "couch_1" not in seats.candidates and seats.allowed == ("chair_4",)
    assert not needs_model(seats) and checked_choice(seats, None) == "chair_4"
    near = seat_candidates(ROOM, "Mo sits on the chair next to the fridge.", FREE, {})
    assert near.allowed == ("chair_4",)


def test_opposite_a_character_is_the_seat_that_faces_them_squarely() -> None:
    scene = Scene(name="pair", bounds_min=(-4.0, -4.0), bounds_max=(10.0, 7.0), objects=(
        *ROOM.objects, obj("chair", 5, 2.5, 2.4, seat=True, facing=(0.0, -1.0)),
        obj("chair", 6, 5.5, 2.4, seat=True, facing=(0.0, -1.0)),
    ))
    kim_at = (2.5, 0.0)  # Kim sits on chair_2, facing north across the table
    free = tuple(n for n in (o.name for o in scene.objects if o.is_seat) if n != "chair_2")
    seats = seat_candidates(scene, "Mo sits down opposite Kim.", free, {"Kim": kim_at})
    assert seats.allowed == ("chair_5",)


def test_there_points_back_to_the_character_or_thing_the_clause_before_names() -> None:
    assert back_references("Mo sits down there too.", "Kim is sitting at the table; ", LABELS, ["Kim"]) == [
        RelationMention("near", (("@Kim",),), 3, 4)]
    assert back_references("Mo sits there.", "Kim waits. Then the fridge hums.", LABELS, ["Kim"]) == [
        RelationMention("near", (("fridge",),), 2, 3)]
    assert back_references("There is a free chair, Mo sits.", "Kim waits by the fridge.", LABELS, ["Kim"]) == []
    assert back_references("Mo sits down.", "Kim waits by the fridge.", LABELS, ["Kim"]) == []
    assert points_back("Mo sits down there too.") and not points_back("There is a chair; Mo sits.")
    kim_at = (5.5, 0.4)  # beside chair_4
    free = tuple(n for n in FREE if n != "couch_1")
    pointed = seat_candidates(ROOM, "Mo comes over and sits down there too.", free, {"Kim": kim_at},
                              before="Kim is sitting at the table; ")
    assert pointed.allowed == ("chair_4",)
    # without the words before, nothing is stated: every chair is the model's to rank
    assert len(seat_candidates(ROOM, "Mo comes over and sits down there too.", free, {"Kim": kim_at}).allowed) == 4


def test_the_same_thing_or_their_thing_points_back_to_the_characters_named_before_it() -> None:
    """"Seeing Kim and Lu at a table, Mo sits at that same table": near both of them, so a seat
    at their table (not one beside Lu at the next table); "their table" and "that table" alike;
    a "that" before a word that is no thing of the scene points nowhere."""
    names = ["Kim", "Lu"]
    assert back_references("Seeing Kim and Lu at a table, Mo takes a free seat at that same table.", "", LABELS, names) == [
        RelationMention("near", (("@Kim",),), 15, 16), RelationMention("near", (("@Lu",),), 15, 16)]
    for text in ("Mo joins Kim and Lu at their table.", "Kim and Lu eat; Mo sits at that table too.",
                 "Kim and Lu talk, and Mo takes the same sofa."):
        assert [m.references for m in back_references(text, "", LABELS, names)] == [(("@Kim",),), (("@Lu",),)], text
    assert points_back("Mo sits at their table.", LABELS) and points_back("the same chair")
    assert not points_back("Mo sits on the chair that faces the TV.", LABELS) and not points_back("Mo sits at the table.", LABELS)
    assert back_references("Mo takes the chair that faces Kim.", "", LABELS, names) == []
    # Kim (chair_1) and Lu (chair_2) at table_1, chairs 3 and 4 free across it; chair_5 at table_2
    two_tables = Scene(name="cafe", bounds_min=(-4.0, -4.0), bounds_max=(8.0, 4.0), objects=(
        obj("table", 1, 0.0, 0.0, size=(2.0, 1.0, 0.75)), obj("table", 2, 4.0, 0.0, size=(1.0, 1.0, 0.75)),
        obj("chair", 1, -0.5, -0.8, seat=True), obj("chair", 2, 0.5, -0.8, seat=True),
        obj("chair", 3, -0.5, 0.8, seat=True, facing=(0.0, -1.0)), obj("chair", 4, 0.5, 0.8, seat=True, facing=(0.0, -1.0)),
        obj("chair", 5, 4.0, -0.8, seat=True),
    ))
    at = {"Kim": (-0.5, -0.8), "Lu": (0.5, -0.8)}
    free = ("chair_3", "chair_4", "chair_5")
    pointed = seat_candidates(two_tables, "Seeing Kim and Lu at a table, Mo takes a free seat at that same table.", free, at)
    assert pointed.allowed and set(pointed.allowed) <= {"chair_3", "chair_4"}
    assert "chair_5" in seat_candidates(two_tables, "Mo takes a free seat at a table.", free, at).allowed


def test_the_seat_prompt_quotes_the_instruction_up_to_the_part() -> None:
    instruction = "Kim is sitting at a table; Mo comes over and sits down there too. Then Mo reads."
    part = "Mo comes over and sits down there too."
    assert words_so_far(instruction, part) == "Kim is sitting at a table; Mo comes over and sits down there too."
    assert words_before(instruction, part) == "Kim is sitting at a table; "
    assert words_before(instruction, "Then Mo reads.").endswith("there too. Then ")
    assert words_so_far(instruction, "not in it") == "not in it" and words_before(instruction, "not in it") == ""


def test_without_stated_relations_the_model_chooses_and_the_prompt_describes_each_seat() -> None:
    near_kim = seat_candidates(ROOM, "Mo sits on a chair near Kim.", FREE, {"Kim": (4.0, 0.8)})
    assert near_kim.allowed == ("chair_3",) and "faces Kim" in near_kim.notes["chair_3"]
    seats = seat_candidates(ROOM, "Mo sits at the table to eat.", FREE, {"Kim": (4.0, 0.8)})
    assert needs_model(seats) and set(seats.allowed) == {"chair_1", "chair_2", "chair_3", "chair_4"}
    request = seat_choice_request(package_prompts(), seats, "Mo", "eats", "Mo sits at the table to eat.")
    assert request.choices == seats.candidates and request.json_schema is not None
    user = request.messages[-1].content
    assert "- chair_3: at table_1; with Kim; 0.5 m from table_1; faces table_1\n" in user
    assert "- chair_1: at table_1; 0.5 m from table_1\n" in user


def test_the_check_overrides_a_ranking_that_prefers_a_seat_the_relation_excludes() -> None:
    seats = seat_candidates(ROOM, "Mo sits on the chair farthest from the couch.", FREE, {})
    ranked = read_choice(json.dumps({"choice": "chair_1", "scores": {n: -float(i) for i, n in enumerate(seats.candidates)}}),
                         seats.candidates)
    assert ranked.ranked[0] == "chair_1" and checked_choice(seats, ranked) in seats.allowed
    assert checked_choice(seats, ranked) != "chair_1"


# ----- the typed choice through a port ------------------------------------------------------
class OnePort:
    trace = None

    def __init__(self, text: str) -> None:
        self.text = text
        self.requests: list[LLMRequest] = []

    async def complete(self, request: LLMRequest) -> LLMResponse:
        self.requests.append(request)
        return LLMResponse(text=self.text, model="fake")

    def close(self) -> None:
        pass


def test_a_choice_request_carries_the_candidates_and_an_enum_schema_for_other_providers() -> None:
    req = choice_request("event_parser", (ChatMessage(role="user", content="which?"),), ["b", "a", "b"])
    assert req.choices == ("b", "a")
    assert req.json_schema is not None and req.json_schema["properties"]["choice"]["enum"] == ["b", "a"]
    port = OnePort(json.dumps({"choice": "a"}))
    got = anyio.run(choose, port, req)
    assert got.choice == "a" and got.ranked == ("a", "b") and not got.scored
    scored = anyio.run(choose, OnePort(json.dumps({"choice": "a", "scores": {"a": -1.0, "b": -0.5}})), req)
    assert scored.ranked == ("b", "a") and scored.scored


@pytest.mark.parametrize("reply", ["chair_9", json.dumps({"choice": "c"}), json.dumps({"pick": "a"})])
def test_a_reply_naming_no_candidate_is_an_error(reply: str) -> None:
    with pytest.raises(ChoiceError):
        read_choice(reply, ("a", "b"))


def test_the_client_sends_local_models_the_choices_and_others_the_schema() -> None:
    from storyteller.orchestrator.llm.client import LiteLLMClient
    from storyteller.orchestrator.llm.config import NodeConfig, StorytellerConfig

    sent: list[dict[str, object]] = []

    async def fake(**kwargs: object) -> object:
        import litellm

        sent.append(kwargs)
        return litellm.ModelResponse(
            choices=[{"index": 0, "finish_reason": "stop", "message": {"role": "assistant", "content": '{"choice": "a"}'}}],
        )

    req = choice_request("event_parser", (ChatMessage(role="user", content="which?"),), ["a", "b"])
    for model in ("local/qwen2.5-coder-0.5b", "openai/gpt-4o-mini"):
        config = StorytellerConfig(nodes={n: NodeConfig(model=model) for n in ("describer", "narrator", "event_parser", "planner")})
        client = LiteLLMClient(config, acompletion=fake, check_local=lambda m: None)
        with pytest.MonkeyPatch.context() as mp:
            mp.setenv("OPENAI_API_KEY", "x")
            assert anyio.run(choose, client, req).choice == "a"
    local, api = (s["response_format"] for s in sent)
    assert local == {"type": "choices", "choices": ["a", "b"]}
    assert isinstance(api, dict) and api.get("type") in ("json_schema", "json_object")


def test_footprint_gaps_are_the_scene_graphs() -> None:
    chair, fridge = ROOM.by_name["chair_4"], ROOM.by_name["fridge_1"]
    assert group_gap(chair, (Reference("f", obj=fridge),)) == pytest.approx(footprint_distance(chair, fridge))


def test_a_part_with_a_name_for_a_pronoun_is_found_in_the_words_as_written() -> None:
    instruction = "Kim sits at the table by the window. Afterwards she reads a book there."
    part = split_instruction(instruction, ("Kim",))[1].text
    assert part == "Then Kim reads a book there."
    assert words_so_far(instruction, part) == instruction
    assert words_before(instruction, part) == "Kim sits at the table by the window. Afterwards she "

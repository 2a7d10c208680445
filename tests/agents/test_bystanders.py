"""Bystanders: the everyday activities code offers a character the instruction does not need,
the narrator's constrained choice among them, and the feedback on a reply that copies the
instruction, repeats the character's last activity or takes an object in use."""

from __future__ import annotations

import json
from collections.abc import Sequence

import pytest

from storyteller.agents.action_shortlist import action_shortlist
from storyteller.agents.bystanders import (
    MAX_CHOICES,
    Choice,
    SceneNow,
    bystander_rules,
    object_areas,
    scene_choices,
    scene_now,
)
from storyteller.agents.event_parser import scene_action_labels
from storyteller.agents.instruction_parts import instruction_progress
from storyteller.agents.messages import CharacterStatus, HistoryEntry
from storyteller.agents.narrator import NarratorInput, narrate, narrator_request
from storyteller.agents.prompt_templates import PromptLibrary
from storyteller.agents.retry_feedback import RetriesExhaustedError
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.model import Scene
from storyteller.tools.character_states import CharacterState, WorldView
from storyteller.tools.clusters import cluster_objects
from tests.support.scripted_llm import ScriptedLLM

README = "Ava makes coffee, then sits on the couch and drinks it."



@pytest.fixture(scope="module")
def home_choices(home: Scene) -> tuple[tuple[Choice, ...], dict[str, int]]:
    areas = object_areas(home, cluster_objects(home))
    return scene_choices(home, scene_action_labels(home), areas), areas


def _now(home: Scene, home_choices: tuple[tuple[Choice, ...], dict[str, int]], view: WorldView) -> SceneNow:
    choices, areas = home_choices
    return scene_now(home, scene_action_labels(home), choices, areas, view)


def _ava_making_coffee(home: Scene) -> tuple[tuple[CharacterStatus, ...], WorldView]:
    maker = home.by_name["coffee_maker_1"]
    at = (float(maker.center[0]), float(maker.center[1]) - 0.6)
    roster = (
        CharacterStatus(name="Ava", busy=True, action="use_coffee_maker", position=at, event_index=0),
        CharacterStatus(name="Ben", position=(3.5, 4.0)),
    )
    view = WorldView(characters=(
        CharacterState(name="Ava", position=at, action="use_coffee_maker", busy=True, target_position=at),
        CharacterState(name="Ben", position=(3.5, 4.0)),
    ))
    return roster, view


MAKING = HistoryEntry(index=0, characters=("Ava",), activity="make coffee at coffee_maker_1", state="ongoing")


def _input(home: Scene, home_choices: tuple[tuple[Choice, ...], dict[str, int]],
           history: Sequence[HistoryEntry] = (MAKING,)) -> NarratorInput:  # fmt: skip
    roster, view = _ava_making_coffee(home)
    return NarratorInput(scene_description="- kitchen: coffee_maker_1", characters=roster, instruction=README,
                         history=tuple(history), now=_now(home, home_choices, view))  # fmt: skip


def reply(names: list[str], activity: str) -> str:
    return json.dumps({"reasoning": "r", "event": {"characters": names, "activity": activity}})


# ----- candidates ------------------------------------------------------------------------------
@pytest.mark.parametrize("scene_name", ["home", "office", "restaurant"])
def test_every_choice_reads_back_as_its_own_action(scene_name: str) -> None:
    scene = load_bundled_scene(scene_name)
    labels = scene_action_labels(scene)
    choices = scene_choices(scene, labels, object_areas(scene, cluster_objects(scene)))
    assert len({c.label for c in choices}) >= 6, "a bundled scene offers several everyday activities"
    for c in choices:
        assert action_shortlist(c.text, labels, sorted(set(scene.labels)))[0] == c.label, c
        assert c.obj in c.text and c.obj in scene.by_name


def test_candidates_leave_out_objects_in_use_and_full_seats(home: Scene) -> None:
    toaster = home.by_name["toaster_1"]
    at = (float(toaster.center[0]), float(toaster.center[1]) - 0.6)
    view = WorldView(characters=(
        CharacterState(name="Ava", position=at, action="use_toaster", busy=True, target_position=at),
        CharacterState(name="Cy", position=(1.0, 1.0), action="sit_idle", seat="armchair_1"),
        CharacterState(name="Ben", position=(3.5, 4.0)),
    ))
    roster = tuple(CharacterStatus(name=c.name, busy=c.busy, action=c.action, position=c.position, seat=c.seat)
                   for c in view.characters)  # fmt: skip
    areas = object_areas(home, cluster_objects(home))

    def offered(labels: tuple[str, ...], world: WorldView) -> set[str]:
        now = scene_now(home, labels, scene_choices(home, labels, areas), areas, world)
        return {c.obj for c in bystander_rules(now, roster, "Ava is at home.", (), ("Ben",), offer=True).choices}

    assert offered(("idle", "use_toaster"), WorldView()) == {"toaster_1"}
    assert offered(("idle", "use_toaster"), view) == set()  # Ava uses it alone
    assert offered(("idle", "watch_tv"), WorldView()) == {"couch_1", "armchair_1"}
    assert offered(("idle", "watch_tv"), view) == {"couch_1"}  # Cy sits in the armchair; the couch seats more
    sitting = view.model_copy(update={"characters": (*view.characters[:1], view.characters[1].model_copy(update={"seat": "couch_1"}), view.characters[2])})
    assert offered(("idle", "watch_tv"), sitting) == {"couch_1", "armchair_1"}
    three = WorldView(characters=tuple(CharacterState(name=n, seat="couch_1") for n in ("Cy", "Dan", "Eve")))
    assert offered(("idle", "watch_tv"), three) == {"armchair_1"}  # the couch is full


def test_candidates_leave_out_the_instruction_its_objects_and_the_last_activity(
    home: Scene, home_choices: tuple[tuple[Choice, ...], dict[str, int]]
) -> None:
    inp = _input(home, home_choices)
    rules = inp.bystanders
    assert rules.names == ("Ben",) and rules.listed
    assert set(rules.asked) == {"use_coffee_maker", "drink"} and rules.asked["drink"] == ("Ava",)
    labels = {c.label for c in rules.choices}
    assert labels and not labels & {"use_coffee_maker", "drink"}
    assert not any(c.obj in ("coffee_maker_1", "couch_1") for c in rules.choices)  # what the instruction names
    assert 0 < len(rules.choices) <= MAX_CHOICES and len(labels) == len(rules.choices)  # one per label first
    # once Ben has done the first one, it is not offered again
    first = rules.choices[0]
    did = HistoryEntry(index=1, characters=("Ben",), activity=first.text, state="completed")
    again = _input(home, home_choices, (MAKING, did)).bystanders
    assert again.previous["Ben"] == (first.label, first.text)
    assert first.label not in {c.label for c in again.choices}


def test_choices_spread_over_areas_with_the_bystanders_own_area_last(
    home: Scene, home_choices: tuple[tuple[Choice, ...], dict[str, int]]
) -> None:
    rules = _input(home, home_choices).bystanders
    areas = [c.area for c in rules.choices]
    assert len(set(areas)) >= 3
    assert len(set(areas[:3])) == 3  # one per area in turn


def test_no_repeat_while_the_scene_offers_something_else_and_a_repeat_when_it_does_not(home: Scene) -> None:
    areas = object_areas(home, cluster_objects(home))
    roster = (CharacterStatus(name="Ava", busy=True, event_index=0), CharacterStatus(name="Ben", action="read_book"))
    labels: tuple[str, ...] = ("idle", "read_book", "use_smartphone", "use_coffee_maker")
    now = scene_now(home, labels, scene_choices(home, labels, areas), areas, WorldView(), roster)
    rules = bystander_rules(now, roster, "Ava makes coffee.", (), ("Ben",), offer=True)
    assert not rules.repeats_allowed and {c.label for c in rules.choices} == {"use_smartphone"}
    labels = ("idle", "read_book", "use_coffee_maker")
    now = scene_now(home, labels, scene_choices(home, labels, areas), areas, WorldView(), roster)
    rules = bystander_rules(now, roster, "Ava makes coffee.", (), ("Ben",), offer=True)
    assert rules.repeats_allowed and {c.label for c in rules.choices} == {"read_book"}


# ----- the narrator's choice and the feedback -------------------------------------------------
def test_the_prompt_lists_the_choices_and_the_schema_admits_only_them(
    home: Scene, home_choices: tuple[tuple[Choice, ...], dict[str, int]]
) -> None:
    inp = _input(home, home_choices)
    req = narrator_request(PromptLibrary(), inp)
    user = req.messages[-1].content
    assert "no part of the instruction is for Ben now" in user
    for text in inp.bystanders.texts:
        assert f"\n- {text}\n" in user
    assert req.json_schema is not None
    event = req.json_schema["properties"]["event"]["properties"]
    assert event["activity"]["enum"] == list(inp.bystanders.texts)
    assert event["characters"]["items"]["enum"] == ["Ben"]


def test_a_listed_activity_is_for_one_bystander(home: Scene, home_choices: tuple[tuple[Choice, ...], dict[str, int]]) -> None:
    roster, view = _ava_making_coffee(home)
    roster = (*roster, CharacterStatus(name="Cleo", position=(1.0, 4.0)))
    inp = NarratorInput(scene_description="-", characters=roster, instruction=README, history=(MAKING,),
                        now=_now(home, home_choices, view))  # fmt: skip
    assert inp.bystanders.names == ("Ben", "Cleo") and inp.bystanders.texts
    req = narrator_request(PromptLibrary(), inp)
    assert req.json_schema is not None
    chars = req.json_schema["properties"]["event"]["properties"]["characters"]
    assert chars["items"]["enum"] == ["Ben", "Cleo"] and chars["maxItems"] == 1 and chars["minItems"] == 1


async def test_copying_the_instruction_or_repeating_gets_feedback_until_a_listed_choice(
    home: Scene, home_choices: tuple[tuple[Choice, ...], dict[str, int]]
) -> None:
    first = _input(home, home_choices).bystanders.choices[0]
    did = HistoryEntry(index=1, characters=("Ben",), activity=first.text, state="completed")
    inp = _input(home, home_choices, (MAKING, did))
    fresh = inp.bystanders.texts[0]
    port = ScriptedLLM([
        reply(["Ben"], "make coffee at coffee_maker_1"),  # the instruction's own activity, at Ava's coffee maker
        reply(["Ben"], first.text),  # what Ben did just before
        reply(["Ben"], fresh),
    ])
    accepted = await narrate(port, PromptLibrary(), inp, max_retries=3)
    assert accepted.attempts == 3 and accepted.value.event.activity == fresh
    feedback = [m.content for m in port.requests[-1].messages if m.role == "user"][1:]
    assert "Ben has no part in the instruction" in feedback[0] and "Ava" in feedback[0]
    assert "coffee_maker_1 is being used by Ava" in feedback[0]
    assert f"Ben has just done that ({first.text})" in feedback[1]
    assert fresh in feedback[0] and fresh in feedback[1]  # what he could do instead


async def test_without_a_scene_offering_anything_else_the_retries_end(
    home: Scene, home_choices: tuple[tuple[Choice, ...], dict[str, int]]
) -> None:
    inp = _input(home, home_choices)
    port = ScriptedLLM([reply(["Ben"], "drink sitting on couch_1")] * 4)
    with pytest.raises(RetriesExhaustedError):
        await narrate(port, PromptLibrary(), inp, max_retries=3)


def test_once_every_part_has_happened_the_never_named_go_on_with_their_own_lives(
    home: Scene, home_choices: tuple[tuple[Choice, ...], dict[str, int]]
) -> None:
    names = ("Ava", "Ben")
    done = (
        HistoryEntry(index=0, characters=("Ava",), activity="make coffee", state="completed", part="Ava makes coffee."),
        HistoryEntry(index=1, characters=("Ava",), activity="drink on the couch", state="completed",
                     part="Then Ava sits on the couch and drinks it."),
    )  # fmt: skip
    progress = instruction_progress(README, names, done, names)
    assert progress.next_part is None and progress.bystanders == ("Ben",)  # not Ava: her parts are over
    # Ben still at a looping activity is not asked; the model may still name him, and is checked
    reading = (*done, HistoryEntry(index=2, characters=("Ben",), activity="read a book sitting on chair_5", state="looping"))
    still = instruction_progress(README, names, reading, names)
    assert still.bystanders == () and still.next_actors == ("Ava",)  # Ben carries on: the reply may name Ava only
    assert instruction_progress(README, names, reading, ("Ben",)).nothing_for_the_free  # alone: a wait, no call
    roster = (CharacterStatus(name="Ava"), CharacterStatus(name="Ben", action="read_book"))
    _, view = _ava_making_coffee(home)
    inp = NarratorInput(scene_description="-", characters=roster, instruction=README, history=reading,
                        now=_now(home, home_choices, view))  # fmt: skip
    rules = inp.bystanders
    assert rules.names == ("Ben",) and not rules.listed and rules.texts == ()
    event = json.loads(reply(["Ben"], "drink sitting on chair_2"))["event"]
    from storyteller.agents.messages import Event

    assert any("Ben has no part in the instruction" in p for p in rules.problems(Event(**event)))
    assert any("Ben has just done that" in p for p in rules.problems(Event(characters=("Ben",), activity="read a book sitting on chair_1")))
    assert rules.problems(Event(characters=("Ben",), activity="make toast at toaster_1")) == []
    assert rules.problems(Event(characters=("Ava",), activity="drink sitting on chair_2")) == []  # Ava is not a bystander


def test_an_object_of_an_ongoing_event_not_yet_in_the_world_is_in_use(home: Scene) -> None:
    """Cleo's event beside this one is planned (its words name the bookshelf) but the world does
    not show her there yet: Ben is neither offered the bookshelf nor let take it."""
    from storyteller.agents.messages import Event

    areas = object_areas(home, cluster_objects(home))
    labels = ("idle", "take_out_book", "read_book")
    roster = (CharacterStatus(name="Ava", busy=True, event_index=0), CharacterStatus(name="Ben"),
              CharacterStatus(name="Cleo", busy=True, action="eat", event_index=1))  # fmt: skip
    now = scene_now(home, labels, scene_choices(home, labels, areas), areas, WorldView(), roster)
    pending = (HistoryEntry(index=1, characters=("Cleo",), activity="take a book from bookshelf_1", state="ongoing"),)
    free = bystander_rules(now, roster, "Ava makes coffee.", (), ("Ben",), offer=True)
    assert "bookshelf_1" in {c.obj for c in free.choices}
    rules = bystander_rules(now, roster, "Ava makes coffee.", pending, ("Ben",), offer=True)
    assert rules.users == {"bookshelf_1": ("Cleo",)} and "bookshelf_1" not in {c.obj for c in rules.choices}
    sitting = (HistoryEntry(index=1, characters=("Cleo",), activity="eat sitting on chair_5", state="ongoing"),)
    assert "chair_5" in {c.obj for c in free.choices}
    assert "chair_5" not in {c.obj for c in bystander_rules(now, roster, "Ava makes coffee.", sitting, ("Ben",), offer=True).choices}
    problems = rules.problems(Event(characters=("Ben",), activity="take a book from bookshelf_1"))
    assert any("bookshelf_1 is being used by Cleo" in p for p in problems)


def test_a_single_user_activity_for_two_bystanders_gets_feedback(home: Scene) -> None:
    from storyteller.agents.messages import Event

    areas = object_areas(home, cluster_objects(home))
    labels = ("idle", "use_toaster", "read_book")
    roster = (CharacterStatus(name="Ava", busy=True, event_index=0), CharacterStatus(name="Ben"), CharacterStatus(name="Cleo"))
    now = scene_now(home, labels, scene_choices(home, labels, areas), areas, WorldView(), roster)
    rules = bystander_rules(now, roster, "Ava makes coffee.", (), ("Ben", "Cleo"), offer=True)
    assert "make toast at toaster_1" in rules.texts
    two = rules.problems(Event(characters=("Ben", "Cleo"), activity="make toast at toaster_1"))
    assert any("toaster_1 is for one character at a time: give it to Ben or Cleo" in p for p in two)
    assert rules.problems(Event(characters=("Ben",), activity="make toast at toaster_1")) == []
    assert rules.problems(Event(characters=("Ben", "Cleo"), activity="read a book sitting on couch_1")) == []

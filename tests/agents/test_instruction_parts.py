"""The instruction's parts and their progress, as the narrator's prompt shows them."""

from __future__ import annotations

import pytest

from storyteller.agents.instruction_parts import (
    instruction_progress,
    part_states,
    served_characters,
    split_instruction,
)
from storyteller.agents.llm_port import LLMRequest, LLMResponse
from storyteller.agents.messages import CharacterStatus, EventState, HistoryEntry
from storyteller.agents.narrator import NarratorInput, narrate, narrator_request
from storyteller.agents.prompt_templates import PromptLibrary
from storyteller.agents.step_words import activity_kind

COFFEE = "Ava makes coffee, then sits on the couch and drinks it."
WITH_BEN = "Ava makes coffee, then sits on the couch next to Ben and drinks it."
NAMES = ("Ava", "Ben")


def ev(i: int, who: tuple[str, ...], activity: str, state: EventState = "completed") -> HistoryEntry:
    return HistoryEntry(index=i, characters=who, activity=activity, state=state)


@pytest.mark.parametrize(("instruction", "parts"), [
    (COFFEE, ["Ava makes coffee.", "Then Ava sits on the couch and drinks it."]),
    ("Ava and Ben cook, and then eat at table_1.", ["Ava and Ben cook.", "Then Ava and Ben eat at table_1."]),
    ("Meanwhile, Ben first reads and then naps.", ["Meanwhile, Ben first reads.", "Then Ben naps."]),
    ("Ava cooks; then, Ben eats.\nAva rests", ["Ava cooks;", "then, Ben eats.", "Ava rests"]),
    ("Ben then sits down.", ["Ben then sits down."]),  # "then" without a comma or "and" joins
    ("Ava makes tea, then Ben drinks it.", ["Ava makes tea.", "Then Ben drinks it."]),
    ("Ben works on the laptop, while Ava watches TV.", ["Ben works on the laptop.", "Ava watches TV."]),
    ("Ava and Ben dance while the music plays.", ["Ava and Ben dance while the music plays."]),
    ("Ava and Ben dance, Cy and Di talk at the table, and Ed sits.",
     ["Ava and Ben dance.", "Cy and Di talk at the table.", "Ed sits."]),
    ("Ava, Ben and Cy dance.", ["Ava, Ben and Cy dance."]),
    ("Ava puts a record on, then she and Ben dance.", ["Ava puts a record on.", "Then Ava and Ben dance."]),
    ("Ava and Cy cook, then they eat.", ["Ava and Cy cook.", "Then Ava and Cy eat."]),
    ("Ava and Ben order food, and Cy, their waiter, takes the order.",
     ["Ava and Ben order food.", "Cy, their waiter, takes the order."]),
])
def test_split_by_sentence_and_then_with_the_subject_carried_over(instruction: str, parts: list[str]) -> None:
    assert [p.text for p in split_instruction(instruction, (*NAMES, "Cy", "Di", "Ed"))] == parts


@pytest.mark.parametrize(("instruction", "parts"), [
    ("Ben grabs a book from the shelf and reads it.", ["Ben grabs a book from the shelf.", "Then Ben reads it."]),
    ("Ava opens the fridge and takes out the milk, then drinks it.",
     ["Ava opens the fridge.", "Then Ava takes out the milk.", "Then Ava drinks it."]),
    # one action: a posture and what is done in it, waiting while doing, one kind twice, things joined
    (COFFEE, ["Ava makes coffee.", "Then Ava sits on the couch and drinks it."]),
    ("Ava waits by the door and waves at Ben.", ["Ava waits by the door and waves at Ben."]),
    ("Ben walks to the coffee maker and brews a pot.", ["Ben walks to the coffee maker and brews a pot."]),
    ("Ava takes a soda and some chips from the fridge.", ["Ava takes a soda and some chips from the fridge."]),
    # going somewhere is the way to what is done there, not a step of its own
    ("Cy goes over to the corner with the plant and sits down there to read the news on a phone.",
     ["Cy goes over to the corner with the plant and sits down there to read the news on a phone."]),
    ("Ava slowly makes her way to the fridge and takes out a lemonade.",
     ["Ava slowly makes her way to the fridge and takes out a lemonade."]),
    ("Ben heads into the kitchen and toasts some bread.", ["Ben heads into the kitchen and toasts some bread."]),
    # "goes through" is no going: two steps
    ("Ben goes through his emails on the laptop and drinks a coffee.",
     ["Ben goes through his emails on the laptop.", "Then Ben drinks a coffee."]),
    # a clause that only says how something is, or has no verb, is the reason for the next step
    ("Ava's glass is empty, and after a while it gets refilled at the fridge by Ava.",
     ["Ava's glass is empty, and after a while it gets refilled at the fridge by Ava."]),
    ("Cy, with a minute to spare. Turns the radio on.", ["Cy, with a minute to spare. Turns the radio on."]),
    ("The TV is still on. Ben switches it off.", ["The TV is still on. Ben switches it off."]),
    ("Ava is hungry and eats a sandwich.", ["Ava is hungry and eats a sandwich."]),
    ("Ava joins Ben at his table. Then they chat.", ["Ava joins Ben at his table.", "Then Ava and Ben chat."]),
    # what someone wants, then how they go about it: one step (not when "then" makes it a sequence)
    ("Cy wants to read a comic. He takes the armchair farthest from the TV.",
     ["Cy wants to read a comic. Cy takes the armchair farthest from the TV."]),
    ("Cy wants a coffee. Then he sits on the couch.", ["Cy wants a coffee.", "Then Cy sits on the couch."]),
    ("Cy wants a coffee. Ben makes one for him.", ["Cy wants a coffee.", "Ben makes one for him."]),
    ("Ava makes a tea wherever tea is made. Then she drinks it on the couch.",
     ["Ava makes a tea wherever tea is made.", "Then Ava drinks it on the couch."]),
    # a relation's landmark is no action: "farthest from the coffee maker" is where, not what
    ("Ben opens his laptop and picks the seat farthest from the coffee maker.",
     ["Ben opens his laptop and picks the seat farthest from the coffee maker."]),
    # two characters doing two things at once
    ("Ava and Ben chat and watch TV together.", ["Ava and Ben chat and watch TV together."]),
])
def test_and_before_a_second_action_of_one_character_is_the_next_step(instruction: str, parts: list[str]) -> None:
    assert [p.text for p in split_instruction(instruction, (*NAMES, "Cy"))] == parts


@pytest.mark.parametrize(("instruction", "parts"), [
    # a list of three steps, each opening with its verb: one part each
    ("Cy switches the TV on, reads a magazine on the couch, and turns the TV off again.",
     ["Cy switches the TV on.", "Then Cy reads a magazine on the couch.", "Then Cy turns the TV off again."]),
    ("Ava brews a coffee, drinks it at the table and loads the dishwasher.",
     ["Ava brews a coffee.", "Then Ava drinks it at the table.", "Then Ava loads the dishwasher."]),
    # an item with no action of its own goes with the next, in the user's words; one kind is one step
    ("Ben walks to the desk, sits down, and types an email on the laptop.",
     ["Ben walks to the desk, sits down, and types an email on the laptop."]),
    ("Ava eats toast, bananas with jam, and cereal with milk.", ["Ava eats toast, bananas with jam, and cereal with milk."]),
    ("Ava nibbles some toast, munches an apple, and eats a yoghurt.",
     ["Ava nibbles some toast, munches an apple, and eats a yoghurt."]),
    # words of sequence other than "then"
    ("Cy notes down what they want and afterwards brings their food.",
     ["Cy notes down what they want.", "Then Cy brings their food."]),
    ("Ava reads a book, and later Ben dances.", ["Ava reads a book.", "Then Ben dances."]),
])
def test_a_list_of_steps_and_words_of_sequence_make_parts(instruction: str, parts: list[str]) -> None:
    assert [p.text for p in split_instruction(instruction, (*NAMES, "Cy"))] == parts


def test_parts_know_their_characters_and_words() -> None:
    first, second = split_instruction(COFFEE, NAMES)
    assert first.names == second.names == ("Ava",)
    assert {"mak", "cof"} <= first.stems and "ava" not in first.stems
    assert {"sit", "cou", "dri"} <= second.stems


def test_after_so_the_names_that_follow_act_and_the_clause_before_is_background() -> None:
    (part,) = split_instruction("Cy and Di have already sat down, so Ben takes the last chair by the window.", (*NAMES, "Cy", "Di"))
    assert part.actors == ("Ben",) and set(part.names) == {"Cy", "Di", "Ben"}
    (plain,) = split_instruction("Cy sits by Ben, so they can talk.", (*NAMES, "Cy"))
    assert plain.actors == ("Cy",)  # no name after "so": the first run of names acts


def test_the_people_a_part_acts_for_are_named_or_pointed_at() -> None:
    names = (*NAMES, "Cy")
    guests = "Ava and Ben take seats at a table. Cy brings them menus, then takes their order."
    assert [served_characters(guests, p.text, names) for p in split_instruction(guests, names)] == [
        (), ("Ava", "Ben"), ("Ava", "Ben")]
    assert served_characters("Cy hands the bill to Ben.", "Cy hands the bill to Ben.", names) == ("Ben",)
    alone = "Ava makes tea, then drinks it."
    assert [served_characters(alone, p.text, names) for p in split_instruction(alone, names)] == [(), ()]
    # "they" in a part with a named actor points at others; a part that opens with "they" acts itself
    asked = "Ava and Ben sit at the bar. Cy asks what they fancy. Then they chat."
    assert [served_characters(asked, p.text, names) for p in split_instruction(asked, names)] == [
        (), ("Ava", "Ben"), ()]


def test_events_mark_parts_done_ongoing_and_the_next_one() -> None:
    parts = split_instruction(COFFEE, NAMES)
    assert part_states(parts, (), NAMES) == ["next", ""]
    made = ev(0, ("Ava",), "make coffee with coffee_maker_1", "ongoing")
    assert part_states(parts, [made], ["Ben"]) == ["ongoing", ""]  # part 2 waits for Ava
    made = made.model_copy(update={"state": "completed"})
    assert part_states(parts, [made], NAMES) == ["done", "next"]
    sat = ev(1, ("Ava",), "drink coffee sitting on couch_1", "looping")  # shares "coffee" with part 1
    assert part_states(parts, [made, sat], NAMES) == ["done", "done"]


def test_an_event_sharing_no_word_or_no_character_matches_nothing() -> None:
    parts = split_instruction(COFFEE, NAMES)
    assert part_states(parts, [ev(0, ("Ava",), "wave at Ben")], NAMES) == ["next", ""]
    assert part_states(parts, [ev(0, ("Ben",), "make coffee with coffee_maker_1")], NAMES) == ["next", ""]
    # the same event twice covers one part, not two, even when it shares words with the next
    twice = [ev(0, ("Ava",), "make coffee sitting on couch_1"), ev(1, ("Ava",), "Make coffee  sitting on couch_1")]
    assert part_states(parts, twice, NAMES) == ["done", "next"]


def test_an_event_of_the_same_kind_of_activity_matches_a_part_in_other_words() -> None:
    meal = "Mia orders food at the counter. Later Mia tucks into her lunch by the window. Then, Leo joins her."
    parts = split_instruction(meal, ("Mia", "Leo"))
    ordered = ev(0, ("Mia",), "order food at the counter")
    eating = ev(1, ("Mia",), "munch a sandwich by table_2", "looping")  # no word shared with part 2
    assert activity_kind(eating.activity) == activity_kind(parts[1].text) == "eat"
    assert part_states(parts, [ordered, eating], ("Leo",)) == ["done", "done", "next"]
    chat = ev(1, ("Mia",), "chat with a friend", "looping")  # another kind, no word shared: no match
    assert part_states(parts, [ordered, chat], ("Leo",))[1] == ""
    talks = split_instruction("Ava reads a novel. Then Ava chats with Ben.", ("Ava", "Ben"))
    phone = ev(0, ("Ava",), "Ava talks on the phone")  # the kind of part 2, but without Ben
    assert part_states(talks, [phone], ("Ava", "Ben")) == ["next", ""]


def test_progress_text_and_when_nothing_is_for_the_free() -> None:
    p = instruction_progress(COFFEE, NAMES, (), NAMES)
    assert p.text == "\n1) [next] Ava makes coffee.\n2) Then Ava sits on the couch and drinks it."
    assert p.next_part == "Ava makes coffee." and not p.nothing_for_the_free
    busy = instruction_progress(WITH_BEN, NAMES, [ev(0, ("Ava",), "make coffee", "ongoing")], ["Ben"])
    assert busy.next_part is None and busy.nothing_for_the_free and busy.bystanders == ()
    bystander = instruction_progress(COFFEE, NAMES, [ev(0, ("Ava",), "make coffee", "ongoing")], ["Ben"])
    assert bystander.next_part is None and not bystander.nothing_for_the_free
    assert bystander.bystanders == ("Ben",) and bystander.next_actors == ("Ben",)
    one = instruction_progress("Ben reads a book.", NAMES, [ev(0, ("Ben",), "read book_1 on couch_1", "ongoing")], ["Ava"])
    assert one.text == "[ongoing] Ben reads a book." and one.next_part is None
    assert not one.nothing_for_the_free  # every part has happened: the model decides about Ava
    fresh = instruction_progress("Ben reads a book.", NAMES, (), NAMES)
    assert fresh.text == "Ben reads a book." and fresh.next_part == "Ben reads a book."
    nobody = instruction_progress("Everyone dances.", NAMES, (), ["Ben"])
    assert nobody.next_part == "Everyone dances."  # a part naming nobody is for any free character
    empty = instruction_progress("  ", NAMES, (), NAMES)
    assert empty.text == "(none: continue the story naturally)" and not empty.nothing_for_the_free


class NoCalls:
    trace = None

    async def complete(self, request: LLMRequest) -> LLMResponse:
        raise AssertionError("the narrator asked the model")

    def close(self) -> None:
        pass


def _input(history: tuple[HistoryEntry, ...], busy: tuple[str, ...], instruction: str = COFFEE) -> NarratorInput:
    roster = tuple(CharacterStatus(name=n, busy=n in busy, event_index=0 if n in busy else None) for n in NAMES)
    return NarratorInput(scene_description="- kitchen: coffee_maker_1\n- living room: couch_1", characters=roster,
                         instruction=instruction, history=history)


async def test_narrator_waits_without_a_call_when_the_rest_is_for_busy_characters() -> None:
    making = (ev(0, ("Ava",), "make coffee", "ongoing"),)
    accepted = await narrate(NoCalls(), PromptLibrary(), _input(making, ("Ava",), WITH_BEN))
    assert accepted.value.event.is_wait and accepted.attempts == 0


def test_a_bystander_is_asked_for_an_event_of_their_own() -> None:
    """Ben is never named: while Ava carries the instruction out, he gets something to do
    (the reply must name him and only him) instead of standing idle for the whole story."""
    req = narrator_request(PromptLibrary(), _input((ev(0, ("Ava",), "make coffee", "ongoing"),), ("Ava",)))
    user = req.messages[-1].content
    assert "Next part: no part of the instruction is for Ben now: give them something of their own to do" in user
    assert req.json_schema is not None
    chars = req.json_schema["properties"]["event"]["properties"]["characters"]
    assert chars["items"]["enum"] == ["Ben"] and chars["minItems"] == 1


def test_the_prompt_shows_the_marked_parts_and_the_next_one() -> None:
    req = narrator_request(PromptLibrary(), _input((ev(0, ("Ava",), "make coffee with coffee_maker_1"),), ()))
    user = req.messages[-1].content
    assert "1) [done] Ava makes coffee.\n2) [next] Then Ava sits on the couch and drinks it." in user
    assert "Next part: Then Ava sits on the couch and drinks it." in user


def test_a_character_a_part_only_refers_to_need_not_be_free() -> None:
    text = "Mia orders tea at the bar.\nLeo joins the table of his friend, Mia, to drink tea with her."
    parts = split_instruction(text, ("Mia", "Leo"))
    assert [p.actors for p in parts] == [("Mia",), ("Leo",)] and parts[1].names == ("Mia", "Leo")
    ordered = ev(0, ("Mia",), "order tea at bar_1", "ongoing")
    assert part_states(parts, [ordered], ["Leo"]) == ["ongoing", "next"]
    # an event of the referred-to character does not cover the part of the one who acts
    assert part_states(parts, [ordered, ev(1, ("Mia",), "drink tea at table_2")], ["Leo"]) == ["ongoing", "next"]


def test_the_reply_may_name_only_the_next_parts_actors() -> None:
    roster = tuple(CharacterStatus(name=n) for n in ("Ava", "Ben", "Cy"))
    inp = NarratorInput(scene_description="- kitchen: coffee_maker_1", characters=roster, instruction=COFFEE)
    assert inp.candidates == ["Ava"]
    schema = narrator_request(PromptLibrary(), inp).json_schema
    assert schema is not None
    enum = schema["properties"]["event"]["properties"]["characters"]
    assert enum["items"]["enum"] == ["Ava"] and enum["maxItems"] == 1
    anyone = NarratorInput(scene_description="-", characters=roster, instruction="Everyone dances.")
    assert anyone.candidates == ["Ava", "Ben", "Cy"]
    free_story = NarratorInput(scene_description="-", characters=roster, instruction="")
    assert free_story.candidates == ["Ava", "Ben", "Cy"] and not free_story.progress.nothing_for_the_free


PARTY = "Ava and Ben dance. Cy and Di talk at the table. Ava eats."
PARTY_NAMES = ("Ava", "Ben", "Cy", "Di")


def planned(i: int, who: tuple[str, ...], activity: str, part: str, state: EventState = "completed") -> HistoryEntry:
    return HistoryEntry(index=i, characters=who, activity=activity, state=state, part=part)


def test_an_event_planned_for_a_part_marks_that_part_whatever_its_words() -> None:
    parts = split_instruction(PARTY, PARTY_NAMES)
    # the narrator's words match nothing, and repeat the next event's words: the part decides
    history = [planned(0, ("Ava", "Ben"), "bring menus to table_4", parts[0].text),
               planned(1, ("Cy", "Di"), "bring menus to table_4", parts[1].text, "ongoing")]
    assert part_states(parts, history, PARTY_NAMES) == ["done", "ongoing", "next"]


def test_a_failed_part_stays_open_goes_after_untried_ones_and_is_given_up_after_two_failures() -> None:
    parts = split_instruction(PARTY, PARTY_NAMES)
    once = [planned(0, ("Ava", "Ben"), "dance in front of tv_1", parts[0].text, "failed")]
    # untried part 2 goes first; part 3 (Ava) waits for Ava's open part 1
    assert part_states(parts, once, PARTY_NAMES) == ["", "next", ""]
    assert part_states(parts, once, ("Ava", "Ben")) == ["next", "", ""]
    twice = [*once, planned(1, ("Ava", "Ben"), "dance by tv_1", parts[0].text, "failed")]
    assert part_states(parts, twice, ("Ava", "Ben")) == ["failed", "", "next"]
    progress = instruction_progress(PARTY, PARTY_NAMES, twice, ("Ava", "Ben"))
    assert "[failed] Ava and Ben dance." in progress.text and progress.next_part == "Ava eats."
    # a failed attempt followed by a success: done
    fixed = [*once, planned(1, ("Ava", "Ben"), "dance", parts[0].text)]
    assert part_states(parts, fixed, ("Ava", "Ben"))[0] == "done"


def test_a_later_part_of_the_same_character_waits_for_the_earlier_one() -> None:
    parts = split_instruction("Ava and Ben chat. Ben reads.", NAMES)
    # Ava is busy elsewhere: Ben's reading comes after the chat, not instead of it
    assert part_states(parts, [], ("Ben",)) == ["", ""]
    assert part_states(parts, [], NAMES) == ["next", ""]


def test_a_character_whose_parts_are_over_is_given_something_to_do_while_others_go_on() -> None:
    text = "Ava and Ben take seats at the table. Cy brings them menus, then takes their order."
    names = ("Ava", "Ben", "Cy")
    parts = split_instruction(text, names)
    seated = [planned(0, ("Ava", "Ben"), "sit at table_1", parts[0].text),
              planned(1, ("Cy",), "bring menus", parts[1].text, "ongoing")]
    progress = instruction_progress(text, names, seated, ("Ava", "Ben"))
    assert progress.bystanders == ("Ava", "Ben")
    # still at their own part (a looping event): they carry on, nobody gives them another
    still = [planned(0, ("Ava", "Ben"), "sit at table_1", parts[0].text, "looping"), seated[1]]
    assert instruction_progress(text, names, still, ("Ava", "Ben")).bystanders == ()
    # ... unless all they do there is sit
    assert instruction_progress(text, names, still, ("Ava", "Ben"), idle=("Ben",)).bystanders == ("Ben",)
    # a character an open part still names waits for it
    waiter = "Ava sits at the table. Cy serves Ava."
    parts = split_instruction(waiter, names)
    sat = [planned(0, ("Ava",), "sit", parts[0].text)]
    assert instruction_progress(waiter, names, sat, ("Ava",)).bystanders == ()


def test_a_part_naming_nobody_is_everyones_so_nobody_is_a_bystander_to_it() -> None:
    """ "Everyone reads.": once Ava has read, Ben reading too is the instruction, not a bystander
    copying someone else's activity (the narrator's check refused it four times)."""
    from storyteller.agents.bystanders import never_named

    progress = instruction_progress("Everyone reads.", ["Ava", "Ben"], [ev(0, ("Ava",), "reads")], ["Ben"])
    assert progress.bystanders == ()
    assert never_named("Everyone reads.", ["Ava", "Ben"]) == ()
    assert never_named("Ava reads.", ["Ava", "Ben"]) == ("Ben",)


@pytest.mark.parametrize(("instruction", "parts"), [
    # a sentence opening with a pronoun acts for the part before's characters
    ("Ava makes coffee. She then sits on the couch.", ["Ava makes coffee.", "Then Ava sits on the couch."]),
    ("Ava opens the fridge; after that, she closes it.", ["Ava opens the fridge;", "Then Ava closes it."]),
    ("Ava and Ben meet by the door. Afterwards the two of them sit down.",
     ["Ava and Ben meet by the door.", "Then Ava and Ben sit down."]),
    ("Ava and Ben meet by the door. She sits down.", ["Ava and Ben meet by the door.", "She sits down."]),  # which?
    ("Ava makes tea. They chat.", ["Ava makes tea.", "They chat."]),  # "they" after one name: unsure
    # what a relative clause says someone else does is that one's own part, said first
    ("Ava brings a coffee to Ben, who waits on the bench with his phone.",
     ["Ben waits on the bench with his phone.", "Ava brings a coffee to Ben."]),
    ("Ava waves at Cy, who is sitting by the door, and then sits down.",
     ["Cy is sitting by the door.", "Ava waves at Cy.", "Then Ava sits down."]),
    ("Ava gives Cy, who stands at the bar, a menu.", ["Cy stands at the bar.", "Ava gives Cy a menu."]),
    # who someone is, or a clause about the subject itself, stays where it is
    ("Ava hugs Ben, who is tired.", ["Ava hugs Ben, who is tired."]),
    ("Cy, who waits tables here, brings the menus.", ["Cy, who waits tables here, brings the menus."]),
    ("Ava serves Ben, who then eats.", ["Ava serves Ben, who then eats."]),
])  # fmt: skip
def test_a_pronoun_or_a_relative_clause_names_who_acts(instruction: str, parts: list[str]) -> None:
    split = split_instruction(instruction, (*NAMES, "Cy"))
    assert [p.text for p in split] == parts
    assert all(p.actors for p in split if not p.text.startswith(("She ", "They ")))


def test_what_someone_is_already_doing_is_no_part() -> None:
    text = "Ava joins her friend Cy, who is already eating, and sits down at his table."
    assert [p.text for p in split_instruction(text, (*NAMES, "Cy"))] == [text]

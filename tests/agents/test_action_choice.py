"""The action of an event whose words name none: the model's choice among the offered labels
(storyteller.agents.action_choice, the planning graph's choose_action node)."""

from __future__ import annotations

from langgraph.checkpoint.memory import InMemorySaver

from storyteller.agents.action_choice import (
    MOTION_LABELS,
    action_candidates,
    action_choice_request,
    earlier_thing_action,
)
from storyteller.agents.event_parser import scene_action_labels
from storyteller.agents.instruction_parts import earlier_parts, split_instruction
from storyteller.agents.program_grammar import event_options
from storyteller.orchestrator.planning.checkpoints import StoryLog
from storyteller.orchestrator.planning.graph import compile_planning_graph, recursion_limit
from storyteller.sim.scene.bundled import resolve_scene
from tests.support.planning_script import DESCRIPTION, PROGRAM, initial_state, make_deps, narration
from tests.support.scripted_llm import ScriptedLLM, choosing

HOME = resolve_scene("home")
LABELS = scene_action_labels(HOME)


def test_words_that_rank_a_label_get_no_choice_and_words_that_rank_none_offer_every_action() -> None:
    assert action_candidates("Ava makes coffee at the coffee maker", LABELS, HOME.labels) == ()
    assert action_candidates("Ava waits by the door", LABELS, HOME.labels) == ()  # idle is ranked
    offered = action_candidates("Ava sits down to have a little treat", LABELS, HOME.labels)
    assert "eat" in offered and "drink" in offered and not MOTION_LABELS & set(offered)
    assert action_candidates("something", ("idle", "walk"), ()) == ()  # one label: nothing to choose


def test_words_that_only_say_where_someone_stands_get_no_choice() -> None:
    for text in ("Mo hangs about beside the record player", "Mo plants himself right in front of the TV",
                 "Mo loiters to the left of the fridge"):
        assert action_candidates(text, LABELS, HOME.labels) == (), text
    # sitting somewhere with no action named is still the model's choice
    assert "eat" in action_candidates("Mo takes a seat beside the fridge", LABELS, HOME.labels)


def test_words_that_say_only_a_direction_act_on_the_thing_an_earlier_part_worked() -> None:
    story = ("Mo opens the cupboard beside the sink. Then he takes out a bowl. Nia switches the telly on. "
             "Then Mo shoves the door shut again. Afterwards Nia turns the set off.")
    parts = [p.text for p in split_instruction(story, ("Mo", "Nia"))]
    assert earlier_parts(story, parts[3], ("Mo", "Nia")) == [parts[1], parts[0]]  # Mo's own, nearest first
    assert earlier_parts(story, "not a part", ("Mo", "Nia")) == []
    offered = action_candidates(parts[3], LABELS, HOME.labels)
    assert offered  # the words rank nothing: without the earlier part the model would choose
    assert earlier_thing_action(parts[3], offered, HOME.labels, earlier_parts(story, parts[3], ("Mo", "Nia"))) == "close_cabinet"
    assert earlier_thing_action(parts[4], LABELS, HOME.labels, earlier_parts(story, parts[4], ("Mo", "Nia"))) == "turn_off_tv"
    assert earlier_thing_action("Then Mo closes it.", LABELS, HOME.labels, ["Mo watches TV."]) is None  # no close_tv
    assert earlier_thing_action("Then Mo sits down.", LABELS, HOME.labels, ["Mo opens the fridge."]) is None
    assert earlier_thing_action("Then Mo closes the fridge.", LABELS, HOME.labels, ["Mo opens the cabinet."]) is None


def test_the_request_is_a_choice_among_the_labels_in_plain_words() -> None:
    request = action_choice_request(("eat", "drink"), ("Ava",), "has an apple", "Ava sits down to have an apple.")
    assert request.choices == ("eat", "drink") and request.node == "event_parser"
    user = request.messages[-1].content
    assert "Ava sits down to have an apple." in user and "eat, drink" in user and "what Ava does" in user
    assert "what Ava and Ben do" in action_choice_request(("eat", "chat"), ("Ava", "Ben"), "sit", "").messages[-1].content


def test_the_chosen_action_comes_first_and_a_seated_one_gives_the_posture() -> None:
    text = "Ava takes a free seat at the dining table"
    before = event_options(HOME, ("Ava",), (), (), LABELS, text)
    after = event_options(HOME, ("Ava",), (), (), LABELS, text, action="eat")
    assert after.labels[0] == "eat" and set(after.labels) == set(before.labels)
    assert after.posture == "sit"
    assert event_options(HOME, ("Ava",), (), (), LABELS, text, action="not_a_label").labels == before.labels


async def test_an_event_naming_no_action_gets_the_models_choice_as_the_parsers_suggestion() -> None:
    picked: list[tuple[str, ...]] = []

    def pick(candidates: tuple[str, ...]) -> str:
        picked.append(candidates)
        return "eat"

    port = ScriptedLLM({
        "describer": [DESCRIPTION],
        "narrator": [narration(["Ann"], "has a little treat"), narration(["Ann"], "eat at table_1")],
        "event_parser": choosing([PROGRAM.format(who="Ann"), PROGRAM.format(who="Ann")], pick),
    })
    story = StoryLog(":memory:", "t1")
    graph = compile_planning_graph(InMemorySaver())
    state = {**initial_state(["Ann"], 2), "instruction": ""}  # the narrator's words alone
    final = await graph.ainvoke(
        state, config={"configurable": {"thread_id": "t1"}, "recursion_limit": recursion_limit(2, 3)},
        context=make_deps(port, story, program_grammar=True), durability="sync",
    )
    parser_calls = [r for r in port.requests if r.node == "event_parser"]
    # the first event names no action: the model chooses (eat), then the seat is chosen for the
    # seated action, and the program's request suggests it; the second event's words rank a label
    assert picked[0] == ("idle", "eat", "chat")
    kinds = [("action" if r.choices == ("idle", "eat", "chat") else "seat") if r.choices else "program" for r in parser_calls]
    assert kinds == ["action", "seat", "program", "seat", "program"]
    assert "Suggested action label: eat" in parser_calls[2].messages[-1].content
    assert final["llm_calls"] == len(port.requests) and final["step"] == 2

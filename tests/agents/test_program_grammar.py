"""The event-program grammar: its text, how it reaches llama.cpp, and the real embedded model
writing a program under it that runs in the sandbox."""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path
from typing import Any

import pytest

from storyteller.agents.event_parser import ParserInput, parser_request, run_reply, scene_action_labels
from storyteller.agents.llm_port import ChatMessage, LLMRequest
from storyteller.agents.messages import CharacterStatus, Event
from storyteller.agents.program_grammar import (
    about_a_seat,
    event_options,
    event_program_grammar,
    open_program_grammar,
    program_grammar,
)
from storyteller.agents.prompt_templates import PromptLibrary
from storyteller.orchestrator.llm.client import LiteLLMClient
from storyteller.orchestrator.llm.config import default_config
from storyteller.orchestrator.llm.trace_writer import NullTraceSink
from storyteller.sim.scene.bundled import resolve_scene
from storyteller.tools.character_states import CharacterState, WorldView
from tests.support.embedded_weights import embedded_weights_or_skip

SCENE = resolve_scene("home")
ROSTER = (CharacterStatus(name="Ava", position=(1.0, 1.0)), CharacterStatus(name="Ben", busy=True, seat="couch_1"))
WORLD = WorldView(characters=tuple(CharacterState(name=c.name, position=c.position, busy=c.busy, seat=c.seat) for c in ROSTER),
                  objects_in_use={"couch_1": "Ben"})
EVENT = Event(characters=("Ava",), activity="make coffee with coffee_maker_1")
VAGUE = Event(characters=("Ava",), activity="pass the time")


LABELS = scene_action_labels(SCENE)
SEATS_IN_USE = ("couch_1", "chair_2")


def event_grammar(event: Event) -> str:
    """The grammar the planning graph's parser input carries for ``event`` (free seats, offered labels)."""
    return event_program_grammar(SCENE, event.characters, ROSTER, SEATS_IN_USE, LABELS, activity=event.activity)


def test_grammar_names_only_scene_objects_free_seats_and_offered_labels() -> None:
    g = event_grammar(VAGUE)
    rules = dict(line.split(" ::= ", 1) for line in g.strip().splitlines())
    objects = set(re.findall(r'\\"([^"\\]+)\\"', rules["object"]))
    assert objects == {o.name for o in SCENE.objects}
    seats = set(re.findall(r'\\"([^"\\]+)\\"', rules["seat"]))
    assert "chair_2" not in seats and seats <= {o.name for o in SCENE.objects if o.is_seat}
    assert "couch_1" in seats  # Ben holds one of its three places
    labels = set(re.findall(r'\\"([^"\\]+)\\"', rules["sitlabel"] + rules["standlabel"]))
    assert labels == set(scene_action_labels(SCENE))
    assert '\\"Ben\\"' in rules["look"]  # another character may be looked at
    assert rules["root"].count("block") == 1 and 'get_character(\\"Ava\\")' in rules["block1"]
    with pytest.raises(ValueError, match="without characters"):
        program_grammar((), ["a_1"], [], ["idle"])
    with pytest.raises(ValueError, match="no alternatives"):
        program_grammar(("Ava",), [], [], ["idle"])
    no_seats = program_grammar(("Ava",), ["table_1"], [], ["idle"])
    assert "get_area_to_sit_on" not in no_seats and "seat ::=" not in no_seats


def _alternatives(grammar: str, rule: str) -> set[str]:
    rules = dict(line.split(" ::= ", 1) for line in grammar.strip().splitlines())
    return set(re.findall(r'\\"([^"\\]+)\\"', rules[rule]))


def test_the_events_words_narrow_objects_and_seats_to_its_shortlist() -> None:
    """"sits on the couch and watches TV" offers the couch and the TV, not the 30 other objects;
    the seat a character holds stays out; words that name nothing keep everything."""
    grammar = event_program_grammar(SCENE, ("Ava",), ROSTER, SEATS_IN_USE, LABELS, activity="sit on the couch and watch TV")
    assert _alternatives(grammar, "object") == {"couch_1", "tv_1"}
    assert _alternatives(grammar, "seat") == {"couch_1"}
    assert {"couch_1", "tv_1", "Ben"} <= _alternatives(grammar, "look")
    vague = event_program_grammar(SCENE, ("Ava",), ROSTER, SEATS_IN_USE, LABELS, activity="wait for a friend")
    assert _alternatives(vague, "object") == {o.name for o in SCENE.objects}
    table = event_program_grammar(SCENE, ("Ava",), ROSTER, SEATS_IN_USE, LABELS, activity="sit on a chair at the table")
    assert "chair_2" not in _alternatives(table, "seat") and _alternatives(table, "seat") <= {f"chair_{i}" for i in range(1, 6)}


def test_a_program_of_the_grammar_runs_in_the_sandbox() -> None:
    program = ('```python\ndef parse_event():\n    c1 = get_character("Ava")\n    c1.set_target_action("use_coffee_maker")\n'
               '    c1.set_position(get_area_to_interact_with("coffee_maker_1"))\n'
               '    c1.set_orientation("coffee_maker_1")\n```')
    assert _admits(event_grammar(EVENT), program)
    result = run_reply(program, scene=SCENE, event=EVENT, world=WORLD, seed=1, action_labels=scene_action_labels(SCENE))
    assert result.plans[0].action == "use_coffee_maker"


def test_grammar_travels_in_the_request_and_only_to_local_models() -> None:
    prompts = PromptLibrary()
    inp = ParserInput(scene_description="x", event=EVENT, characters=ROSTER, action_labels=("idle",), grammar="root ::= \"a\"\n")
    req = parser_request(prompts, inp)
    assert req.grammar == 'root ::= "a"\n'
    client = LiteLLMClient(default_config(), NullTraceSink("t"), check_local=lambda m: None)
    node = client.config.node("event_parser")
    params, _ = client._params(node, "local/qwen2.5-coder-0.5b", req)
    assert params["response_format"] == {"type": "gbnf", "grammar": req.grammar}
    params, _ = client._params(node, "openai/gpt-4o-mini", req)
    assert "response_format" not in params
    client.close()


def test_requests_without_a_grammar_keep_their_old_hash() -> None:
    req = LLMRequest(node="narrator", messages=(ChatMessage(role="user", content="hi"),), seed=3)
    # the fields a request had before grammars and choices existed
    old = json.dumps(
        req.model_dump(mode="json", exclude={"sim_frame", "grammar", "choices"}), sort_keys=True, separators=(",", ":")
    )
    assert req.content_hash() == hashlib.sha256(old.encode()).hexdigest()
    assert req.model_copy(update={"grammar": 'root ::= "a"'}).content_hash() != req.content_hash()
    assert req.model_copy(update={"choices": ("a", "b")}).content_hash() != req.content_hash()


def test_local_provider_builds_a_llama_grammar() -> None:
    pytest.importorskip("llama_cpp")
    from llama_cpp.llama_grammar import LlamaGrammar

    from storyteller.orchestrator.llm.local_model import _llama_params

    params = _llama_params({"max_tokens": 50, "response_format": {"type": "gbnf", "grammar": event_grammar(EVENT)}})
    assert isinstance(params["grammar"], LlamaGrammar) and "response_format" not in params


@pytest.mark.embedded_model
async def test_real_embedded_model_writes_a_runnable_program_under_the_grammar(tmp_path: Path) -> None:
    from storyteller.orchestrator.llm.local_model import LocalLlamaProvider, register_local_provider
    from storyteller.orchestrator.llm.trace_writer import TraceWriter
    from storyteller.orchestrator.llm.traces import read_trace

    embedded_weights_or_skip()
    register_local_provider(LocalLlamaProvider())
    client = LiteLLMClient(default_config(), TraceWriter(tmp_path / "t.jsonl"))
    inp = ParserInput(scene_description="- kitchen: coffee_maker_1, fridge_1, cabinet_1", event=EVENT, characters=ROSTER,
                      action_labels=LABELS, seats_in_use=SEATS_IN_USE, seed=0,
                      grammar=event_grammar(EVENT))
    response = await client.complete(parser_request(PromptLibrary(), inp))
    client.close()
    result = run_reply(response.text, scene=SCENE, event=EVENT, world=WORLD, seed=0, action_labels=LABELS)
    assert [p.character for p in result.plans] == ["Ava"]
    attempt: Any = next(read_trace(tmp_path / "t.jsonl").attempts())
    assert attempt.params["response_format"]["type"] == "gbnf"


def test_a_seat_someone_stands_at_is_not_offered() -> None:
    from storyteller.agents.program_grammar import event_program_grammar
    from storyteller.tools.areas import seat_slots

    seat = next(o for o in SCENE.objects if o.is_seat and len(seat_slots(o)) == 1)
    slot = seat_slots(seat)[0].position
    roster = (CharacterStatus(name="Ava"), CharacterStatus(name="Cy", position=(float(slot[0]) + 0.1, float(slot[1]))))
    blocked = event_program_grammar(SCENE, ("Ava",), roster, (), ("idle",))
    free = event_program_grammar(SCENE, ("Ava",), roster[:1], (), ("idle",))

    def seat_rule(g: str) -> str:
        return next(line for line in g.splitlines() if line.startswith("seat ::="))

    assert f'\\"{seat.name}\\"' in seat_rule(free) and f'\\"{seat.name}\\"' not in seat_rule(blocked)


def test_after_a_sit_area_only_seated_actions_are_offered_and_the_check_agrees() -> None:
    from storyteller.agents.event_parser import check_plans
    from storyteller.agents.retry_feedback import AnswerRejectedError
    from storyteller.tools.character_states import CharacterPlan

    g = event_grammar(VAGUE)
    rules = dict(line.split(" ::= ", 1) for line in g.strip().splitlines())
    assert '\\"use_coffee_maker\\"' in rules["standlabel"] and '\\"use_coffee_maker\\"' not in rules["sitlabel"]
    assert "sitlabel" in rules["block1"] and "sitarea" in rules["block1"].split("standlabel")[0]
    assert "sitarea" not in rules["block1"].split("standlabel")[1]  # a standing-only action never sits
    assert '\\"idle\\"' in rules["sitlabel"]
    seated = CharacterPlan(character="Ava", action="use_coffee_maker", area="sit on chair_1", position=(1.0, 1.0),
                           facing=(1.0, 0.0), seat="chair_1")
    with pytest.raises(AnswerRejectedError, match="cannot use_coffee_maker while sitting on chair_1"):
        check_plans(EVENT, [seated])
    assert check_plans(EVENT, [seated.model_copy(update={"action": "idle"})])[0].seat == "chair_1"


_GBNF_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|[A-Za-z0-9_]+|[()|?]')


def _admits(grammar: str, text: str) -> bool:
    """Whether ``text`` is a sentence of ``grammar``: the event grammar has no recursion and only
    literals, rule names, groups and alternatives, so it expands into one regular expression."""
    rules = dict(line.split(" ::= ", 1) for line in grammar.strip().splitlines())

    def expand(name: str) -> str:
        out = []
        for tok in _GBNF_TOKEN.findall(rules[name]):
            if tok.startswith('"'):
                out.append(re.escape(json.loads(tok)))
            elif tok in "()|?":
                out.append({"(": "(?:", ")": ")", "|": "|", "?": "?"}[tok])
            else:
                out.append(f"(?:{expand(tok)})")
        return "".join(out)

    return re.fullmatch(expand("root"), text) is not None


def test_the_events_words_narrow_the_labels_and_the_action_comes_first() -> None:
    """"make coffee" offers the coffee maker's label only, and a standing one: no seat area."""
    g = event_grammar(EVENT)
    rules = dict(line.split(" ::= ", 1) for line in g.strip().splitlines())
    assert _alternatives(g, "label") == {"use_coffee_maker"}
    assert "sitarea" not in rules["block1"] and "seat" not in rules
    block = rules["block1"]
    assert block.index("set_target_action") < block.index("set_position") < block.index("set_orientation")
    seated = event_program_grammar(SCENE, ("Ava",), ROSTER, SEATS_IN_USE, LABELS,
                                   activity="sit on the couch and read a book")
    assert _alternatives(seated, "sitlabel") == {"read_book"} and "standlabel" not in seated


def test_words_naming_no_thing_use_the_thing_their_action_works() -> None:
    """"spin a vinyl" names no object but ranks turn_on_record_player: the record player is the
    one thing offered (a 0.5B model went to a cabinet); words naming nothing ranked offer all."""
    spun = event_options(SCENE, ("Ava",), ROSTER, SEATS_IN_USE, LABELS, activity="Ava fancies spinning some vinyl")
    assert spun.labels[0] == "turn_on_record_player" and spun.objects == ("record_player_1",)
    assert len(event_options(SCENE, ("Ava",), ROSTER, SEATS_IN_USE, LABELS, activity="Ava hums").objects) > 10


def test_seats_are_sat_on_not_interacted_with() -> None:
    """"interact with armchair_1" means sitting on it (and Ben holds it): seats are offered to
    the seat function only (when free), and stay landmarks for the other areas."""
    roster = (CharacterStatus(name="Ava"), CharacterStatus(name="Ben", busy=True, seat="armchair_1"))
    g = event_program_grammar(SCENE, ("Ava",), roster, ("armchair_1",), LABELS, activity="pass the time")
    assert "armchair_1" in _alternatives(g, "object")
    assert "armchair_1" not in _alternatives(g, "interactobject") and "tv_1" in _alternatives(g, "interactobject")
    program = ('```python\ndef parse_event():\n    c1 = get_character("Ava")\n    c1.set_target_action("idle")\n'
               '    c1.set_position(get_area_{}("armchair_1"))\n    c1.set_orientation("tv_1")\n```')
    assert _admits(g, program.format("close_to")) and not _admits(g, program.format("to_interact_with"))
    assert not _alternatives(g, "interactobject") & {o.name for o in SCENE.objects if o.is_seat}
    assert "chair_1" in _alternatives(g, "seat")


@pytest.mark.parametrize(("activity", "functions"), [
    ("waits behind the couch", {"get_area_behind"}),
    ("stands on the left-hand side of the fridge", {"get_area_left_of"}),
    ("stands to the right of the bookshelf", {"get_area_right_of"}),
    ("waits in the gap between the table and the couch", {"get_area_between"}),
    ("waits right next to the fridge", {"get_area_adjacent_to", "get_area_close_to"}),
])
def test_where_words_name_the_area_function_and_a_place_beside_a_thing_is_stood_in(
    activity: str, functions: set[str]
) -> None:
    g = event_program_grammar(SCENE, ("Ava",), ROSTER, SEATS_IN_USE, LABELS, activity=activity)
    rules = dict(line.split(" ::= ", 1) for line in g.strip().splitlines())
    offered = set(re.findall(r'"(get_area_[a-z_]+)\(', rules["area"]))
    assert offered == functions
    # behind the couch is not on it; waiting right next to the fridge (no seat named) is standing
    assert "sitarea" not in rules["block1"]


def test_a_sitting_word_keeps_the_seat_even_with_a_where_word() -> None:
    g = event_program_grammar(SCENE, ("Ava",), ROSTER, SEATS_IN_USE, LABELS,
                              activity="sits on a chair in front of the tv and watches the news")
    rules = dict(line.split(" ::= ", 1) for line in g.strip().splitlines())
    assert "sitarea" in rules["block1"] and "standlabel" not in rules


def test_words_about_a_seat_sit_on_it_though_no_word_says_sit() -> None:
    """"takes the one" of the chairs, to read: the event is about a chair and reading can be done
    seated, so the character sits; a chair that is only a landmark, or an action that cannot be
    played seated, does not make anyone sit."""
    about = event_options(SCENE, ("Ava",), ROSTER, SEATS_IN_USE, LABELS,
                          "Of all the chairs, Ava takes the one farthest from the floor lamp, to read a novel.")
    assert about.posture == "sit" and about.must_sit
    landmark = event_options(SCENE, ("Ava",), ROSTER, SEATS_IN_USE, LABELS, "Ava reads a novel by the chair.")
    assert landmark.posture is None
    assert not about_a_seat(SCENE, "Ava takes the chair to the coffee maker", "use_coffee_maker")


def _all_sit_on(seat: str, action: str, facing: str, names: tuple[str, ...] = ("Ava", "Cy")) -> str:
    """A reply whose program sends every one of ``names`` to sit on ``seat``."""
    return ('```python\ndef parse_event():\n'
            + "".join(f'    c{i} = get_character("{n}")\n    c{i}.set_target_action("{action}")\n'
                      f'    c{i}.set_position(get_area_to_sit_on("{seat}"))\n    c{i}.set_orientation("{facing}")\n'
                      for i, n in enumerate(names, start=1))
            + '```')


def test_two_characters_sent_to_one_chair_sit_together_and_never_on_a_held_seat() -> None:
    """"Ava and Cy sit on chair_1": Cy takes the nearest free chair instead of failing; but a
    chair held by someone outside the event is still refused."""
    from storyteller.tools.errors import UnsatisfiableAreaError

    event = Event(characters=("Ava", "Cy"), activity="chat at the table")
    program = _all_sit_on("chair_1", "chat", "table_1")
    world = WorldView(characters=(CharacterState(name="Ava", position=(1.0, 1.0)), CharacterState(name="Cy", position=(1.5, 1.0))))
    result = run_reply(program, scene=SCENE, event=event, world=world, seed=0, action_labels=LABELS)
    seats = [p.seat for p in result.plans]
    assert seats[0] == "chair_1" and seats[1] not in (None, "chair_1") and seats[1].startswith("chair_")
    held = WorldView(characters=(*world.characters, CharacterState(name="Ben", busy=True, seat="chair_1")),
                     objects_in_use={"chair_1": "Ben"})
    with pytest.raises(UnsatisfiableAreaError, match="chair_1"):
        run_reply(program, scene=SCENE, event=event, world=held, seed=0, action_labels=LABELS)


def test_the_companion_of_a_two_seat_table_sits_at_that_table_not_the_nearer_next_one() -> None:
    """The restaurant's small table_4 has chair_11 and chair_12; chair_10, at table_3, is a few
    centimetres nearer chair_11: "Ava and Cy sit on chair_11" seats Cy on chair_12."""
    restaurant = resolve_scene("restaurant")
    event = Event(characters=("Ava", "Cy"), activity="eat at the small table")
    program = _all_sit_on("chair_11", "eat", "table_4")
    world = WorldView(characters=(CharacterState(name="Ava", position=(3.0, 3.0)), CharacterState(name="Cy", position=(3.5, 3.0))))
    result = run_reply(program, scene=restaurant, event=event, world=world, seed=0,
                       action_labels=scene_action_labels(restaurant))
    assert [p.seat for p in result.plans] == ["chair_11", "chair_12"]


def test_a_retry_after_a_place_without_room_offers_every_area_function_by_the_same_things() -> None:
    strict = event_program_grammar(SCENE, ("Ava",), ROSTER, SEATS_IN_USE, LABELS, activity="waits behind the couch")
    wide = event_program_grammar(SCENE, ("Ava",), ROSTER, SEATS_IN_USE, LABELS, activity="waits behind the couch",
                                 widen=True)

    def offered(g: str) -> set[str]:
        rules = dict(line.split(" ::= ", 1) for line in g.strip().splitlines())
        return set(re.findall(r'"(get_area_[a-z_]+)\(', rules["area"]))

    assert offered(strict) == {"get_area_behind"}
    assert {"get_area_behind", "get_area_close_to", "get_area_adjacent_to"} <= offered(wide)
    assert _alternatives(wide, "object") == _alternatives(strict, "object")


@pytest.mark.parametrize(("activity", "seated"), [
    ("shares a meal at the kitchen table", True),  # eating at a table: on a chair
    ("eats a sandwich standing at the kitchen table", False),  # unless the words say otherwise
    ("wipes the kitchen table", False),
])
def test_a_meal_or_desk_work_is_done_sitting_unless_the_words_say_otherwise(activity: str, seated: bool) -> None:
    g = event_program_grammar(SCENE, ("Ava",), ROSTER, SEATS_IN_USE, LABELS, activity=activity)
    rules = dict(line.split(" ::= ", 1) for line in g.strip().splitlines())
    assert ("standlabel" not in rules and "label" not in rules and "| area" not in rules["block1"]) == seated


def _block(name: str, action: str, area: str, look: str) -> str:
    return (f'    c = get_character("{name}")\n    c.set_target_action("{action}")\n'
            f'    c.set_position({area})\n    c.set_orientation("{look}")\n')


def test_the_open_grammar_of_w_o_event_lets_the_model_pick_who_acts_and_nothing_is_narrowed() -> None:
    """"w/o Event" has no event, so its grammar offers every free character (one block each at
    most, any subset, or ``pass``), every label, every object and every free seat."""
    roster = (*ROSTER, CharacterStatus(name="Cy", position=(3.0, 1.0)))
    grammar = open_program_grammar(SCENE, roster, SEATS_IN_USE, LABELS)
    assert _alternatives(grammar, "who") == {"Ava", "Cy"}  # Ben is busy
    assert _alternatives(grammar, "object") == {o.name for o in SCENE.objects}
    assert _alternatives(grammar, "sitlabel") | _alternatives(grammar, "standlabel") == set(LABELS)
    seats = _alternatives(grammar, "seat")
    assert seats and not seats & {"couch_1", "chair_2"}  # in use
    start, end = "```python\ndef parse_event():\n", "```"
    coffee = _block("Cy", "use_coffee_maker", 'get_area_to_interact_with("coffee_maker_1")', "coffee_maker_1")
    sit = _block("Ava", "read_book", 'get_area_to_sit_on("chair_1")', "table_1")
    assert _admits(grammar, start + "    pass\n" + end)
    assert _admits(grammar, start + coffee + end) and _admits(grammar, start + coffee + sit + end)
    assert not _admits(grammar, start + end)  # nobody and no pass
    assert not _admits(grammar, start + coffee + sit + coffee + end)  # more blocks than free characters
    assert not _admits(grammar, start + _block("Ben", "idle", 'get_area_close_to("tv_1")', "tv_1") + end)
    assert not _admits(grammar, start + _block("Ava", "read_book", 'get_area_to_sit_on("couch_1")', "tv_1") + end)
    crowd = (*roster, *(CharacterStatus(name=n, position=(float(i), 2.0)) for i, n in enumerate(("Di", "Eve", "Fay"))))
    many = open_program_grammar(SCENE, crowd, SEATS_IN_USE, LABELS)
    blocks = [_block(n, "use_coffee_maker", 'get_area_to_interact_with("coffee_maker_1")', "coffee_maker_1")
              for n in ("Ava", "Cy", "Di", "Eve")]
    assert _admits(many, start + "".join(blocks[:3]) + end) and not _admits(many, start + "".join(blocks) + end)
    with pytest.raises(ValueError, match="nobody is free"):
        open_program_grammar(SCENE, (ROSTER[1],), SEATS_IN_USE, LABELS)


def test_the_open_grammar_parses_in_llama_cpp() -> None:
    pytest.importorskip("llama_cpp")
    from llama_cpp.llama_grammar import LlamaGrammar

    assert LlamaGrammar.from_string(open_program_grammar(SCENE, ROSTER, SEATS_IN_USE, LABELS), verbose=False) is not None


def test_a_place_between_two_things_takes_two_different_things() -> None:
    """``get_area_between`` over one thing twice is refused by the sandbox: the grammar does not
    let the model write it (the 0.5B model had named one shelf twice), while any two different
    things stay open, in either order; with one thing only, no two-thing area is offered."""
    start, end = "```python\ndef parse_event():\n", "```"
    g = program_grammar(("Ava",), ("bookshelf_1", "couch_1", "tv_1"), (), ("idle",))

    def program(area: str) -> str:
        return (start + f'    c1 = get_character("Ava")\n    c1.set_target_action("idle")\n'
                f'    c1.set_position({area})\n    c1.set_orientation("tv_1")\n' + end)

    def wait_between(a: str, b: str) -> str:
        return program(f'get_area_between("{a}", "{b}")')

    assert _admits(g, wait_between("bookshelf_1", "couch_1")) and _admits(g, wait_between("tv_1", "bookshelf_1"))
    assert not _admits(g, wait_between("bookshelf_1", "bookshelf_1"))
    assert not _admits(g, wait_between("tv_1", "tv_1"))
    lone = program_grammar(("Ava",), ("tv_1",), (), ("idle",))
    assert "get_area_between" not in lone and _admits(lone, program('get_area_close_to("tv_1")'))
    pytest.importorskip("llama_cpp")
    from llama_cpp.llama_grammar import LlamaGrammar

    assert LlamaGrammar.from_string(g, verbose=False) is not None

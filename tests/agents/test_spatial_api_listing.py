"""The spatial API's function list exists once, in ``storyteller.tools.spatial_api``: the event parser's
prompt and the program grammar are rendered from it, and this test checks that the class, the
prompt (with its examples) and the grammar agree."""

from __future__ import annotations

import inspect
import re

from storyteller.agents.event_parser import ParserInput, parser_messages, spatial_api_listing
from storyteller.agents.messages import Event
from storyteller.agents.program_grammar import area_functions, program_grammar
from storyteller.agents.prompt_templates import BENCHMARK_TAGS, PromptLibrary
from storyteller.sim.scene.bundled import resolve_scene
from storyteller.tools.spatial_api import CharacterHandle, SpatialAPI, handle_methods

NOT_PROGRAM_FUNCTIONS = {"namespace", "functions", "resolve"}
"""Public SpatialAPI methods for the host (the sandbox's namespace, plan resolution)."""
CALL = re.compile(r"\b([A-Za-z_][A-Za-z0-9_]*)\(")


def _system_prompt() -> str:
    inp = ParserInput(
        scene_description="- room: table_1", event=Event(characters=("Ann",), activity="wait"), characters=(),
        action_labels=("idle",),
    )
    return parser_messages(PromptLibrary(), inp)[0].content


def test_every_public_method_is_a_registered_function_with_a_one_line_doc() -> None:
    public = {n for n, m in vars(SpatialAPI).items() if inspect.isfunction(m) and not n.startswith("_")}
    names = [f.name for f in SpatialAPI.functions()]
    assert set(names) == public - NOT_PROGRAM_FUNCTIONS
    assert len(names) == len(set(names))
    for f in SpatialAPI.functions():
        assert f.summary and len(f.summary) < 300 and "\n" not in f.summary, f.name
        assert f.call.startswith(f"{f.name}(") and f.returns, f.name
    assert [m.name for m in handle_methods()] == ["set_position", "set_orientation", "set_target_action"]
    assert {m.name for m in handle_methods()} | {"name"} == CharacterHandle.sandbox_attributes


def test_the_namespace_is_the_registry() -> None:
    api = SpatialAPI(resolve_scene("home"))
    assert list(api.namespace()) == [f.name for f in SpatialAPI.functions()]


def test_the_prompt_lists_exactly_the_listed_functions_with_their_signatures() -> None:
    system = _system_prompt()
    listing = "\n".join(spatial_api_listing().values())
    for f in SpatialAPI.functions():
        if f.listed:
            assert f.call in system, f.name
        else:
            assert f"{f.name}(" not in system, f.name
    for m in handle_methods():
        assert f"c.{m.call}" in system and m.summary in listing


def test_prompt_files_call_only_functions_the_api_lists() -> None:
    """The template, its examples and the rendered prompt name no function that does not exist
    (or that the prompt does not list)."""
    prompts = PromptLibrary()
    listed = {f.name for f in SpatialAPI.functions() if f.listed} | {m.name for m in handle_methods()}
    texts = [prompts.text("event_parser/system.md"), prompts.examples("event_parser", BENCHMARK_TAGS), _system_prompt()]
    called = {name for text in texts for name in CALL.findall(text)}
    assert called - {"parse_event"} <= listed, sorted(called - {"parse_event"} - listed)
    template = prompts.text("event_parser/system.md")
    assert not any(f"{f.name}(" in template for f in SpatialAPI.functions())  # no copy of the list


def test_the_grammar_offers_the_listed_area_functions_and_nothing_else() -> None:
    one, two, seat = area_functions()
    listed_areas = {f.name for f in SpatialAPI.functions() if f.listed and f.kind in ("area", "seat_area")}
    assert {*one, *two, seat} == listed_areas
    by_name = {f.name: f for f in SpatialAPI.functions()}
    assert all(len(by_name[n].parameters) == 1 for n in (*one, seat)) and all(len(by_name[n].parameters) == 2 for n in two)
    grammar = program_grammar(("Ann",), ["table_1", "chair_1"], ["chair_1"], ["idle"])
    in_grammar = set(re.findall(r"([a-z_]+)\(", grammar)) - {"parse_event", "get_character"}
    in_grammar -= {m.name for m in handle_methods()}
    assert in_grammar == listed_areas
    assert in_grammar <= set(CALL.findall(_system_prompt()))

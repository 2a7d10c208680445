"""Describer: every object exactly once, feedback on misses/repeats, repair, disk cache."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from storyteller.agents.describer import (
    AreaList,
    DescriberInput,
    cache_path,
    describe_scene,
    describe_scene_cached,
    describer_input_from_scene,
    describer_regions_schema,
    describer_request,
    parse_areas,
    render_description,
    repair_areas,
)
from storyteller.agents.prompt_templates import PromptLibrary
from storyteller.agents.retry_feedback import AnswerRejectedError, RetriesExhaustedError
from storyteller.sim.scene.bundled import resolve_scene
from tests.support.scripted_llm import ScriptedLLM

NAMES = ("fridge_1", "cabinet_1", "coffee_maker_1", "couch_1", "tv_1")
INP = DescriberInput(
    scene_name="mini",
    object_names=NAMES,
    scene_graph_json='{"fridge_1":{}}',
    clusters=(("fridge_1", "cabinet_1", "coffee_maker_1"), ("couch_1", "tv_1")),
    supports={"coffee_maker_1": "cabinet_1"},
)
GOOD = {"areas": [{"name": "kitchen", "purpose": "make coffee", "objects": ["fridge_1", "cabinet_1", "coffee_maker_1"]},
                  {"name": "living room", "purpose": "watch TV", "objects": ["couch_1", "tv_1"]}]}
PARTIAL = {"areas": [{"name": "kitchen", "purpose": "", "objects": ["fridge_1", "fridge_1", "sink_9"]},
                     {"name": "living room", "purpose": "relax", "objects": ["couch_1"]}]}


def test_schema_restricts_names_and_bounds_arrays() -> None:
    req = describer_request(PromptLibrary(), INP)
    assert req.json_schema is not None
    items = req.json_schema["properties"]["areas"]["items"]["properties"]["objects"]
    assert items["items"]["enum"] == list(NAMES) and items["maxItems"] == len(NAMES)
    assert req.json_schema["properties"]["areas"]["maxItems"] <= 8
    assert "fridge_1, cabinet_1, coffee_maker_1" in req.messages[1].content


def test_missing_repeated_unknown_are_all_named() -> None:
    with pytest.raises(AnswerRejectedError) as info:
        parse_areas(json.dumps(PARTIAL), NAMES)
    text = str(info.value)
    assert "sink_9" in text and "named more than once: fridge_1" in text
    assert "missing (put each into one area): cabinet_1, coffee_maker_1, tv_1" in text


def test_render_names_each_object_once_with_supports() -> None:
    text = render_description(parse_areas(json.dumps(GOOD), NAMES), INP.supports)
    assert text.splitlines()[0] == "- kitchen (make coffee): fridge_1, cabinet_1 (with coffee_maker_1 on it)"
    for name in NAMES:
        assert sum(tok.strip(",()") == name for tok in text.split()) == 1


def test_repair_uses_clusters() -> None:
    repaired = repair_areas(AreaList.model_validate(PARTIAL), INP)
    by_area = {a.name: a.objects for a in repaired.areas}
    assert by_area["kitchen"] == ("fridge_1", "cabinet_1", "coffee_maker_1")
    assert by_area["living room"] == ("couch_1", "tv_1")


async def test_feedback_retry_then_success() -> None:
    port = ScriptedLLM([json.dumps(PARTIAL), json.dumps(GOOD)])
    desc = await describe_scene(port, PromptLibrary(), INP)
    assert desc.attempts == 2 and not desc.repaired
    assert "named more than once: fridge_1" in port.requests[1].messages[-1].content


async def test_exhausted_retries_repair_or_raise() -> None:
    desc = await describe_scene(ScriptedLLM([json.dumps(PARTIAL)] * 2), PromptLibrary(), INP, max_retries=1)
    assert desc.repaired and "tv_1" in desc.text
    with pytest.raises(RetriesExhaustedError):
        await describe_scene(ScriptedLLM(["{}"] * 2), PromptLibrary(), INP, max_retries=1, repair=False)
    garbage = await describe_scene(ScriptedLLM(["not json"]), PromptLibrary(), INP, max_retries=0)
    assert garbage.repaired and all(n in garbage.text for n in NAMES)


async def test_cache_per_scene_model_and_prompts(tmp_path: Path) -> None:
    scene = resolve_scene("home")
    inp = describer_input_from_scene(scene)
    reply = json.dumps({"areas": [{"name": "all", "purpose": "", "objects": list(inp.object_names)}]})
    port = ScriptedLLM([reply, reply])
    lib = PromptLibrary()
    first = await describe_scene_cached(port, lib, scene, model="m1", cache_dir=tmp_path, inp=inp)
    again = await describe_scene_cached(port, lib, scene, model="m1", cache_dir=tmp_path, inp=inp)
    assert first == again and len(port.requests) == 1
    await describe_scene_cached(port, lib, scene, model="m2", cache_dir=tmp_path, inp=inp)
    assert len(port.requests) == 2
    assert cache_path(tmp_path, scene, "m1", lib) != cache_path(tmp_path, scene, "m2", lib)


def test_input_from_bundled_scene() -> None:
    inp = describer_input_from_scene(resolve_scene("home"))
    assert "coffee_maker_1" in inp.object_names and inp.clusters
    assert inp.supports.get("coffee_maker_1") is not None
    json.loads(inp.scene_graph_json)


def test_render_chain_of_supports_names_everything_once() -> None:
    areas = AreaList.model_validate({"areas": [{"name": "a", "purpose": "", "objects": ["cup_1", "tray_1", "table_1"]}]})
    text = render_description(areas, {"cup_1": "tray_1", "tray_1": "table_1"})
    assert text == "- a: tray_1 (with cup_1 on it), table_1"


REGIONS_INP = DescriberInput(
    scene_name="mini",
    object_names=NAMES,
    scene_graph_json="{}",
    clusters=(("fridge_1", "cabinet_1", "coffee_maker_1"), ("couch_1",), ("tv_1",)),
    supports={"coffee_maker_1": "cabinet_1"},
    mode="regions",
)


async def test_regions_mode_pins_one_entry_per_region_and_groups_by_name() -> None:
    lib = PromptLibrary()
    req = describer_request(lib, REGIONS_INP)
    assert req.json_schema is not None
    regions = req.json_schema["properties"]["regions"]
    assert [e["properties"]["region"]["const"] for e in regions["prefixItems"]] == [1, 2, 3]
    assert regions["minItems"] == regions["maxItems"] == 3 and "items" not in regions
    kinds = [e["properties"]["area"]["enum"] for e in regions["prefixItems"]]
    assert kinds[0][0] == "kitchen" and "living room" in kinds[1] and "dining area" not in kinds[1]
    assert "region 2: couch_1\n  areas: living room, lounge" in req.messages[1].content
    bad = json.dumps({"regions": [{"region": 1, "area": "kitchen", "purpose": ""}, {"region": 3, "area": "x", "purpose": ""}]})
    good = json.dumps({"regions": [{"region": 1, "area": "kitchen", "purpose": "coffee"},
                                   {"region": 2, "area": "Living room", "purpose": ""},
                                   {"region": 3, "area": "living  room", "purpose": "watch TV"}]})
    port = ScriptedLLM([bad, good])
    desc = await describe_scene(port, lib, REGIONS_INP)
    feedback = port.requests[1].messages[-1].content
    assert "answer once per region, in order: regions 1 to 3 (got 1, 3)" in feedback
    assert desc.attempts == 2 and not desc.repaired
    assert desc.text == "- kitchen (coffee): fridge_1, cabinet_1 (with coffee_maker_1 on it)\n- Living room (watch TV): couch_1, tv_1"


def test_the_regions_schema_admits_only_complete_answers_in_order() -> None:
    """What the grammar decodes is what the parser accepts: the pinned schema rejects a
    missing, repeated or reordered region (checked with a JSON-schema validator)."""
    jsonschema = pytest.importorskip("jsonschema")
    schema = describer_regions_schema(3)

    def entry(r: int) -> dict[str, object]:
        return {"region": r, "area": "kitchen", "purpose": ""}

    jsonschema.validate({"regions": [entry(1), entry(2), entry(3)]}, schema)
    for wrong in ([1, 2], [1, 2, 2], [2, 1, 3], [1, 2, 3, 4]):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate({"regions": [entry(r) for r in wrong]}, schema)
    with pytest.raises(jsonschema.ValidationError):  # an object name is no area name
        jsonschema.validate({"regions": [entry(1), entry(2), {**entry(3), "area": "fridge_1"}]}, schema)


async def test_regions_mode_repairs_after_last_try() -> None:
    partial = json.dumps({"regions": [{"region": 1, "area": "kitchen", "purpose": ""}]})
    desc = await describe_scene(ScriptedLLM([partial]), PromptLibrary(), REGIONS_INP, max_retries=0)
    assert desc.repaired and "couch_1" in desc.text and "tv_1" in desc.text

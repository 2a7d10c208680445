"""Reference cases the pipeline tests share: case 20 with scripted describer / narrator /
parser answers, and the 10 PI cases with their hand-written programs (``tests/pi_programs``).
Need the reference data (``tests.support.reference``)."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

from storyteller.agents.llm_port import LLMRequest
from storyteller.benchmark.reference_cases import BenchmarkCase, load_cases, scene_dir
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene
from storyteller.tools.scene_graph import SceneGraph, build_scene_graph
from tests.support.reference import REFERENCE

CASE = 20  # SS: Taylor reads a book sitting on chair_3 (a describer call, a narrator call, a parser call)
WHO, ACTIVITY = "Taylor", "read a book sitting on chair_3"
PROGRAM = (
    '```python\ndef parse_event():\n    a = get_character("Taylor")\n'
    '    a.set_position(get_area_to_sit_on("chair_3"))\n    a.set_target_action("read_book")\n```'
)
SEED, RETRIES, MODEL = 3, 1, "openai/scripted"


def answer(request: LLMRequest) -> str:
    if request.node == "describer":
        return "{}"  # rejected: the describer retries, then repairs from the clusters
    if request.node == "narrator":
        return json.dumps({"reasoning": "asked for", "event": {"characters": [WHO], "activity": ACTIVITY}})
    return PROGRAM


def the_case() -> tuple[BenchmarkCase, Scene]:
    case = load_cases(REFERENCE, [CASE])[0].at_level(2)
    return case, load_scene(scene_dir(REFERENCE, case))


# ----- the PI cases ---------------------------------------------------------------------
PROGRAMS = Path(__file__).resolve().parents[1] / "pi_programs"
CASE_IDS = list(range(60, 70))


def case_path(case_id: int) -> Path:
    return REFERENCE / "benchmark" / "test_cases" / "6_PI" / f"testcase_{case_id}.json"


@cache
def scene_and_graph(name: str) -> tuple[Scene, SceneGraph]:
    scene = load_scene(REFERENCE / "configs" / "scenes" / name)
    return scene, build_scene_graph(scene)

"""One object, one user (issue 23, item 5): a coffee maker, a microwave, a whiteboard spot that a
character is using is not given to a second one at the same time unless the action is shared.

Before: nothing but seats was ever counted as taken, so the event parser could send Ben to the
coffee maker Ava was walking to (or using), and both acted on it at once.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import anyio
import numpy as np
import pytest

from storyteller.agents.llm_port import LLMRequest
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.model import Scene
from storyteller.tools.character_states import CharacterState, WorldView
from storyteller.tools.errors import ObjectInUseError
from storyteller.tools.event_program import run_event_program
from storyteller.tools.object_use import places, shared_use_frames, use_conflicts, used_labels
from tests.support.scripted_llm import ScriptedLLM


def _program(who: str, action: str, area: str, target: str) -> str:
    return (f'def parse_event():\n    c = get_character("{who}")\n    c.set_target_action("{action}")\n'
            f'    c.set_position({area}("{target}"))\n    c.set_orientation("{target}")\n')


COFFEE = _program("{who}", "use_coffee_maker", "get_area_to_interact_with", "coffee_maker_1")



def _ava_at(home: Scene, action: str, target: str, *, busy: bool = True, area: str = "get_area_to_interact_with") -> WorldView:
    program = _program("Ava", action, area, target)
    (ava,) = run_event_program(home, program, WorldView(), seed=0)
    return WorldView(characters=(
        CharacterState(name="Ava", action=action, busy=busy, position=(4.0, 4.0), target_position=ava.position),
        CharacterState(name="Ben", position=(5.0, 4.0)),
    ))


def test_the_coffee_maker_ava_is_heading_to_is_refused_to_ben_with_typed_feedback(home: Scene) -> None:
    world = _ava_at(home, "use_coffee_maker", "coffee_maker_1")
    with pytest.raises(ObjectInUseError, match="Ben: coffee_maker_1 is being used by Ava; choose another object or wait"):
        run_event_program(home, COFFEE.format(who="Ben"), world, seed=0)
    waiting = ('def parse_event():\n    c = get_character("Ben")\n    c.set_position(get_area_close_to("coffee_maker_1"))\n'
               '    if is_object_occupied("coffee_maker_1"):\n        c.set_target_action("idle")\n'
               '    else:\n        c.set_target_action("use_coffee_maker")\n')
    (ben,) = run_event_program(home, waiting, world, seed=0)  # the program sees it taken, and waits beside it
    assert ben.action == "idle"
    (ben,) = run_event_program(home, COFFEE.format(who="Ben"), world.model_copy(update={"busy_objects": "wait"}), seed=0)
    to_maker = np.subtract(home.by_name["coffee_maker_1"].center[:2], ben.position)
    assert ben.action == "idle" and float(np.dot(to_maker / np.hypot(*to_maker), ben.facing)) > 0.99


def test_two_characters_of_one_event_cannot_share_the_coffee_maker(home: Scene) -> None:
    both = ('def parse_event():\n    a = get_character("Ava")\n    a.set_target_action("use_coffee_maker")\n'
            '    a.set_position(get_area_to_interact_with("coffee_maker_1"))\n    b = get_character("Ben")\n'
            '    b.set_target_action("use_coffee_maker")\n    b.set_position(get_area_to_interact_with("coffee_maker_1"))\n')
    with pytest.raises(ObjectInUseError, match="line 7: Ben: coffee_maker_1 is being used by Ava"):
        run_event_program(home, both, WorldView(), seed=0)


def test_shared_actions_and_finished_uses_do_not_block(home: Scene) -> None:
    assert used_labels("watch_tv") == () and used_labels("chat") == () and used_labels("use_sink") == ("sink",)
    tv = _ava_at(home, "watch_tv", "tv_1")
    (ben,) = run_event_program(home, _program("Ben", "watch_tv", "get_area_close_to", "tv_1"), tv, seed=0)
    assert ben.action == "watch_tv"
    remote = _ava_at(home, "turn_on_tv", "tv_1")  # one hand on the remote
    with pytest.raises(ObjectInUseError, match="tv_1 is being used by Ava"):
        run_event_program(home, _program("Ben", "turn_off_tv", "get_area_close_to", "tv_1"), remote, seed=0)
    done = _ava_at(home, "use_coffee_maker", "coffee_maker_1", busy=False)  # a finished, non-looping use
    (ben,) = run_event_program(home, COFFEE.format(who="Ben"), done, seed=0)
    assert ben.action == "use_coffee_maker"
    laptop = _ava_at(home, "use_laptop", "laptop_1", busy=False, area="get_area_close_to")  # looping: goes on while she is free
    plans = run_event_program(home, _program("Ben", "use_laptop", "get_area_close_to", "laptop_1"), WorldView(), seed=0)
    assert [c.obj for c in use_conflicts(plans, laptop.characters, home)] == ["laptop_1"]


def test_a_wide_whiteboard_has_a_place_per_writer() -> None:
    office = load_bundled_scene("office")
    board = office.by_name["white_board_1"]
    assert places(board) == max(1, int(max(board.size[0], board.size[1]) // 1.2))


# ----- a scripted run: the planning graph and the simulation ---------------------------------
class CoffeeStory:
    """The LLM port's script: Ava makes coffee, then Ben is sent to the same coffee maker; after
    the feedback he makes toast instead (``stubborn``: he is sent to the coffee maker again).
    Every later step is a wait."""

    def __init__(self, stubborn: bool = False) -> None:
        self.stubborn = stubborn
        self.given: list[str] = []
        self.parser_requests: list[LLMRequest] = []

    def describer(self, request: LLMRequest) -> str:
        assert request.json_schema is not None
        names = request.json_schema["properties"]["areas"]["items"]["properties"]["objects"]["items"]["enum"]
        return json.dumps({"areas": [{"name": "home", "purpose": "live", "objects": names}]})

    def narrator(self, request: LLMRequest) -> str:
        assert request.json_schema is not None
        free = request.json_schema["properties"]["event"]["properties"]["characters"]["items"].get("enum", [])
        who = next((n for n in ("Ava", "Ben") if n in free and n not in self.given), None)
        if who is None:
            return json.dumps({"reasoning": "wait", "event": {"characters": [], "activity": ""}})
        self.given.append(who)
        return json.dumps({"reasoning": "coffee", "event": {"characters": [who], "activity": "make coffee"}})

    def parser(self, request: LLMRequest) -> str:
        self.parser_requests.append(request)
        named = re.search(r'Event: characters \["(\w+)"', request.messages[1].content)
        assert named is not None
        who = named.group(1)
        if who == "Ben" and len(request.messages) > 2 and not self.stubborn:  # told the coffee maker is taken
            return "```python\n" + _program("Ben", "use_toaster", "get_area_to_interact_with", "toaster_1") + "```"
        return "```python\n" + COFFEE.format(who=who) + "```"


def _coffee_run(home: Scene, tmp_path: Path, story: CoffeeStory) -> tuple[dict[str, tuple[str, ...]], dict[str, np.ndarray], list[LLMRequest]]:
    """The story through the planning graph and the simulation (30 s, lockstep): every
    character's per-frame action labels and positions, and the parser's requests for Ben."""
    from langgraph.checkpoint.memory import InMemorySaver

    from storyteller.agents.event_parser import scene_action_labels
    from storyteller.orchestrator.cache_paths import motion_cache_dir
    from storyteller.orchestrator.planning.checkpoints import StoryLog
    from storyteller.orchestrator.planning.graph import compile_planning_graph
    from storyteller.orchestrator.planning.state import PlanningDeps
    from storyteller.orchestrator.session.roster import RosterWorld
    from storyteller.orchestrator.session.runtime import Session
    from storyteller.orchestrator.session.session_types import SessionSettings
    from storyteller.orchestrator.session.step_planner import GraphStepPlanner
    from storyteller.sim.motion.database import load_databases
    from storyteller.sim.motion.matching import MotionMatcher
    from storyteller.sim.world.step import World

    port = ScriptedLLM({"describer": story.describer, "narrator": story.narrator, "event_parser": story.parser})
    log = StoryLog(tmp_path / "runs.sqlite", "coffee")
    deps = PlanningDeps(port=port, scene=home, world=RosterWorld(), story=log, action_labels=scene_action_labels(home), seed=0)
    planner = GraphStepPlanner(compile_planning_graph(InMemorySaver()), deps, "coffee")
    world = World(home, {"Ava": ((3.5, 2.5), 0.0), "Ben": ((3.5, 4.0), 0.0)}, MotionMatcher(load_databases(cache_dir=motion_cache_dir())))
    settings = SessionSettings(frames=30 * 30, pace="lockstep", max_steps=2, instruction="Ava makes coffee. Ben makes coffee.")

    async def main() -> object:
        try:
            return await Session(world, planner, settings).run()
        finally:
            log.close()

    anyio.run(main)
    tracks = world.tracks()
    ben_calls = [r for r in story.parser_requests if 'Event: characters ["Ben"]' in r.messages[1].content]
    return ({n: tuple(t.action_labels or ()) for n, t in tracks.items()},
            {n: np.asarray(t.root_positions) for n, t in tracks.items()}, ben_calls)


def test_a_scripted_run_never_has_two_users_at_the_coffee_maker(home: Scene, tmp_path: Path) -> None:
    labels, positions, ben_calls = _coffee_run(home, tmp_path, CoffeeStory())
    assert len(ben_calls) == 2, "Ben's first program was refused"
    assert "coffee_maker_1 is being used by Ava; choose another object or wait" in ben_calls[1].messages[-1].content
    assert "use_coffee_maker" in labels["Ava"] and "use_toaster" in labels["Ben"]
    assert shared_use_frames(labels, positions, home) == []


def test_a_parser_that_insists_makes_the_second_character_wait_by_the_object(home: Scene, tmp_path: Path) -> None:
    """Told once, the parser sends Ben to the coffee maker again: he waits there (idle, facing
    it) instead of the step failing, and still nobody shares the coffee maker."""
    labels, positions, ben_calls = _coffee_run(home, tmp_path, CoffeeStory(stubborn=True))
    assert len(ben_calls) == 2
    assert "use_coffee_maker" in labels["Ava"] and "use_coffee_maker" not in labels["Ben"]
    end = positions["Ben"][-1][:2]
    maker = home.by_name["coffee_maker_1"].center[:2]
    assert float(np.hypot(*(np.subtract(end, maker)))) < 2.0  # he waits by it
    assert shared_use_frames(labels, positions, home) == []

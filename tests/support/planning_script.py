"""The planning graph's test double world: a tiny scene, a fake event-program runner, scripted
describer / narrator / parser replies and the graph's first state (no model, no sim). Used by
the planning graph's tests and by the tests of what the graph feeds (history, action choice,
traces)."""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from storyteller.agents.messages import CharacterStatus
from storyteller.orchestrator.planning.checkpoints import StoryLog
from storyteller.orchestrator.planning.state import PlanningDeps, PlanningState
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.tools.character_states import WorldView
from storyteller.tools.errors import UnknownObjectError
from tests.support.scripted_llm import ScriptedLLM


def tiny_scene() -> Scene:
    def obj(
        name: str, x: float, y: float, size: tuple[float, float, float] = (0.5, 0.5, 0.9), seat: float = 0.0
    ) -> SceneObject:
        label, idx = name.rsplit("_", 1)
        return SceneObject(
            name=name, label=label, idx=int(idx), center=(x, y, size[2] / 2), size=size,
            has_facing=True, sit_offset_vertical=seat,
        )

    return Scene(
        name="tiny",
        bounds_min=(0.0, 0.0),
        bounds_max=(6.0, 6.0),
        objects=(
            obj("table_1", 2.0, 2.0, (1.2, 0.8, 0.75)),
            obj("chair_1", 2.0, 1.2, seat=0.45),
            obj("chair_2", 2.0, 2.8, seat=0.45),
            obj("fridge_1", 5.0, 5.0, (0.8, 0.7, 1.8)),
        ),
    )


@dataclass
class Plan:
    """A planned character as a runner returns it (the fields the planning code reads)."""

    character: str
    action: str
    area: str
    position: tuple[float, float]
    facing: tuple[float, float]
    seat: str | None = None


def fake_runner(
    scene: Scene, source: str, world: WorldView, *, seed: int, action_labels: object = None, graph: object = None
) -> list[Plan]:
    """Understands just enough: get_character("X") calls, unknown object names, actions."""
    for name in re.findall(r'"([a-z_]+_\d+)"', source):
        if name not in scene.by_name:
            raise UnknownObjectError(f"unknown object '{name}'")
    actions = re.findall(r'set_target_action\("([a-z_]+)"\)', source) or ["idle"]
    plans = []
    for i, who in enumerate(re.findall(r'get_character\("(\w+)"\)', source)):
        plans.append(Plan(who, actions[min(i, len(actions) - 1)], "close to table_1", (1.0 + i + seed % 3, 1.0), (0.0, 1.0)))
    return plans


class FakeWorld:
    def world_view(self, roster: Sequence[CharacterStatus]) -> WorldView:
        """Nobody: the fake runner reads no world, and no device is busy."""
        return WorldView()

    def seats_in_use(self, roster: Sequence[CharacterStatus]) -> list[str]:
        return []


DESCRIPTION = json.dumps(
    {"areas": [{"name": "dining", "purpose": "eat", "objects": ["table_1", "chair_1", "chair_2"]},
               {"name": "kitchen", "purpose": "food", "objects": ["fridge_1"]}]}
)


def narration(chars: list[str], activity: str) -> str:
    return json.dumps({"reasoning": "next", "event": {"characters": chars, "activity": activity}})


PROGRAM = '```python\ndef parse_event():\n    c = get_character("{who}")\n    c.set_position(get_area_close_to("table_1"))\n    c.set_target_action("eat")\n```'


def make_deps(port: ScriptedLLM, story: StoryLog, **kw: Any) -> PlanningDeps:
    return PlanningDeps(
        port=port, scene=tiny_scene(), world=FakeWorld(), story=story,
        action_labels=("idle", "eat", "chat"), runner=fake_runner, scene_graph=None, **kw,
    )


def initial_state(names: list[str], k: int) -> dict[str, Any]:
    return PlanningState(
        instruction="Ann eats.", events_target=k, roster=tuple(CharacterStatus(name=n) for n in names)
    ).model_dump()

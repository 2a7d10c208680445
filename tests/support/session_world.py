"""A story session's test world: free spots on a scene, a world of characters standing on them,
a scripted step planner and a scripted ``litellm.acompletion`` for the whole planning graph on
the home scene (no model)."""

from __future__ import annotations

import random
from typing import TYPE_CHECKING

import anyio
import numpy as np

from storyteller.agents.llm_port import LLMError
from storyteller.agents.messages import Event, ParsedEvent, PlannedCharacter, PlanningFailure
from storyteller.orchestrator.planning.state import StepProgress
from storyteller.orchestrator.session.session_types import Outcome, PlanningRequest
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.paths.nav_grid import build_nav_grid
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.step import World

if TYPE_CHECKING:
    import litellm

FPS = 30


def free_points(scene: Scene, n: int, seed: int) -> list[tuple[float, float]]:
    grid = build_nav_grid(scene)
    cells = np.argwhere(grid.free)
    rng = np.random.default_rng(seed)
    out: list[tuple[float, float]] = []
    for k in rng.permutation(len(cells)):
        p = grid.center_of(*cells[k])
        if all(np.hypot(*(p - q)) > 1.2 for q in out):
            out.append((float(p[0]), float(p[1])))
        if len(out) == n:
            return out
    raise AssertionError("not enough free points")


def make_world(scene: Scene, motion: MotionMatcher, names: list[str]) -> World:
    starts = free_points(scene, len(names), seed=1)
    return World(scene, {n: (p, 0.0) for n, p in zip(names, starts, strict=True)}, motion)


class ScriptedPlanner:
    """Gives every free character a short standing action at a free spot, deterministically
    from the request; optionally takes a random (wall-clock) time to answer."""

    def __init__(self, scene: Scene, delays: bool = False, fail_at: int | None = None) -> None:
        self.spots = free_points(scene, 12, seed=7)
        self.delays = random.Random(5) if delays else None
        self.fail_at = fail_at
        self.requests: list[PlanningRequest] = []

    async def plan(self, request: PlanningRequest, progress: StepProgress | None = None) -> Outcome:
        self.requests.append(request)
        if self.delays is not None:
            await anyio.sleep(self.delays.uniform(0.0, 0.02))
        if self.fail_at is not None and request.index == self.fail_at:
            raise LLMError("provider unreachable")
        free = [c.name for c in request.roster if not c.busy]
        if request.index % 4 == 3:
            return None  # the narrator waits
        if request.index % 5 == 4:
            return PlanningFailure(index=request.index, node="event_parser", attempts=4, feedback="gave up")
        who = free[: 2 if len(free) > 1 and request.index % 2 else 1]
        plans = []
        for k, name in enumerate(who):
            x, y = self.spots[(request.index * 3 + k) % len(self.spots)]
            plans.append(PlannedCharacter(character=name, action="use_smartphone" if k == 0 else "drink",
                                          area="near a free spot", position=(x, y), facing=(1.0, 0.0)))
        return ParsedEvent(index=request.index, event=Event(characters=tuple(who), activity="take a break"),
                           plans=tuple(plans))


class ScriptedCompletion:
    """A fake ``litellm.acompletion`` for the whole graph on the home scene: the node is told
    by the request (describer / narrator schema, no schema for the parser). The first parser
    reply has no code, so step 0 needs a parser retry."""

    def __init__(self) -> None:
        self.parser_calls = 0

    async def __call__(self, *, model: str, messages: list[dict[str, str]], **kw: object) -> litellm.ModelResponse:
        import json
        import re

        import litellm

        fmt = kw.get("response_format")
        schema = fmt.get("schema") if isinstance(fmt, dict) else None
        if schema is not None and "areas" in schema["properties"]:
            names = schema["properties"]["areas"]["items"]["properties"]["objects"]["items"]["enum"]
            text = json.dumps({"areas": [{"name": "home", "purpose": "live", "objects": names}]})
        elif schema is not None:
            free = schema["properties"]["event"]["properties"]["characters"]["items"]["enum"]
            text = json.dumps({"reasoning": "next", "event": {"characters": free[:1], "activity": "read near bookshelf_1"}})
        else:
            self.parser_calls += 1
            named = re.search(r'Event: characters \["(\w+)"', messages[1]["content"])
            assert named is not None, "the parser's prompt names the event's characters"
            who = named.group(1)
            text = "I would let them read." if self.parser_calls == 1 else (
                f'```python\ndef parse_event():\n    c = get_character("{who}")\n'
                '    c.set_position(get_area_close_to("bookshelf_1"))\n    c.set_target_action("read_book")\n```'
            )
        return litellm.ModelResponse(
            choices=[{"index": 0, "finish_reason": "stop", "message": {"role": "assistant", "content": text}}],
            usage={"prompt_tokens": 10, "completion_tokens": 5, "total_tokens": 15},
        )

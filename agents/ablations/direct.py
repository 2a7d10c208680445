"""Ablation "Direct Inference": the event parser answers coordinates instead of areas.

The narrator picks the event as usual; the parser (node ``event_parser``) answers JSON
(names restricted by enums) with a floor point per character. The points run through the same
sandboxed program path (``set_position([x, y])``, :func:`direct_program`). A point on a seat's
footprint means "sit on that seat" (the only way coordinates can ask for sitting); a point
inside other furniture, off the free floor, or closer than ``MIN_SEPARATION`` to another
character is rejected with :class:`storyteller.tools.errors.BlockedPositionError` (the spatial API's own,
so whoever catches one catches both) and fed back like any other typed error.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from storyteller.agents.event_parser import ParserInput, ProgramResult, ProgramRunner, run_reply
from storyteller.agents.llm_port import ChatMessage, LLMRequest
from storyteller.agents.llm_schemas import Refine, reply_schema
from storyteller.agents.messages import CharacterStatus, Event
from storyteller.agents.prompt_templates import PromptLibrary, package_prompts
from storyteller.agents.retry_feedback import Turn, retry_temperature, with_turns
from storyteller.sim.scene.model import Scene
from storyteller.tools.character_states import WorldView
from storyteller.tools.errors import BlockedPositionError
from storyteller.tools.position_sampling import MIN_SEPARATION, FloorMap
from storyteller.tools.scene_graph import SceneGraph
from storyteller.tools.scene_text import object_list_text


class DirectPlan(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    character: str
    action: str
    x: float = Field(description="Floor x in metres.")
    y: float = Field(description="Floor y in metres.")
    look_at: str = ""


class DirectPlans(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    plans: tuple[DirectPlan, ...]


def direct_schema(characters: Sequence[str], labels: Sequence[str], targets: Sequence[str]) -> dict[str, Any]:
    """The reply schema of one Direct Inference call, generated from :class:`DirectPlans`:
    exactly one plan per event character, names, labels and look-at targets from the call."""
    n = len(characters)
    return reply_schema(
        DirectPlans,
        {
            "plans": Refine(min_items=n, max_items=n),
            "plans.character": Refine(enum=list(characters)),
            "plans.action": Refine(enum=list(labels)),
            "plans.look_at": Refine(enum=list(targets)),
        },
    )


def seat_at(scene: Scene, x: float, y: float) -> str | None:
    """The seat whose footprint holds (x, y), if exactly one does."""
    seats = [o.name for o in scene.objects if o.is_seat and bool(o.contains_xy(np.array([x, y])))]
    return seats[0] if len(seats) == 1 else None


def direct_program(plans: DirectPlans, scene: Scene | None = None) -> str:
    """A parse_event() that puts each character at its coordinates (names JSON-quoted).

    With ``scene``, a point on a seat's footprint becomes ``get_area_to_sit_on(seat)``."""
    lines = ["def parse_event():"]
    for i, p in enumerate(plans.plans):
        var = f"c{i}"
        lines.append(f"    {var} = get_character({json.dumps(p.character)})")
        seat = seat_at(scene, p.x, p.y) if scene is not None else None
        if seat is not None:
            lines.append(f"    {var}.set_position(get_area_to_sit_on({json.dumps(seat)}))")
        else:
            lines.append(f"    {var}.set_position([{p.x!r}, {p.y!r}])")
        if p.look_at:
            lines.append(f"    {var}.set_orientation({json.dumps(p.look_at)})")
        lines.append(f"    {var}.set_target_action({json.dumps(p.action)})")
    return "\n".join(lines) + "\n"


def blocked_positions(scene: Scene, world: WorldView, plans: DirectPlans, prompts: PromptLibrary | None = None) -> list[str]:
    """Problems of the standing points of ``plans`` (checked before the program runs, so the
    feedback speaks of coordinates): inside furniture or too near the scene's edge, or closer
    than MIN_SEPARATION to another character (planned earlier in the same event, or anyone
    else's position or target). Points on a seat are seats (see :func:`direct_program`). The
    sentences are ``prompts/feedback/direct/*.md``."""
    lib = prompts or package_prompts()
    floor = FloorMap(scene)
    moving = {p.character for p in plans.plans}
    others: list[tuple[str, tuple[float, float]]] = []
    for c in world.characters:
        if c.name not in moving:
            others += [(c.name, pt) for pt in (c.position, c.target_position) if pt is not None]
    problems: list[str] = []
    for p in plans.plans:
        if seat_at(scene, p.x, p.y) is not None:
            continue
        where = {"character": p.character, "x": f"{p.x:.2f}", "y": f"{p.y:.2f}"}
        inside = floor.colliding_objects((p.x, p.y))
        if inside:
            problems.append(
                lib.render_text(
                    "feedback/direct/inside_furniture.md",
                    **where, objects=", ".join(inside), clearance=f"{floor.body_radius:.2f}",
                )
            )
        elif not bool(floor.free(np.array([[p.x, p.y]]))[0]):
            problems.append(lib.render_text("feedback/direct/off_floor.md", **where))
        for name, q in others:
            d = float(np.hypot(p.x - q[0], p.y - q[1]))
            if d < MIN_SEPARATION:
                problems.append(
                    lib.render_text(
                        "feedback/direct/too_close.md",
                        **where, distance=f"{d:.2f}", other=name, separation=f"{MIN_SEPARATION:.1f}",
                    )
                )
                break
        others.append((p.character, (p.x, p.y)))
    return problems


def _status_line(prompts: PromptLibrary, c: CharacterStatus) -> str:
    """One character with its floor position (the coordinates the model answers in)."""
    line = prompts.render_text("story/character_busy.md" if c.busy else "story/character_free.md", name=c.name, action=c.action)
    if not c.position:
        return line
    return line + prompts.render_text("story/character_at_position.md", x=f"{c.position[0]:.1f}", y=f"{c.position[1]:.1f}")


def direct_max_tokens(event_characters: int) -> int:
    """40 + 50 per event character (one plan is about 35 tokens of JSON)."""
    return 40 + 50 * max(1, event_characters)


def direct_request(
    prompts: PromptLibrary,
    inp: ParserInput,
    scene: Scene,
    *,
    lists_objects: bool,
    turns: tuple[Turn, ...] = (),
    max_tokens: int | None = None,
) -> LLMRequest:
    """The coordinates request for ``inp.event`` (the event parser's input; its grammar is
    not used). Unless the description already ``lists_objects``, the scene's object list is
    appended so the model has coordinates to answer with."""
    description = inp.scene_description.strip()
    if not lists_objects:
        description = prompts.render_text(
            "direct/description_with_objects.md", description=description, objects=object_list_text(scene)
        )
    system = prompts.render("direct/system.md", scene_description=description, action_labels=", ".join(inp.action_labels))
    user = prompts.render(
        "direct/request.md",
        characters="\n".join(_status_line(prompts, c) for c in inp.characters),
        seats_in_use=", ".join(inp.seats_in_use) if inp.seats_in_use else prompts.render_text("story/no_seats_in_use.md"),
        event_characters=", ".join(f'"{n}"' for n in inp.event.characters),
        activity=inp.event.activity.strip(),
    )
    base = (ChatMessage(role="system", content=system), ChatMessage(role="user", content=user))
    targets = [*scene.object_names, *(c.name for c in inp.characters)]
    return LLMRequest(
        node="event_parser",
        messages=with_turns(base, turns),
        json_schema=direct_schema(inp.event.characters, inp.action_labels, targets),
        max_tokens=max_tokens or direct_max_tokens(len(inp.event.characters)),
        seed=inp.seed,
        temperature=retry_temperature(turns),
    )


def check_direct_reply(
    reply: str,
    *,
    scene: Scene,
    event: Event,
    world: WorldView,
    seed: int,
    action_labels: Sequence[str],
    graph: SceneGraph | None = None,
    runner: ProgramRunner | None = None,
) -> ProgramResult:
    """Validate the coordinates, then run them as an event program. Raises the typed errors
    that become feedback (bad JSON, :class:`BlockedPositionError`, a failing program)."""
    start, end = reply.find("{"), reply.rfind("}")
    plans = DirectPlans.model_validate(json.loads(reply[start : end + 1] if 0 <= start < end else reply))
    problems = blocked_positions(scene, world, plans)
    if problems:
        raise BlockedPositionError("; ".join(problems))
    program = direct_program(plans, scene)
    result = run_reply(
        f"```python\n{program}```",
        scene=scene,
        event=event,
        world=world,
        seed=seed,
        action_labels=action_labels,
        graph=graph,
        runner=runner,
    )
    return ProgramResult(program=program, plans=result.plans)

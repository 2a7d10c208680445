"""The paper's planner and its ablations behind one interface, :class:`Planner`.

- :class:`EventDrivenPlanner`: the full method (narrator, then event parser).
- :class:`UnifiedPlanner` ("w/o Event"): one LLM call (node ``planner``) writes a
  ``parse_event()`` for the free characters straight from the instruction and the story,
  without an explicit event; the event is read back from the program's plans.
- :class:`DirectInferencePlanner` ("Direct Inference"): narrator as usual, but the parser
  (node ``event_parser``) answers coordinates (JSON, names restricted by enums) instead of
  areas; the coordinates are run through the same sandboxed program path
  (``set_position([x, y])``). A point on a seat's footprint means "sit on that seat" (the
  only way coordinates can ask for sitting); a point inside other furniture, or closer than
  ``MIN_SEPARATION`` to another character, is rejected with :class:`BlockedPositionError`
  and fed back like any other typed error.
- Description ablations: :func:`object_list_description` and :func:`scene_graph_description`
  replace the describer's text.

Every planner returns a :class:`StepOutcome` for one planning step: an event with plans, a
wait (``None``) or a :class:`~agents.messages.PlanningFailure`.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from agents.event_parser import (
    ParserInput,
    ProgramRunner,
    check_plans,
    default_runner,
    extract_program,
    parse_event,
    run_reply,
)
from agents.llm_port import ChatMessage, LLMPort, LLMRequest
from agents.messages import (
    CharacterStatus,
    Event,
    HistoryEntry,
    ParsedEvent,
    PlanningFailure,
    SceneDescription,
)
from agents.narrator import (
    NarratorInput,
    characters_text,
    history_text,
    narrate,
    narrator_request,
    parse_narration,
)
from agents.program_grammar import event_program_grammar
from agents.prompt_templates import BENCHMARK_TAGS, PromptLibrary
from agents.retry_feedback import (
    REJECTIONS,
    AnswerRejectedError,
    RetriesExhaustedError,
    Turn,
    ask_until_valid,
    feedback_from_error,
    retry_temperature,
    with_turns,
)
from sim.scene.model import Scene
from tools.errors import ToolError
from tools.position_sampling import MIN_SEPARATION, FloorMap
from tools.scene_graph import SceneGraph, build_scene_graph
from tools.scene_text import object_list_text, scene_graph_json

StepOutcome = ParsedEvent | PlanningFailure | None

JudgeHook = Callable[[str, Any, BaseException | None, str | None], None]
"""``hook(node, parsed_output, error, feedback)``, called once per reply right after it was
judged (before the next LLM call): the parsed output as JSON data (None when rejected), or the
typed error and the feedback it produced. Used to trace what each attempt parsed to."""


def judging(parse: Callable[[str], Any], node: str, hook: JudgeHook | None, dump: Callable[[Any], Any]) -> Callable[[str], Any]:
    """``parse`` that reports each verdict to ``hook`` (``dump`` turns a value into JSON data)."""
    if hook is None:
        return parse

    def judged(reply: str) -> Any:
        try:
            value = parse(reply)
        except REJECTIONS as exc:
            hook(node, None, exc, feedback_from_error(exc))
            raise
        hook(node, dump(value), None, None)
        return value

    return judged


def _dump_parsed(value: ParsedEvent | None) -> Any:
    if value is None:
        return {"wait": True}
    return {"plans": [p.model_dump(mode="json") for p in value.plans], "program": value.program}


def object_list_description(scene: Scene) -> SceneDescription:
    """Ablation: a plain object list (names, positions, sizes) instead of the describer's text."""
    return SceneDescription(scene=scene.name, text=object_list_text(scene), source="object_list")


def scene_graph_description(scene: Scene, graph: SceneGraph | None = None) -> SceneDescription:
    """Ablation: the raw scene graph JSON instead of the describer's text."""
    text = scene_graph_json(graph or build_scene_graph(scene))
    return SceneDescription(scene=scene.name, text=text, source="scene_graph")


@dataclass(frozen=True)
class PlanningStep:
    """Everything one planning step depends on."""

    index: int
    scene: Scene
    description: SceneDescription
    characters: Sequence[CharacterStatus]
    instruction: str
    world: Any
    action_labels: Sequence[str]
    history: Sequence[HistoryEntry] = ()
    seats_in_use: Sequence[str] = ()
    tags: tuple[str, ...] = BENCHMARK_TAGS
    seed: int = 0
    graph: SceneGraph | None = None
    runner: ProgramRunner | None = None
    program_grammar: bool = False
    """Decode the event parser's program under agents.program_grammar (local models)."""


class Planner(Protocol):
    async def plan(self, step: PlanningStep) -> StepOutcome: ...


def _failure(step: PlanningStep, exc: RetriesExhaustedError) -> PlanningFailure:
    node = exc.node if exc.node in ("describer", "narrator", "event_parser", "planner") else "planner"
    return PlanningFailure(index=step.index, node=node, attempts=exc.attempts, feedback=exc.feedback)  # type: ignore[arg-type]


def _narrator_input(step: PlanningStep) -> NarratorInput:
    return NarratorInput(
        scene_description=step.description.text,
        characters=step.characters,
        instruction=step.instruction,
        history=step.history,
        tags=step.tags,
        seed=step.seed,
    )


def step_program_grammar(step: PlanningStep, event: Event) -> str:
    """The program grammar of ``event`` in ``step``'s scene: free seats, offered labels."""
    return event_program_grammar(step.scene, event.characters, step.characters, step.seats_in_use, step.action_labels)


def _parser_input(step: PlanningStep, event: Event, description: str | None = None) -> ParserInput:
    return ParserInput(
        grammar=step_program_grammar(step, event) if step.program_grammar else None,
        scene_description=description if description is not None else step.description.text,
        event=event,
        characters=step.characters,
        action_labels=step.action_labels,
        tags=step.tags,
        seats_in_use=step.seats_in_use,
        seed=step.seed,
    )


@dataclass
class EventDrivenPlanner:
    """The full method: narrator picks an event, the event parser places its characters."""

    port: LLMPort
    prompts: PromptLibrary
    max_retries: int = 3

    async def plan(self, step: PlanningStep) -> StepOutcome:
        try:
            narrated = await narrate(self.port, self.prompts, _narrator_input(step), max_retries=self.max_retries)
            event = narrated.value.event
            if event.is_wait:
                return None
            parsed = await parse_event(
                self.port,
                self.prompts,
                _parser_input(step, event),
                scene=step.scene,
                world=step.world,
                seed=step.seed + step.index,
                graph=step.graph,
                runner=step.runner,
                max_retries=self.max_retries,
            )
        except RetriesExhaustedError as exc:
            return _failure(step, exc)
        return ParsedEvent(
            index=step.index,
            event=event,
            plans=parsed.value.plans,
            program=parsed.value.program,
            narrator_attempts=narrated.attempts,
            parser_attempts=parsed.attempts,
        )


@dataclass
class UnifiedPlanner:
    """Ablation "w/o Event": one call plans the free characters directly."""

    port: LLMPort
    prompts: PromptLibrary
    max_retries: int = 3
    max_tokens: int | None = None
    """None: 80 + 110 per free character, at most 400 (as the event parser's budget; a small
    model that is given more tends to repeat lines until the cap)."""
    judged: JudgeHook | None = None

    def request(self, step: PlanningStep, turns: tuple[Turn, ...] = ()) -> LLMRequest:
        free = [c.name for c in step.characters if not c.busy]
        system = self.prompts.render(
            "planner/system.md",
            scene_description=step.description.text.strip(),
            action_labels=", ".join(step.action_labels),
        )
        user = self.prompts.render(
            "planner/request.md",
            characters=characters_text(step.characters),
            free=", ".join(free) if free else "(none)",
            seats_in_use=", ".join(step.seats_in_use) if step.seats_in_use else "none",
            history=history_text(step.history),
            instruction=step.instruction.strip() or "(none: continue the story naturally)",
        )
        base = (ChatMessage(role="system", content=system), ChatMessage(role="user", content=user))
        return LLMRequest(
            node="planner",
            messages=with_turns(base, turns),
            max_tokens=self.max_tokens or min(400, 80 + 110 * max(1, len(free))),
            seed=step.seed,
            temperature=retry_temperature(turns),
        )

    def check(self, step: PlanningStep, reply: str) -> ParsedEvent | None:
        """Run the reply; a program that plans nobody (``pass``) is a wait."""
        program = extract_program(reply)
        body = [ln.strip() for ln in program.splitlines()[1:] if ln.strip() and not ln.strip().startswith("#")]
        if body == ["pass"]:
            return None
        busy = {c.name for c in step.characters if c.busy}
        free = [c.name for c in step.characters if not c.busy]
        runner = step.runner or default_runner()
        plans = runner(
            step.scene, program, step.world, seed=step.seed + step.index, action_labels=list(step.action_labels), graph=step.graph
        )
        if not plans:  # a program that touches nobody plans nothing: a wait
            return None
        names = tuple(dict.fromkeys(str(p.character) for p in plans))
        bad = [n for n in names if n in busy]
        if bad:
            raise AnswerRejectedError(
                [f"{n} is busy and cannot be planned" for n in bad] + [f"free characters are: {', '.join(free)}"]
            )
        event = Event(
            characters=names,
            activity="; ".join(f"{p.character}: {p.action} ({p.area})" for p in plans)[:320],
        )
        return ParsedEvent(index=step.index, event=event, plans=check_plans(event, plans), program=program)

    async def plan(self, step: PlanningStep) -> StepOutcome:
        if not any(not c.busy for c in step.characters):
            return None
        try:
            accepted = await ask_until_valid(
                self.port,
                lambda turns: self.request(step, turns),
                judging(lambda reply: self.check(step, reply), "planner", self.judged, _dump_parsed),
                max_attempts=self.max_retries + 1,
                node="planner",
            )
        except RetriesExhaustedError as exc:
            return _failure(step, exc)
        if accepted.value is None:
            return None
        return accepted.value.model_copy(update={"narrator_attempts": 0, "parser_attempts": accepted.attempts})


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
    n = len(characters)
    return {
        "type": "object",
        "properties": {
            "plans": {
                "type": "array",
                "minItems": n,
                "maxItems": n,
                "items": {
                    "type": "object",
                    "properties": {
                        "character": {"type": "string", "enum": list(characters)},
                        "action": {"type": "string", "enum": list(labels)},
                        "x": {"type": "number"},
                        "y": {"type": "number"},
                        "look_at": {"type": "string", "enum": list(targets)},
                    },
                    "required": ["character", "action", "x", "y", "look_at"],
                    "additionalProperties": False,
                },
            }
        },
        "required": ["plans"],
        "additionalProperties": False,
    }


class BlockedPositionError(ToolError):
    """A direct coordinate that no character can stand on (inside furniture, off the floor,
    or on top of another character)."""

    kind = "blocked_position"


def seat_at(scene: Scene, x: float, y: float) -> str | None:
    """The seat whose footprint holds (x, y), if exactly one does."""
    seats = [o.name for o in scene.objects if o.is_seat and bool(o.contains_xy([x, y]))]
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


def blocked_positions(scene: Scene, world: Any, plans: DirectPlans) -> list[str]:
    """Problems of the standing points of ``plans`` (checked before the program runs, so the
    feedback speaks of coordinates): inside furniture or too near the scene's edge, or closer
    than MIN_SEPARATION to another character (planned earlier in the same event, or anyone
    else's position or target). Points on a seat are seats (see :func:`direct_program`)."""
    floor = FloorMap(scene)
    moving = {p.character for p in plans.plans}
    others: list[tuple[str, tuple[float, float]]] = []
    for c in getattr(world, "characters", ()):
        if c.name not in moving:
            others += [(c.name, pt) for pt in (c.position, c.target_position) if pt is not None]
    problems: list[str] = []
    for p in plans.plans:
        if seat_at(scene, p.x, p.y) is not None:
            continue
        where = f"{p.character} at [{p.x:.2f}, {p.y:.2f}]"
        inside = floor.colliding_objects((p.x, p.y))
        if inside:
            problems.append(
                f"{where} is inside {', '.join(inside)} (stand on free floor at least "
                f"{floor.body_radius:.2f} m from furniture)"
            )
        elif not bool(floor.free([[p.x, p.y]])[0]):
            problems.append(f"{where} is off the free floor (too close to the edge of the scene)")
        for name, q in others:
            d = float(np.hypot(p.x - q[0], p.y - q[1]))
            if d < MIN_SEPARATION:
                problems.append(f"{where} is {d:.2f} m from {name} (keep {MIN_SEPARATION:.1f} m apart)")
                break
        others.append((p.character, (p.x, p.y)))
    return problems


@dataclass
class DirectInferencePlanner:
    """Ablation "Direct Inference": the parser outputs coordinates instead of areas."""

    port: LLMPort
    prompts: PromptLibrary
    max_retries: int = 3
    max_tokens: int | None = None
    """None: 40 + 50 per event character (one plan is about 35 tokens of JSON)."""
    judged: JudgeHook | None = None

    def request(self, step: PlanningStep, event: Event, turns: tuple[Turn, ...] = ()) -> LLMRequest:
        description = step.description.text.strip()
        if step.description.source != "object_list":
            description += "\n\nObjects:\n" + object_list_text(step.scene)
        system = self.prompts.render(
            "direct/system.md", scene_description=description, action_labels=", ".join(step.action_labels)
        )
        user = self.prompts.render(
            "direct/request.md",
            characters="\n".join(
                f"- {c.name}: {'busy' if c.busy else 'free'}, {c.action}"
                + (f", at [{c.position[0]:.1f}, {c.position[1]:.1f}]" if c.position else "")
                for c in step.characters
            ),
            seats_in_use=", ".join(step.seats_in_use) if step.seats_in_use else "none",
            event_characters=", ".join(f'"{n}"' for n in event.characters),
            activity=event.activity.strip(),
        )
        base = (ChatMessage(role="system", content=system), ChatMessage(role="user", content=user))
        targets = [*step.scene.object_names, *(c.name for c in step.characters)]
        return LLMRequest(
            node="event_parser",
            messages=with_turns(base, turns),
            json_schema=direct_schema(event.characters, step.action_labels, targets),
            max_tokens=self.max_tokens or 40 + 50 * max(1, len(event.characters)),
            seed=step.seed,
            temperature=retry_temperature(turns),
        )

    def check(self, step: PlanningStep, event: Event, reply: str) -> tuple[str, ParsedEvent]:
        start, end = reply.find("{"), reply.rfind("}")
        plans = DirectPlans.model_validate(json.loads(reply[start : end + 1] if 0 <= start < end else reply))
        problems = blocked_positions(step.scene, step.world, plans)
        if problems:
            raise BlockedPositionError("; ".join(problems))
        program = direct_program(plans, step.scene)
        result = run_reply(
            f"```python\n{program}```",
            scene=step.scene,
            event=event,
            world=step.world,
            seed=step.seed + step.index,
            action_labels=step.action_labels,
            graph=step.graph,
            runner=step.runner,
        )
        return program, ParsedEvent(index=step.index, event=event, plans=result.plans, program=program)

    async def plan(self, step: PlanningStep) -> StepOutcome:
        inp = _narrator_input(step)
        if not inp.free:
            return None
        try:
            # as agents.narrator.narrate (the same requests), with each verdict reported
            narrated = await ask_until_valid(
                self.port,
                lambda turns: narrator_request(self.prompts, inp, turns),
                judging(lambda text: parse_narration(text, inp.characters), "narrator", self.judged,
                        lambda out: out.model_dump(mode="json")),
                max_attempts=self.max_retries + 1,
                node="narrator",
            )
            event = narrated.value.event
            if event.is_wait:
                return None
            accepted = await ask_until_valid(
                self.port,
                lambda turns: self.request(step, event, turns),
                judging(lambda reply: self.check(step, event, reply), "event_parser", self.judged,
                        lambda value: _dump_parsed(value[1])),
                max_attempts=self.max_retries + 1,
                node="event_parser",
            )
        except RetriesExhaustedError as exc:
            return _failure(step, exc)
        _, parsed = accepted.value
        return parsed.model_copy(update={"narrator_attempts": narrated.attempts, "parser_attempts": accepted.attempts})

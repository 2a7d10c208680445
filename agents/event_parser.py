"""The event parser: turns an event into a ``parse_event()`` program and runs it.

One call = one request from :func:`parser_request`. The reply's code is found by
:func:`extract_program` (a fenced block, or bare code, or even a bare function body), run
in the sandbox through ``storyteller.tools.event_program.run_event_program``, and the result is checked:
every character of the event, and no other, gets a plan. Any failure (no code, a typed
``EventProgramError`` from the sandbox or the spatial API, a missing character) becomes
feedback for the next attempt.

Prompt layout (stable first): system = role, API, rules, examples, scene description,
action labels; user = the characters' states and the event.
"""

from __future__ import annotations

import re
import textwrap
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from storyteller.agents.action_shortlist import suggested_action
from storyteller.agents.llm_port import ChatMessage, LLMPort, LLMRequest
from storyteller.agents.messages import CharacterStatus, Event, PlannedCharacter, ToolPlan
from storyteller.agents.place_phrases import plain_places
from storyteller.agents.prompt_templates import BENCHMARK_TAGS, PromptLibrary, package_prompts
from storyteller.agents.retry_feedback import (
    Accepted,
    AnswerRejectedError,
    NoCodeError,
    Turn,
    ask_until_valid,
    retry_temperature,
    with_turns,
)
from storyteller.sim.motion.action_labels import ACTION_LABELS, ACTION_SPECS, playable_seated
from storyteller.sim.scene.model import Scene
from storyteller.tools.character_states import WorldView
from storyteller.tools.scene_graph import SceneGraph
from storyteller.tools.spatial_api import SpatialAPI, handle_methods

PARSER_RETRY_INSTRUCTION = "feedback/code_again.md"
"""Prompt file of the instruction after a rejected program."""
PARSER_FILES = ("event_parser/system.md", "event_parser/request.md")
DEFAULT_MAX_TOKENS = 400
MAX_PROGRAM_CHARS = 6000


class ProgramRunner(Protocol):
    """``tools.event_program.run_event_program``'s signature."""

    def __call__(
        self,
        scene: Scene,
        source: str,
        world: WorldView,
        *,
        seed: int,
        action_labels: Sequence[str] | None = None,
        graph: SceneGraph | None = None,
    ) -> Sequence[ToolPlan]: ...


def default_runner() -> ProgramRunner:
    from storyteller.tools.event_program import run_event_program

    return run_event_program


@dataclass(frozen=True)
class ParserInput:
    """Everything one event-parser call depends on."""

    scene_description: str
    event: Event
    characters: Sequence[CharacterStatus]
    action_labels: Sequence[str]
    tags: tuple[str, ...] = BENCHMARK_TAGS
    seats_in_use: Sequence[str] = ()
    seed: int | None = None
    sim_frame: int | None = None
    grammar: str | None = None
    """GBNF grammar of the reply (see storyteller.agents.program_grammar); None: free text."""
    instruction_part: str = ""
    """The part of the user's instruction the event carries out ("" when none): its own words,
    which the narrator's activity may have lost ("the laptop" in "takes the seat from which
    the laptop can be reached")."""
    seat: str | None = None
    """The seat chosen for the event before its program (``storyteller.agents.place_choice``), named in the
    request; None: no seat was chosen."""
    action: str | None = None
    """The action chosen for the event before its program when its words name none
    (``storyteller.agents.action_choice``): the suggested label; None: the label ranker's suggestion."""
    max_tokens: int | None = None
    """None: 80 + 110 per event character (capped at DEFAULT_MAX_TOKENS), enough for the
    function; a small model otherwise goes on writing more examples."""


MOTION_ONLY_LABELS = frozenset({"walk", "sit_down", "sit_idle", "stand_up"})
OBJECT_GESTURES = frozenset({"reach", "reach_low", "write", "wipe"})


def scene_action_labels(scene: Scene, labels: Sequence[str] | None = None) -> tuple[str, ...]:
    """Action labels worth offering in ``scene`` (a short list keeps small-model prompts short).

    Drops labels the simulation uses by itself (walk, sit down...) and object-operating labels
    (gesture reach / write / wipe) whose name mentions no object label of the scene, e.g.
    ``use_toaster`` in a scene without a toaster.
    """
    scene_labels = set(scene.labels)
    out = []
    for label in labels if labels is not None else ACTION_LABELS:
        if label in MOTION_ONLY_LABELS:
            continue
        spec = ACTION_SPECS.get(label)
        if spec is not None and spec.gesture in OBJECT_GESTURES and not any(o in label for o in scene_labels):
            continue
        out.append(label)
    return tuple(out)


def _status_line(prompts: PromptLibrary, c: CharacterStatus) -> str:
    """One character for the parser: no coordinates (a small model copies them into
    set_position instead of choosing an area)."""
    line = prompts.render_text("story/character_busy.md" if c.busy else "story/character_free.md", name=c.name, action=c.action)
    return line + prompts.render_text("story/character_sitting_on.md", seat=c.seat) if c.seat else line


_WORD = re.compile(r"[a-z]+")


AREA_KINDS = ("area", "seat_area", "area_operation")


def spatial_api_listing(prompts: PromptLibrary | None = None) -> dict[str, str]:
    """The system prompt's function list, rendered from ``storyteller.tools.spatial_api`` (the listed
    functions and the character handle's methods), so the prompt names only what exists."""
    lib = prompts or package_prompts()
    listed = [f for f in SpatialAPI.functions() if f.listed]
    characters = [f for f in listed if f.kind == "character"]
    return {
        "get_character": ", ".join(f.call for f in characters),
        "character_methods": "\n".join(
            lib.render_text("event_parser/api_method.md", call=m.call, summary=m.summary) for m in handle_methods()
        ),
        "area_functions": ", ".join(f.call for f in listed if f.kind in AREA_KINDS),
        "query_functions": ", ".join(f.signature for f in listed if f.kind == "query"),
    }


def event_text(activity: str, instruction_part: str = "") -> str:
    """What the event is about, for the label and object shortlists: the instruction part it
    carries out when there is one (the user's own words; a small narrator adds places of its
    own, "... sitting on chair_1"), else the narrator's activity; the sides of things written
    the one way the readers know (:func:`storyteller.agents.place_phrases.plain_places`: "on the bench's
    right-hand side" is "to the right of the bench")."""
    return plain_places(instruction_part.strip() or activity.strip())


def parser_messages(prompts: PromptLibrary, inp: ParserInput) -> tuple[ChatMessage, ...]:
    system = prompts.render(
        "event_parser/system.md",
        **spatial_api_listing(prompts),
        examples=prompts.examples("event_parser", inp.tags),
        scene_description=inp.scene_description.strip(),
        action_labels=", ".join(inp.action_labels),
    )
    user = prompts.render(
        "event_parser/request.md",
        characters="\n".join(_status_line(prompts, c) for c in inp.characters),
        seats_in_use=", ".join(inp.seats_in_use) if inp.seats_in_use else prompts.render_text("story/no_seats_in_use.md"),
        event_characters=", ".join(f'"{n}"' for n in inp.event.characters),
        activity=inp.event.activity.strip(),
        instruction_part="\n" + prompts.render_text("event_parser/instruction_part.md", part=inp.instruction_part.strip())
        if inp.instruction_part.strip() else "",
        chosen_seat="\n" + prompts.render_text("event_parser/chosen_seat.md", seat=inp.seat) if inp.seat else "",
        likely_action=inp.action or suggested_action(
            event_text(inp.event.activity, inp.instruction_part), inp.action_labels,
            context=inp.event.activity if inp.instruction_part.strip() else "",
        ),
    )
    return (ChatMessage(role="system", content=system), ChatMessage(role="user", content=user))


def parser_request(prompts: PromptLibrary, inp: ParserInput, turns: tuple[Turn, ...] = ()) -> LLMRequest:
    return LLMRequest(
        node="event_parser",
        messages=with_turns(parser_messages(prompts, inp), turns),
        json_schema=None,
        max_tokens=inp.max_tokens or min(DEFAULT_MAX_TOKENS, 80 + 110 * max(1, len(inp.event.characters))),
        seed=inp.seed,
        sim_frame=inp.sim_frame,
        temperature=retry_temperature(turns),
        grammar=inp.grammar,
    )


_FENCE_TAG = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_+-")
_DEF = re.compile(r"^def[ \t]+parse_event[ \t]*\(", re.MULTILINE)


def _skip(text: str, i: int, chars: frozenset[str] | str) -> int:
    """The first index at or after ``i`` whose character is not in ``chars``."""
    while i < len(text) and text[i] in chars:
        i += 1
    return i


def fenced_blocks(text: str) -> list[str]:
    r"""The bodies of the fenced code blocks of ``text``: a line opening with three backticks,
    optional spaces, an optional language tag and optional spaces; the body runs to the next
    three backticks or, unclosed, to the end. One scan (a regular expression with adjacent
    ``[ \t]*`` runs took 50 s on a fence and 150,000 spaces); the blocks are those of
    ``r"```[ \t]*([A-Za-z0-9_+-]*)[ \t]*\n(.*?)(?:```|\Z)"`` with ``re.DOTALL``."""
    blocks: list[str] = []
    pos = 0
    while (start := text.find("```", pos)) >= 0:
        end_of_header = _skip(text, _skip(text, _skip(text, start + 3, " \t"), _FENCE_TAG), " \t")
        if end_of_header >= len(text) or text[end_of_header] != "\n":
            pos = start + 1  # not an opening fence here: look further (as the pattern's search did)
            continue
        body = end_of_header + 1
        close = text.find("```", body)
        if close < 0:
            blocks.append(text[body:])
            break
        blocks.append(text[body:close])
        pos = close + 3
    return blocks


def _function_at(code: str, start: int) -> str:
    """The ``def parse_event`` starting at ``start``: its line plus indented or blank lines."""
    lines = code[start:].splitlines()
    kept = [lines[0]]
    for line in lines[1:]:
        if line.strip() and not line[0].isspace():
            break
        kept.append(line)
    return "\n".join(kept).rstrip() + "\n"


def extract_program(reply: str, prompts: PromptLibrary | None = None) -> str:
    """The ``parse_event()`` source in a reply; raises NoCodeError when there is none.

    Looks in fenced blocks first (any language tag; an unclosed fence runs to the end), then
    in the bare reply. A block of statements without ``def parse_event`` is wrapped into one.
    Top-level lines after the function (e.g. a ``parse_event()`` call) are dropped. The
    errors' texts are ``prompts/feedback/no_code.md`` and ``program_too_long.md``.
    """
    lib = prompts or package_prompts()
    text = reply.replace("\r\n", "\n").replace("\t", "    ")
    blocks = fenced_blocks(text)
    for candidate in (*blocks, text):
        match = _DEF.search(candidate)
        if match:
            program = _function_at(candidate, match.start())
            if len(program) > MAX_PROGRAM_CHARS:
                raise NoCodeError(lib.render_text("feedback/program_too_long.md", limit=MAX_PROGRAM_CHARS))
            return program
    for candidate in (*blocks, text):
        body = textwrap.dedent(candidate).strip("\n")
        if "get_character(" in body and len(body) <= MAX_PROGRAM_CHARS:
            return "def parse_event():\n" + textwrap.indent(body, "    ") + "\n"
    raise NoCodeError(lib.render_text("feedback/no_code.md"))


def check_plans(
    event: Event, plans: Sequence[ToolPlan], prompts: PromptLibrary | None = None
) -> tuple[PlannedCharacter, ...]:
    """Copy the program's plans; every event character, and no other, must have one (the
    problems are ``prompts/feedback/event_parser/*.md``)."""
    lib = prompts or package_prompts()
    out = tuple(PlannedCharacter.from_tool_plan(p) for p in plans)
    got = [p.character for p in out]
    problems = []
    missing = [n for n in event.characters if n not in got]
    extra = [n for n in got if n not in event.characters]
    if missing:
        problems.append(lib.render_text("feedback/event_parser/no_position.md", missing=", ".join(missing)))
    if extra:
        problems.append(
            lib.render_text(
                "feedback/event_parser/not_in_event.md", extra=", ".join(extra), characters=", ".join(event.characters)
            )
        )
    for p in out:  # the motion library must be able to play the action in that posture
        if p.seat is not None and p.action in ACTION_SPECS and not playable_seated(p.action):
            problems.append(
                lib.render_text("feedback/event_parser/cannot_act_seated.md", character=p.character, action=p.action, seat=p.seat)
            )
    if problems:
        raise AnswerRejectedError(problems)
    return out



@dataclass(frozen=True)
class ProgramResult:
    program: str
    plans: tuple[PlannedCharacter, ...]


def run_reply(
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
    """Extract, run and check one reply. Raises the errors that become feedback."""
    program = extract_program(reply)
    run = runner or default_runner()
    plans = run(scene, program, world, seed=seed, action_labels=list(action_labels), graph=graph)
    return ProgramResult(program=program, plans=check_plans(event, plans))


async def parse_event(
    port: LLMPort,
    prompts: PromptLibrary,
    inp: ParserInput,
    *,
    scene: Scene,
    world: WorldView,
    seed: int,
    graph: SceneGraph | None = None,
    runner: ProgramRunner | None = None,
    max_retries: int = 3,
) -> Accepted[ProgramResult]:
    """Plan every character of ``inp.event``: a first try plus at most ``max_retries`` retries."""
    check: Callable[[str], ProgramResult] = lambda reply: run_reply(  # noqa: E731
        reply,
        scene=scene,
        event=inp.event,
        world=world,
        seed=seed,
        action_labels=inp.action_labels,
        graph=graph,
        runner=runner,
    )
    return await ask_until_valid(
        port,
        lambda turns: parser_request(prompts, inp, turns),
        check,
        max_attempts=max_retries + 1,
        node="event_parser",
        instruction=PARSER_RETRY_INSTRUCTION,
        prompts=prompts,
    )

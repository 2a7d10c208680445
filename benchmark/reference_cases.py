"""The reference benchmark's test cases as typed data, and what a planner is given for one.

A case (``benchmark/test_cases/<tags>/testcase_<id>.json`` in the reference data) holds a
scene name, the action labels allowed, a user instruction, a planning history (events with
states ongoing / looping / completed), the current state of every character, and the expected
plans: per character an action expression, a relationship expression (``||``, ``&&``, ``!``,
parentheses over atoms like ``sit on chair_3``) or, for position-inference (PI) cases, a
``sampled_position`` expression. ``allow_null_plan`` says whether waiting is acceptable.

A case set is the reference data's root or any folder in the same ``<tags>/testcase_<id>.json``
layout (our own cases: ``benchmark/cases/ours``), or one ``<tags>`` folder of either. A ``scene_name`` is a folder of the
reference data's ``configs/scenes`` (``House``), or ``bundled:<name>`` for a scene shipped
with the package (``bundled:home``; see :func:`scene_dir`).

:func:`planning_inputs` turns a case into the planner's inputs: the roster
(:class:`~storyteller.agents.messages.CharacterStatus`, positions placed by the project's own sampler,
deterministic per case), the narrator's history and the spatial API's world view.

A case file is outside text: it is read within ``MAX_CASE_BYTES`` and ``MAX_CASE_JSON_DEPTH``
(``storyteller.sim.bounded_files``: a regular file, UTF-8, finite numbers, integers of bounded length), and
a case set's files must be named ``testcase_<id>.json`` with a numeric id; anything else is one
:class:`BenchmarkCaseError` naming the file.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from storyteller.agents.messages import CharacterStatus, HistoryEntry
from storyteller.agents.prompt_templates import BENCHMARK_TAGS
from storyteller.sim.bounded_files import BoundedFileError, load_bounded_json, read_bounded_bytes
from storyteller.sim.scene.bundled import bundled_scene_names
from storyteller.sim.scene.model import Scene
from storyteller.sim.validation_text import user_error
from storyteller.tools.character_states import ReferenceCaseError, WorldView, world_view_from_reference_case

TAGS: tuple[str, ...] = ("OA", "RC", "SS", "PI")
"""Object affordance, relationship comprehension, scene-state awareness, position inference."""


MAX_CASE_BYTES = 4 * 1024 * 1024
"""Bytes of one case file (the reference cases take 2-10 KB)."""
MAX_CASE_JSON_DEPTH = 32
"""Nesting of a case file (the format needs 5)."""
_CASE_NAME = re.compile(r"testcase_([0-9]{1,9})")


class BenchmarkCaseError(ValueError):
    """A test-case file that cannot be read: names the file and the field."""


class _Case(BaseModel):
    model_config = ConfigDict(frozen=True, extra="ignore")


class CaseDetail(_Case):
    character: str
    target_action: str | None = None
    position: tuple[str, ...] = ()
    orientation: tuple[str, ...] = ()


class CaseHistoryEvent(_Case):
    idx: int
    state: Literal["ongoing", "looping", "completed"]
    characters: tuple[str, ...]
    activity: str
    details: tuple[CaseDetail, ...] = ()
    distraction_level: int = 0


class CaseCharacter(_Case):
    idx: int
    name: str = Field(min_length=1)
    state: str = "idle"
    current_action: str | None = "idle"
    position: tuple[str, ...] = ()
    orientation: tuple[str, ...] = ()
    distraction_level: int = 0
    type: str = "essential"


class ExpectedPlan(_Case):
    character: str
    target_action: str | None = Field(None, description="action expression, e.g. 'order_food || order_drink'")
    relationships: str | None = Field(None, description="relationship expression over atoms")
    sampled_position: str | None = Field(None, description="position expression (PI cases)")


class BenchmarkCase(_Case):
    id: int
    tags: tuple[str, ...]
    scene_name: str
    action_labels: tuple[str, ...]
    user_instruction: str
    planning_history: tuple[CaseHistoryEvent, ...] = ()
    current_states: tuple[CaseCharacter, ...]
    expected_plans: tuple[ExpectedPlan, ...]
    allow_null_plan: bool = False
    source: str = Field("", description="file the case was read from")
    raw: dict[str, Any] = Field(default_factory=dict, exclude=True, repr=False)

    @property
    def group(self) -> str:
        """The case's tag combination as the reference folders name it, e.g. 'OA+RC'."""
        return "+".join(self.tags)

    def at_level(self, level: int) -> BenchmarkCase:
        """The case with only the distractors (characters and history events) of distraction
        level <= ``level``; essential ones (level 0) always stay."""
        raw = dict(self.raw)
        raw["current_states"] = [c for c in raw.get("current_states", []) if int(c.get("distraction_level", 0)) <= level]
        raw["planning_history"] = [e for e in raw.get("planning_history", []) if int(e.get("distraction_level", 0)) <= level]
        return BenchmarkCase.model_validate({**raw, "source": self.source, "raw": raw})

    @property
    def level(self) -> int:
        """Highest distraction level of the case's distractor characters and events."""
        levels = [c.distraction_level for c in self.current_states] + [e.distraction_level for e in self.planning_history]
        return max(levels, default=0)


def load_case(path: str | Path) -> BenchmarkCase:
    """Read one test case; raises :class:`BenchmarkCaseError` naming file and field."""
    path = Path(path)
    try:
        raw = load_bounded_json(read_bounded_bytes(path, MAX_CASE_BYTES, str(path)), MAX_CASE_JSON_DEPTH, str(path))
    except BoundedFileError as exc:
        raise BenchmarkCaseError(str(exc)) from None
    if not isinstance(raw, dict):
        raise BenchmarkCaseError(f"{path}: expected a JSON object")
    try:
        return BenchmarkCase.model_validate({**raw, "source": str(path), "raw": raw})
    except ValidationError as exc:
        raise BenchmarkCaseError(user_error(path, exc)) from None


def case_files(reference: str | Path) -> list[Path]:
    """The ``testcase_<id>.json`` files of a case set, by id.

    ``reference`` is the reference data's root (cases under ``benchmark/test_cases/<tags>/``)
    or a case folder in the same layout itself (``<tags>/testcase_<id>.json``, e.g.
    ``benchmark/cases/ours``), or one ``<tags>`` folder of either (``.../test_cases/6_PI``)."""
    root = Path(reference) / "benchmark" / "test_cases"
    if not root.is_dir():
        root = Path(reference)
    found = list(root.glob("*/testcase_*.json")) or list(root.glob("testcase_*.json"))
    for p in found:
        if _CASE_NAME.fullmatch(p.stem) is None:
            raise BenchmarkCaseError(
                f"{p}: a case file's name must be testcase_<id>.json with a numeric id of at most 9 digits"
            )
    files = sorted(found, key=lambda p: int(p.stem.split("_")[-1]))
    if not files:
        raise BenchmarkCaseError(
            f"{Path(reference)}: no test cases (expected benchmark/test_cases/<tags>/testcase_<id>.json "
            "under the reference data, <tags>/testcase_<id>.json in a case folder, or testcase_<id>.json "
            "in one <tags> folder)"
        )
    return files


def load_cases(
    reference: str | Path, ids: Iterable[int] | None = None, tags: Iterable[str] | None = None
) -> list[BenchmarkCase]:
    """Cases of the reference data, by id; ``ids`` / ``tags`` select (a case matches a tag it carries)."""
    wanted_ids = None if ids is None else set(ids)
    wanted_tags = None if tags is None else set(tags)
    if wanted_tags is not None and (unknown := wanted_tags - set(TAGS)):
        raise BenchmarkCaseError(f"unknown tag(s) {sorted(unknown)}; known: {', '.join(TAGS)}")
    cases = [load_case(p) for p in case_files(reference)]
    if wanted_ids is not None and (missing := wanted_ids - {c.id for c in cases}):
        raise BenchmarkCaseError(f"no test case with id(s) {sorted(missing)} in {reference}")
    return [
        c for c in cases
        if (wanted_ids is None or c.id in wanted_ids) and (wanted_tags is None or wanted_tags & set(c.tags))
    ]


BUNDLED_PREFIX = "bundled:"
"""A ``scene_name`` of ``bundled:<name>`` names a scene shipped with the package (``sim/scene/scenes``)."""


def scene_dir(reference: str | Path | None, case: BenchmarkCase) -> Path:
    """Where the case's scene is, for :func:`storyteller.sim.scene.files.load_scene`.

    A reference ``scene_name`` (``House``) is the folder ``configs/scenes/<name>`` of the
    reference data (``reference``; None: not given, which such a case refuses);
    ``bundled:<name>`` (``bundled:home``) is the bundled scene's JSON file, whatever
    ``reference`` is."""
    if case.scene_name.startswith(BUNDLED_PREFIX):
        name = case.scene_name[len(BUNDLED_PREFIX):]
        if name not in bundled_scene_names():
            raise BenchmarkCaseError(
                f"{case.source}: field 'scene_name': {name!r} is not a bundled scene "
                f"(bundled: {', '.join(bundled_scene_names())})"
            )
        return Path(str(resources.files("storyteller.sim.scene") / "scenes" / f"{name}.json"))
    if reference is None:
        raise BenchmarkCaseError(
            f"{case.source}: field 'scene_name': {case.scene_name!r} is a scene of the reference data, "
            "which was not given for these cases"
        )
    return Path(reference) / "configs" / "scenes" / case.scene_name


@dataclass(frozen=True)
class PlanningInputs:
    """What a planner is given for one case."""

    roster: tuple[CharacterStatus, ...]
    history: tuple[HistoryEntry, ...]
    world: WorldView
    seats_in_use: tuple[str, ...]
    free: tuple[str, ...]


def planning_inputs(case: BenchmarkCase, scene: Scene) -> PlanningInputs:
    """Roster, history and world view of ``case`` in ``scene`` (deterministic)."""
    try:
        world = world_view_from_reference_case(case.raw or case.model_dump(), scene)
    except ReferenceCaseError as exc:
        raise BenchmarkCaseError(f"{case.source}: {exc}") from None
    roster = tuple(
        CharacterStatus(
            name=c.name, busy=c.busy, action=c.action, position=c.position, facing=c.facing, seat=c.seat,
        )
        for c in world.characters
    )
    history = tuple(
        HistoryEntry(index=i, characters=e.characters, activity=e.activity, state=e.state)
        for i, e in enumerate(case.planning_history)
    )
    seats = tuple(sorted(
        {c.seat for c in world.characters if c.seat}
        | {o for o in world.objects_in_use if o in scene.by_name and scene.by_name[o].is_seat}
    ))
    return PlanningInputs(roster, history, world, seats, tuple(c.name for c in roster if not c.busy))


def expected_characters(case: BenchmarkCase) -> Sequence[str]:
    return [p.character for p in case.expected_plans]


class CaseWorld:
    """The spatial API's view of a test case as the reference data gives it (characters at
    positions sampled from the case's area texts, the objects in use): fixed for the case's one
    planning step, so it is not rebuilt from the roster."""

    def __init__(self, inputs: PlanningInputs) -> None:
        self.inputs = inputs

    def world_view(self, roster: Sequence[CharacterStatus]) -> WorldView:
        return self.inputs.world

    def seats_in_use(self, roster: Sequence[CharacterStatus]) -> list[str]:
        return list(self.inputs.seats_in_use)


def case_tags(case: BenchmarkCase) -> tuple[str, ...]:
    """The prompt tags of ``case`` (its in-context examples): the benchmark tags it carries."""
    return tuple(t for t in BENCHMARK_TAGS if t in case.tags)

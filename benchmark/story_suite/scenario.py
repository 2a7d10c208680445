"""A story-suite scenario as typed data: what to run and what the story log must show.

One TOML file per scenario (``benchmark/story_suite/scenarios/<name>.toml``); the file's stem
is the scenario's name. Loading checks everything that can be checked without a run: the
scene exists, every expectation names one of the run's characters, every action label is one
the scene allows, every position expression parses against the scene, and every ``order``
expectation names ``does`` expectations of the same file. A bad file raises
:class:`ScenarioError` naming the file and the field.

Expectations (``[[expect]]`` tables, judged by :mod:`storyteller.benchmark.story_suite.evaluate`):

- ``kind = "does"``: ``character`` has a plan whose ``action`` matches the action expression
  (``||`` / ``&&`` / parentheses, as in :func:`storyteller.benchmark.plan_scoring.action_matches`) and
  whose sampled position (and seat) satisfies ``where`` (a relationship expression, as in
  :func:`storyteller.benchmark.position_check.check_position`). Either may be left out, not both.
- ``kind = "order"``: the ``does`` expectation ``first`` is met by an event applied strictly
  before an event that meets ``then``.
- ``kind = "not_idle"``: ``character`` is given a non-idle action at least once.
"""

from __future__ import annotations

import tomllib
from collections.abc import Iterable
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from storyteller.benchmark.plan_scoring import ActionExpressionError, action_matches
from storyteller.benchmark.position_check import PositionExpressionError, check_position
from storyteller.sim.bounded_files import BoundedFileError, read_bounded_bytes
from storyteller.sim.scene.model import Scene
from storyteller.sim.validation_text import user_error

SCENARIO_DIR = Path(__file__).resolve().parent / "scenarios"
MAX_SCENARIO_BYTES = 1024 * 1024
"""Bytes of one scenario file (read as a regular file, ``storyteller.sim.bounded_files``)."""
CHARACTER_NAMES = ("Ava", "Ben", "Cleo", "Dan", "Eve", "Finn")
"""``storyteller run -n N`` names its characters in this order (``storyteller.orchestrator.cli.plan.NAMES``)."""


class ScenarioError(ValueError):
    """A scenario file that cannot be used: names the file and the field."""


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class Does(_Frozen):
    kind: Literal["does"] = "does"
    id: str = Field(min_length=1, description="Name used by order expectations and in reports.")
    character: str
    action: str | None = Field(default=None, description="Action expression over labels.")
    where: str | None = Field(default=None, description="Relationship expression over scene objects.")

    @model_validator(mode="after")
    def _something(self) -> Does:
        if self.action is None and self.where is None:
            raise ValueError("a 'does' expectation needs an action, a where, or both")
        return self


class Order(_Frozen):
    kind: Literal["order"]
    first: str
    then: str

    @property
    def id(self) -> str:
        return f"{self.first}<{self.then}"


class NotIdle(_Frozen):
    kind: Literal["not_idle"]
    character: str

    @property
    def id(self) -> str:
        return f"{self.character}-busy"


Expectation = Annotated[Does | Order | NotIdle, Field(discriminator="kind")]


class Scenario(_Frozen):
    name: str = Field(min_length=1)
    scene: Literal["home", "office", "restaurant"]
    characters: int = Field(ge=2, le=6)
    instruction: str = Field(min_length=1)
    duration: float = Field(gt=0, le=120, description="Simulated seconds.")
    max_events: int = Field(ge=1, le=8, description="Planning steps at most (waits do not count).")
    seed: int = 0
    expect: tuple[Expectation, ...] = Field(min_length=1)

    @property
    def names(self) -> tuple[str, ...]:
        return CHARACTER_NAMES[: self.characters]

    def run_args(self) -> list[str]:
        """The ``storyteller run`` arguments of this scenario (without --out/--record/--replay)."""
        return [
            "run", self.scene, "-n", str(self.characters), "-i", self.instruction,
            "--duration", f"{self.duration:g}", "--max-events", str(self.max_events),
            "--seed", str(self.seed), "--pace", "lockstep",
        ]  # fmt: skip


def _check_against_scene(scenario: Scenario, scene: Scene, labels: Iterable[str]) -> None:
    allowed = set(labels)
    does_ids = set()
    for i, e in enumerate(scenario.expect):
        field = f"expect[{i}]"
        if isinstance(e, Does | NotIdle) and e.character not in scenario.names:
            raise ValueError(f"{field}.character: {e.character!r} is not one of {', '.join(scenario.names)}")
        if isinstance(e, Does):
            if e.id in does_ids:
                raise ValueError(f"{field}.id: {e.id!r} is used twice")
            does_ids.add(e.id)
            if e.action is not None:
                try:
                    action_matches(e.action, "idle")
                except ActionExpressionError as exc:
                    raise ValueError(f"{field}.action: {exc}") from None
                words = {w for w in e.action.replace("(", " ").replace(")", " ").split() if w not in ("||", "&&")}
                if unknown := sorted(words - allowed):
                    raise ValueError(f"{field}.action: {', '.join(unknown)} not an action label of {scene.name}")
            if e.where is not None:
                try:
                    check_position(scene, e.where, (0.0, 0.0), seat=None)
                except PositionExpressionError as exc:
                    raise ValueError(f"{field}.where: {exc}") from None
    for i, e in enumerate(scenario.expect):
        if isinstance(e, Order):
            for side in ("first", "then"):
                if getattr(e, side) not in does_ids:
                    raise ValueError(f"expect[{i}].{side}: no 'does' expectation with id {getattr(e, side)!r}")


def load_scenario(path: Path) -> Scenario:
    from storyteller.agents.event_parser import scene_action_labels
    from storyteller.sim.scene.bundled import resolve_scene

    try:
        data = tomllib.loads(read_bounded_bytes(path, MAX_SCENARIO_BYTES, str(path)).decode("utf-8"))
        scenario = Scenario.model_validate({"name": path.stem, **data})
        scene = resolve_scene(scenario.scene)
        _check_against_scene(scenario, scene, scene_action_labels(scene))
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ScenarioError(f"{path}: cannot read ({exc})") from None
    except BoundedFileError as exc:
        raise ScenarioError(str(exc)) from None
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{path}: cannot read (not UTF-8: bad byte at offset {exc.start})") from None
    except RecursionError:  # tomllib is recursive: arrays or tables nested hundreds deep
        raise ScenarioError(f"{path}: cannot read (TOML nested too deeply)") from None
    except ValidationError as exc:
        raise ScenarioError(user_error(path, exc)) from None
    except ValueError as exc:
        raise ScenarioError(f"{path}: {exc}") from None
    return scenario


def load_scenarios(pattern: str = "*.toml", directory: Path = SCENARIO_DIR) -> list[Scenario]:
    """Scenarios whose file name matches ``pattern`` (a glob; a path with a '/' is taken as is)."""
    paths = sorted(Path().glob(pattern)) if "/" in pattern else sorted(directory.glob(pattern if pattern.endswith(".toml") else f"{pattern}.toml"))
    if not paths:
        raise ScenarioError(f"no scenario matches {pattern!r} in {directory}")
    return [load_scenario(p) for p in paths]

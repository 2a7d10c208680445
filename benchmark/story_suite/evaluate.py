"""Score a run's story log (``story.json`` from ``storyteller run``) against its scenario.

The score is the share of the scenario's expectations met. Every expectation gets a verdict
and a reason that says what the log showed, so a failed one can be read without the log.

What counts as "a character did X" (a ``does`` expectation): some applied event's plan for
that character has an action matching the action expression
(:func:`storyteller.benchmark.plan_scoring.action_matches`) and a sampled position (and seat) satisfying
the ``where`` expression without collision (:func:`storyteller.benchmark.position_check.check_position`,
the reference thresholds), and the simulation did not report that event as failed. Waits and
planning failures contribute no plans. ``order``: some plan meeting ``first`` belongs to an
event applied at a strictly earlier frame than some plan meeting ``then``. ``not_idle``: some
event gives the character an action other than ``idle``.

The judgement reads only ``story.json`` and the scene; it never looks at the trace, so a
replayed run and its live run score alike when their story logs are equal.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from storyteller.benchmark.plan_scoring import action_matches
from storyteller.benchmark.position_check import check_position
from storyteller.benchmark.story_suite.scenario import Does, NotIdle, Order, Scenario
from storyteller.sim.scene.model import Scene


class StoryLogError(ValueError):
    """A story log that cannot be judged: names the file and what is wrong."""


@dataclass(frozen=True)
class PlanRecord:
    """One character's plan in one applied event, as the story log holds it."""

    step: int
    frame: int
    character: str
    action: str
    area: str
    position: tuple[float, float]
    seat: str | None
    failure: str | None  # the simulation's failure of this event, if any

    def describe(self) -> str:
        where = f"seat {self.seat}" if self.seat else f"[{self.position[0]:.2f}, {self.position[1]:.2f}]"
        return f"step {self.step}: {self.action} at {where}" + (f" (event failed: {self.failure})" if self.failure else "")


@dataclass(frozen=True)
class Verdict:
    id: str
    kind: str
    met: bool
    reason: str


@dataclass(frozen=True)
class ScenarioScore:
    scenario: str
    verdicts: tuple[Verdict, ...]
    steps: int
    events: int

    @property
    def met(self) -> int:
        return sum(v.met for v in self.verdicts)

    @property
    def total(self) -> int:
        return len(self.verdicts)

    @property
    def share(self) -> float:
        return self.met / self.total if self.total else 0.0

    def to_json(self) -> dict[str, Any]:
        return {
            "scenario": self.scenario, "met": self.met, "total": self.total, "share": round(self.share, 4),
            "steps": self.steps, "events": self.events,
            "verdicts": [{"id": v.id, "kind": v.kind, "met": v.met, "reason": v.reason} for v in self.verdicts],
        }  # fmt: skip


def plan_records(story: dict[str, Any], source: str = "story.json") -> list[PlanRecord]:
    """Every character plan of every applied event, in step order."""
    try:
        failures = {e["index"]: e.get("failure") or "failed" for e in story["events"] if e["state"] == "failed"}
        out = []
        for step in story["steps"]:
            if step["kind"] != "event":
                continue
            for p in step["plans"]:
                out.append(PlanRecord(
                    step=int(step["index"]), frame=int(step["applied_frame"]), character=p["character"],
                    action=p["action"], area=p.get("area", ""), position=(float(p["position"][0]), float(p["position"][1])),
                    seat=p.get("seat"), failure=failures.get(step["index"]),
                ))  # fmt: skip
    except (KeyError, TypeError, IndexError, ValueError) as exc:
        raise StoryLogError(f"{source}: not a story log of storyteller run ({type(exc).__name__}: {exc})") from None
    return out


def _meets(e: Does, scene: Scene, plan: PlanRecord) -> str | None:
    """None when ``plan`` meets ``e``, else what is wrong with it."""
    if plan.character != e.character:
        return "another character"
    problems = []
    if e.action is not None and not action_matches(e.action, plan.action):
        problems.append(f"action {plan.action!r} is not {e.action!r}")
    if e.where is not None:
        result = check_position(scene, e.where, plan.position, seat=plan.seat)
        if not result.relation_passed:
            off = f" (off by {result.error:.2f} m)" if math.isfinite(result.error) else ""  # inf: another seat
            problems.append(f"not '{e.where}'{off}")
        elif result.collision is not None:
            problems.append(f"position collides with {result.collision}")
    if not problems and plan.failure is not None:
        problems.append(f"the event failed in the simulation: {plan.failure}")
    return "; ".join(problems) or None


def _judge_does(e: Does, scene: Scene, plans: list[PlanRecord]) -> Verdict:
    own = [p for p in plans if p.character == e.character]
    if not own:
        return Verdict(e.id, e.kind, False, f"{e.character} is in no event")
    misses = []
    for p in own:
        problem = _meets(e, scene, p)
        if problem is None:
            return Verdict(e.id, e.kind, True, f"{e.character} {p.describe()}")
        misses.append(f"{p.describe()}: {problem}")
    return Verdict(e.id, e.kind, False, f"{e.character}: " + " | ".join(misses))


def _judge_order(e: Order, does: dict[str, Does], scene: Scene, plans: list[PlanRecord]) -> Verdict:
    first = [p.frame for p in plans if _meets(does[e.first], scene, p) is None]
    then = [p.frame for p in plans if _meets(does[e.then], scene, p) is None]
    if not first or not then:
        missing = " and ".join(n for n, f in ((e.first, first), (e.then, then)) if not f)
        return Verdict(e.id, e.kind, False, f"cannot order: {missing} not met")
    if min(first) < max(then):
        return Verdict(e.id, e.kind, True, f"{e.first} at frame {min(first)} before {e.then} at frame {max(then)}")
    return Verdict(e.id, e.kind, False, f"{e.first} first at frame {min(first)}, {e.then} last at frame {max(then)}")


def _judge_not_idle(e: NotIdle, plans: list[PlanRecord]) -> Verdict:
    busy = [p for p in plans if p.character == e.character and p.action != "idle"]
    if busy:
        return Verdict(e.id, e.kind, True, f"{e.character} {busy[0].describe()}")
    seen = [p.describe() for p in plans if p.character == e.character]
    return Verdict(e.id, e.kind, False, f"{e.character} idles the whole run" + (f" ({'; '.join(seen)})" if seen else ""))


def score_story(scenario: Scenario, scene: Scene, story: dict[str, Any], source: str = "story.json") -> ScenarioScore:
    """Judge every expectation of ``scenario`` on one story log (see the module docstring)."""
    if story.get("scene") != scenario.scene or story.get("instruction") != scenario.instruction:
        raise StoryLogError(f"{source}: the log is of scene {story.get('scene')!r} with another instruction, "
                            f"not of scenario {scenario.name}")  # fmt: skip
    plans = plan_records(story, source)
    does = {e.id: e for e in scenario.expect if isinstance(e, Does)}
    verdicts = []
    for e in scenario.expect:
        if isinstance(e, Does):
            verdicts.append(_judge_does(e, scene, plans))
        elif isinstance(e, Order):
            verdicts.append(_judge_order(e, does, scene, plans))
        else:
            verdicts.append(_judge_not_idle(e, plans))
    return ScenarioScore(scenario.name, tuple(verdicts), steps=len(story["steps"]), events=len(story["events"]))


def score_run(scenario: Scenario, run_dir: Path) -> ScenarioScore:
    """Score the ``story.json`` in ``run_dir`` against ``scenario``."""
    from storyteller.sim.scene.bundled import resolve_scene

    path = run_dir / "story.json"
    try:
        story = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise StoryLogError(f"{path}: cannot read the story log ({exc})") from None
    return score_story(scenario, resolve_scene(scenario.scene), story, str(path))

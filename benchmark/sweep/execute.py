"""One run of a sweep: one planning step of the planning graph on one case, scored.

A run is driven by :func:`storyteller.orchestrator.session.plan_job.run_plan` exactly as
``storyteller plan`` and ``python -m storyteller.benchmark.planning_benchmark`` drive it (throwaway
in-memory checkpoints, the case's roster, history, world view and action labels), with the
method's graph variant and ``max_retries`` = the sweep's feedback budget. The scene
description of the describer methods is made once per scene and model by a separate
zero-step run of the same graph (:func:`describe`), traced in its own file, and handed to
every run of that scene and model: as in the paper, one description serves every case.

The port is the caller's: live and recording to the run's trace, or replaying it. Either way
:func:`run_result` reads tokens, latencies and first-attempt acceptance from the recorded
trace, so a replay yields the same :class:`~storyteller.benchmark.sweep.results.RunResult`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from storyteller.agents.llm_port import LLMPort
from storyteller.agents.messages import ParsedEvent, PlanningFailure, SceneDescription
from storyteller.benchmark.plan_scoring import CaseScore, score_outcome
from storyteller.benchmark.reference_cases import (
    BenchmarkCase,
    CaseWorld,
    case_tags,
    load_cases,
    planning_inputs,
    scene_dir,
)
from storyteller.benchmark.sweep.grid import METHODS, ModelSpec, RunKey, SweepSpec, SweepSpecError, slug
from storyteller.benchmark.sweep.results import CallStat, RunResult
from storyteller.benchmark.sweep.sweep_files import sweep_folder
from storyteller.orchestrator.llm.traces import AttemptRecord, ParsedRecord, TraceContents, read_trace
from storyteller.sim.scene.model import Scene

PortFactory = Callable[[ModelSpec, Path], LLMPort]
"""Builds the LLM port of one run (or one description) for a model, given the run's trace file."""
PLANNING_NODES = ("narrator", "event_parser", "planner")


def record_port(model: ModelSpec, trace: Path) -> LLMPort:
    """A live port on the model's config that records every call to ``trace``."""
    from storyteller.orchestrator.llm.replay import build_llm_port

    return build_llm_port(model.config, record=trace)


def replay_port(model: ModelSpec, trace: Path) -> LLMPort:
    """A port that answers only from ``trace`` (no model is loaded)."""
    from storyteller.orchestrator.llm.replay import ReplayClient

    return ReplayClient(trace)


def description_key(scene_name: str, model: str) -> str:
    return f"{slug(scene_name)}-{slug(model)}"


class SweepWorkspace:
    """A sweep's cases and scenes, loaded once: what every run of the sweep reads."""

    def __init__(self, spec: SweepSpec, out: Path) -> None:
        self.spec, self.out = spec, out
        for cs in spec.case_sets:
            if not Path(cs.path).is_dir():
                if cs.name == "reference":
                    from storyteller.orchestrator.reference_data import locate_reference

                    locate_reference().require()  # absent: its reason says how to provide it
                raise SweepSpecError(f"case set {cs.name!r}: {cs.path} is not a folder on this machine")
        self.cases: dict[str, dict[int, BenchmarkCase]] = {
            cs.name: {c.id: c for c in load_cases(cs.path, spec.case_ids)
                      if cs.case_ids is None or c.id in cs.case_ids}
            for cs in spec.case_sets
        }
        self._scenes: dict[tuple[str | None, str], tuple[Scene, Any]] = {}

    def case(self, key: RunKey) -> BenchmarkCase:
        return self.cases[key.case_set][key.case].at_level(key.level)

    def scene(self, case_set: str, case: BenchmarkCase) -> tuple[Scene, Any]:
        """The case's scene and its scene graph (loaded once per scene)."""
        from storyteller.sim.scene.files import load_scene
        from storyteller.tools.scene_graph import build_scene_graph

        root = self.spec.case_set(case_set).scenes_root
        if (root, case.scene_name) not in self._scenes:
            scene = load_scene(scene_dir(root, case))
            self._scenes[(root, case.scene_name)] = (scene, build_scene_graph(scene))
        return self._scenes[(root, case.scene_name)]

    def run_trace(self, key: RunKey) -> Path:
        return self.out / "traces" / "runs" / f"{key.run_id}.jsonl"

    def description_trace(self, key: str) -> Path:
        return self.out / "traces" / "descriptions" / f"{key}.jsonl"

    def description_file(self, key: str) -> Path:
        return self.out / "descriptions" / f"{key}.json"

    def description_needs(self, keys: list[RunKey]) -> dict[str, tuple[RunKey, str]]:
        """Description key -> (a run that needs it, its scene name), for the describer methods."""
        out: dict[str, tuple[RunKey, str]] = {}
        for k in keys:
            if METHODS[k.method].description == "describer":
                scene_name = self.cases[k.case_set][k.case].scene_name
                out.setdefault(description_key(scene_name, k.model), (k, scene_name))
        return out


async def describe(ws: SweepWorkspace, key: RunKey, port: LLMPort) -> SceneDescription:
    """The describer's description of ``key``'s scene for ``key``'s model (a zero-step run)."""
    from storyteller.orchestrator.session.plan_job import run_plan

    case = ws.case(key)
    scene, graph = ws.scene(key.case_set, case)
    model = ws.spec.model(key.model)
    planned = await run_plan(
        scene=scene, port=port, instruction="", events=0, seed=ws.spec.seed,
        runs_db=":memory:", thread_id=f"describe-{description_key(case.scene_name, key.model)}", roster=(),
        scene_graph=graph, describer_model=model.config.node("describer").model, max_retries=ws.spec.feedback,
        program_grammar=ws.spec.program_grammar,
    )
    assert planned.description is not None, "a zero-step run of the graph ends with a description"
    return planned.description


async def plan_run(
    ws: SweepWorkspace, key: RunKey, port: LLMPort, description: SceneDescription | None
) -> tuple[ParsedEvent | PlanningFailure | None, CaseScore]:
    """Run one planning step of ``key`` through ``port`` and score it."""
    from storyteller.orchestrator.session.plan_job import run_plan

    case = ws.case(key)
    scene, graph = ws.scene(key.case_set, case)
    inputs = planning_inputs(case, scene)
    ablation = METHODS[key.method]
    planned = await run_plan(
        scene=scene, port=port, instruction=case.user_instruction, events=1, seed=ws.spec.seed + key.repeat,
        runs_db=":memory:", thread_id=key.run_id, roster=inputs.roster, history=inputs.history,
        world=CaseWorld(inputs), description=description if ablation.description == "describer" else None,
        action_labels=case.action_labels, scene_graph=graph,
        describer_model=ws.spec.model(key.model).config.node("describer").model,
        max_retries=ws.spec.feedback, tags=case_tags(case), ablation=ablation,
        program_grammar=ws.spec.program_grammar,
    )
    ((_, outcome),) = planned.outcomes
    return outcome, score_outcome(case, scene, outcome)


def call_stats(trace: TraceContents) -> tuple[CallStat, ...]:
    """One entry per logical call (attempts grouped by ``call``), in call order."""
    by_call: dict[int, list[AttemptRecord]] = {}
    for a in trace.attempts():
        by_call.setdefault(a.call, []).append(a)
    stats = []
    for call in sorted(by_call):
        attempts = by_call[call]
        last = attempts[-1]
        stats.append(CallStat(
            node=last.node, model=last.model, attempts=len(attempts),
            prompt_tokens=sum(a.usage.prompt_tokens for a in attempts if a.usage),
            completion_tokens=sum(a.usage.completion_tokens for a in attempts if a.usage),
            latency_s=round(sum(a.latency_s for a in attempts), 3),
        ))
    return tuple(stats)


def first_replies_accepted(trace: TraceContents) -> bool:
    """Whether the first reply of every planning role in the trace was accepted by its check."""
    first: dict[str, ParsedRecord] = {}
    for r in trace.records:
        if isinstance(r, ParsedRecord) and r.node in PLANNING_NODES:
            first.setdefault(r.node, r)
    return all(r.ok for r in first.values())


def error_class(score: CaseScore, outcome: ParsedEvent | PlanningFailure | None) -> str | None:
    """Why a run did not pass, as a short class: ``failure:<role>`` / ``unavailable:<role>``
    (no plan), ``wait`` (waited where a plan was expected), or the sorted ``+``-joined kinds of
    the character verdicts that failed: ``missing``, ``action``, ``position``, ``collision``."""
    if score.passed:
        return None
    if isinstance(outcome, PlanningFailure):
        unavailable = outcome.feedback.startswith(("LLMError", "LLMUnavailableError"))
        return f"{'unavailable' if unavailable else 'failure'}:{outcome.node}"
    if score.kind == "wait":
        return "wait"
    kinds: set[str] = set()
    for v in score.characters:
        if v.passed:
            continue
        if v.reason.startswith("no plan for"):
            kinds.add("missing")
            continue
        if "does not match" in v.reason:
            kinds.add("action")
        if v.collision is not None:
            kinds.add("collision")
        if " is not '" in v.reason:
            kinds.add("position")
    return "+".join(sorted(kinds)) or "other"


def run_result(
    ws: SweepWorkspace, key: RunKey, outcome: ParsedEvent | PlanningFailure | None, score: CaseScore, trace: Path
) -> RunResult:
    """The result line of a finished run, from its outcome, its verdict and its trace file."""
    contents = read_trace(trace) if trace.exists() else TraceContents(records=[], torn_tail=None)
    calls = call_stats(contents)
    case = ws.case(key)
    model = ws.spec.model(key.model)
    verdict = "pass" if score.passed else ("fail" if score.executed else "error")
    return RunResult(
        run_id=key.run_id, case_set=key.case_set, case=key.case, group=case.group,
        characters=len(case.current_states), level=key.level, repeat=key.repeat, seed=ws.spec.seed + key.repeat,
        method=key.method, description=METHODS[key.method].description, model=key.model, models=model.roles,
        verdict=verdict, executed=score.executed, executed_first=score.executed and first_replies_accepted(contents),
        kind=score.kind, error_class=error_class(score, outcome), reason=score.reason, calls=calls,
        prompt_tokens=sum(c.prompt_tokens for c in calls), completion_tokens=sum(c.completion_tokens for c in calls),
        latency_s=round(sum(c.latency_s for c in calls), 3),
    )


async def execute(
    ws: SweepWorkspace, key: RunKey, factory: PortFactory, description: SceneDescription | None, *, fresh: bool
) -> RunResult:
    """Run ``key`` with a port from ``factory`` on its trace file; ``fresh``: delete a partial
    trace first (a run in flight when a sweep was killed is redone from scratch)."""
    trace = ws.run_trace(key)
    if fresh:
        sweep_folder(ws.out, "traces", "runs")
        trace.unlink(missing_ok=True)
    port = factory(ws.spec.model(key.model), trace)
    try:
        outcome, score = await plan_run(ws, key, port, description)
    finally:
        port.close()
    return run_result(ws, key, outcome, score, trace)

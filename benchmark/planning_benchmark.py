"""Planning quality on the reference benchmark's 40 test cases, measured as the paper does.

For every case (and every run of it) one planning step of the planning graph is run (the full
event-driven method or one of the paper's ablations, which are variants of that graph), driven
exactly as ``storyteller plan`` drives it (:func:`storyteller.orchestrator.session.plan_job.run_plan`), with
the case's instruction, history and character states; the outcome is scored by :mod:`storyteller.benchmark.plan_scoring`. It prints the
success rate (passed runs / runs) and the execution rate (runs without a planning failure /
runs) per tag group, per tag and overall, next to the paper's own figures.

Every LLM call goes through the project's LLM port, so ``--config`` picks models per role,
``--record`` writes a trace and ``--replay`` re-scores a recorded run with no model loaded
(stdout is identical; timings go to stderr)::

    python -m storyteller.benchmark.planning_benchmark --cases 0 10 60 --record bench.jsonl
    python -m storyteller.benchmark.planning_benchmark --cases 0 10 60 --replay bench.jsonl

``--help`` lists the options (planner, description, distraction level, runs, seed).

For sweeps over case sets, levels, methods and models that resume, scale out and write
reports, use ``storyteller bench run`` (:mod:`storyteller.benchmark.sweep`); it drives the same graph.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal, get_args

os.environ.setdefault("LITELLM_LOCAL_MODEL_COST_MAP", "True")  # before litellm is imported

from storyteller.agents.llm_port import LLMPort
from storyteller.agents.messages import ParsedEvent, SceneDescription
from storyteller.agents.prompt_templates import PromptLibrary
from storyteller.benchmark.plan_scoring import CaseScore, score_outcome
from storyteller.benchmark.reference_cases import (
    TAGS,
    BenchmarkCase,
    BenchmarkCaseError,
    CaseWorld,
    case_tags,
    load_cases,
    planning_inputs,
    scene_dir,
)
from storyteller.orchestrator.planning.ablation_graph import Ablation
from storyteller.orchestrator.planning.kinds import DescriptionKind, PlannerKind
from storyteller.orchestrator.reference_data import locate_reference
from storyteller.orchestrator.session.plan_job import run_plan
from storyteller.sim.scene.model import Scene
from storyteller.tools.scene_graph import SceneGraph, build_scene_graph

DEFAULT_REFERENCE = locate_reference().path  # $STORYTELLER_REFERENCE, else ../shared/reference/event-driven-storytelling
REFERENCE_DESCRIPTIONS = "openai-gpt-4o-2024-08-06-0.1"
DescriptionSource = Literal["describer", "reference", "object-list", "scene-graph"]
"""The planning graph's description variants, and ``reference``: the authors' GPT-4o text."""
PLANNERS: tuple[PlannerKind, ...] = get_args(PlannerKind)
DESCRIPTIONS: tuple[DescriptionSource, ...] = get_args(DescriptionSource)
PAPER = (
    "paper (full method, 40 cases): GPT-4o success 0.90 (execution 0.98), GPT-4o mini 0.74 (0.96), "
    "Qwen2.5-7B 0.39 (0.87); PI with area sampling 0.94 vs direct coordinates 0.46 (GPT-4o)"
)


@dataclass(frozen=True)
class RunResult:
    case: int
    group: str
    run: int
    seed: int
    score: CaseScore
    event: dict[str, Any] | None


class Descriptions:
    """The scene description a case starts from, by source: the authors' GPT-4o text
    (``reference``), or the one the planning graph made (describer) or set (object list,
    scene graph) for an earlier case of the same scene; None until then (the graph makes it)."""

    def __init__(self, source: DescriptionSource, reference: Path) -> None:
        if source not in DESCRIPTIONS:
            raise ValueError(f"unknown description {source!r}; expected one of {', '.join(DESCRIPTIONS)}")
        self.source, self.reference = source, reference
        self._done: dict[str, SceneDescription] = {}

    @property
    def graph_description(self) -> DescriptionKind:
        """The planning graph's description variant for this source."""
        return "describer" if self.source == "reference" else self.source

    def get(self, scene: Scene) -> SceneDescription | None:
        if scene.name not in self._done and self.source == "reference":
            path = self.reference / "configs" / "scenes" / scene.name / "descriptions" / REFERENCE_DESCRIPTIONS / "description-0.txt"
            try:
                self._done[scene.name] = SceneDescription(scene=scene.name, text=path.read_text(encoding="utf-8"))
            except OSError as exc:
                raise BenchmarkCaseError(f"{path}: cannot read the reference description ({exc.strerror})") from None
        return self._done.get(scene.name)

    def remember(self, scene: Scene, description: SceneDescription | None) -> None:
        if description is not None:
            self._done.setdefault(scene.name, description)


async def run_cases(
    cases: Sequence[BenchmarkCase],
    port: LLMPort,
    descriptions: Descriptions,
    reference: Path,
    *,
    planner: PlannerKind = "event",
    prompts: PromptLibrary | None = None,
    max_retries: int = 3,
    describer_model: str = "unknown",
    description_cache: Path | None = None,
    runs: int = 1,
    seed: int = 0,
    program_grammar: bool = False,
    on_result: Any = None,
) -> list[RunResult]:
    """Plan and score every case ``runs`` times (seed + run index per run).

    Each run is one planning step of the planning graph (or its ``planner`` variant), driven
    by :func:`storyteller.orchestrator.session.plan_job.run_plan` as ``storyteller plan`` drives it, from
    the case's roster, story so far, world view and action labels, on a throwaway thread."""
    from storyteller.orchestrator.sandbox_worker import WorkerRunner
    from storyteller.sim.scene.files import load_scene

    prompts = prompts or PromptLibrary()
    ablation = Ablation(planner=planner, description=descriptions.graph_description)
    scenes: dict[str, tuple[Scene, SceneGraph]] = {}
    results: list[RunResult] = []
    with WorkerRunner() as runner:  # one worker process for every case
        for case in cases:
            if case.scene_name not in scenes:
                scene = load_scene(scene_dir(reference, case))
                scenes[case.scene_name] = (scene, build_scene_graph(scene))
            scene, graph = scenes[case.scene_name]
            inputs = planning_inputs(case, scene)
            for r in range(runs):
                planned = await run_plan(
                    scene=scene, port=port, instruction=case.user_instruction, events=1, seed=seed + r,
                    runs_db=":memory:", thread_id=f"case-{case.id}-run-{r}", roster=inputs.roster,
                    history=inputs.history, world=CaseWorld(inputs), description=descriptions.get(scene),
                    action_labels=case.action_labels, scene_graph=graph, describer_model=describer_model,
                    description_cache=description_cache, max_retries=max_retries, prompts=prompts,
                    tags=case_tags(case), ablation=ablation, program_grammar=program_grammar, runner=runner,
                )
                descriptions.remember(scene, planned.description)
                ((_, outcome),) = planned.outcomes
                event = None
                if isinstance(outcome, ParsedEvent):
                    event = {
                        "characters": list(outcome.event.characters), "activity": outcome.event.activity,
                        "plans": [{"character": p.character, "action": p.action, "area": p.area, "seat": p.seat,
                                   "position": [round(p.position[0], 3), round(p.position[1], 3)]} for p in outcome.plans],
                    }
                result = RunResult(case.id, case.group, r, seed + r, score_outcome(case, scene, outcome), event)
                results.append(result)
                if on_result is not None:
                    on_result(result)
    return results


def summary_rows(results: Sequence[RunResult]) -> list[tuple[str, int, float, float]]:
    """(label, runs, success rate, execution rate) per tag group, per tag, and overall."""
    def row(label: str, rs: Sequence[RunResult]) -> tuple[str, int, float, float]:
        n = len(rs)
        return (label, n, sum(r.score.passed for r in rs) / n, sum(r.score.executed for r in rs) / n)

    groups = sorted({r.group for r in results}, key=lambda g: (g.count("+"), g))
    rows = [row(g, [r for r in results if r.group == g]) for g in groups]
    for tag in TAGS:
        tagged = [r for r in results if tag in r.group.split("+")]
        if tagged and len({r.group for r in tagged}) > 1:
            rows.append(row(f"any {tag}", tagged))
    rows.append(row("all", results))
    return rows


def format_summary(results: Sequence[RunResult], header: str) -> str:
    lines = [header, f"{'cases':12s}{'runs':>6s}{'success':>10s}{'execution':>11s}"]
    lines += [f"{label:12s}{n:6d}{s:10.2f}{e:11.2f}" for label, n, s, e in summary_rows(results)]
    lines.append(PAPER)
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m storyteller.benchmark.planning_benchmark", description=__doc__.split("\n\n")[0])
    p.add_argument("--reference", type=Path, default=DEFAULT_REFERENCE, help="the reference data folder")
    p.add_argument("--cases", type=int, nargs="*", help="case ids (default: all 40)")
    p.add_argument("--tags", nargs="*", choices=TAGS, help="only cases carrying one of these tags")
    p.add_argument("--level", type=int, default=2, choices=(0, 1, 2), help="keep distractors up to this level")
    p.add_argument("--runs", type=int, default=1, help="runs per case (seeds seed .. seed+runs-1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--planner", choices=PLANNERS, default="event", help="event (full method), unified (w/o Event), direct (Direct Inference)")
    p.add_argument("--description", choices=DESCRIPTIONS, default="describer",
                   help="scene description: our describer, the authors' GPT-4o text, an object list, or the raw scene graph")
    p.add_argument("--config", type=Path, help="TOML run config (models per role)")
    p.add_argument("--record", type=Path, help="write every LLM call to this trace")
    p.add_argument("--replay", type=Path, help="serve every LLM call from this trace (no model loaded)")
    p.add_argument("--max-retries", type=int, default=3)
    p.add_argument("--program-grammar", action=argparse.BooleanOptionalAction, default=True,
                   help="local models write the event program under a grammar of the API's area functions and the "
                        "scene's names (default; --no-program-grammar: free Python, as the paper)")
    p.add_argument("--json", type=Path, help="also write every run's verdict to this JSON file")
    p.add_argument("--verbose", action="store_true", help="print each run's verdict")
    return p


async def _main(args: argparse.Namespace) -> int:
    from storyteller.orchestrator.cache_paths import description_cache_dir
    from storyteller.orchestrator.llm.config import load_config
    from storyteller.orchestrator.llm.replay import build_llm_port

    if args.runs < 1:
        raise BenchmarkCaseError("--runs must be at least 1")
    cases = [c.at_level(args.level) for c in load_cases(args.reference, args.cases, args.tags)]
    if not cases:
        raise BenchmarkCaseError("no test case selected")
    config = load_config(args.config)
    port = build_llm_port(config, record=args.record, replay=args.replay)
    # a cached description would make a recorded run depend on this machine's cache
    cache = None if (args.record or args.replay) else description_cache_dir()
    descriptions = Descriptions(args.description, args.reference)
    started = time.perf_counter()

    def report(r: RunResult) -> None:
        if args.verbose:
            verdict = "pass" if r.score.passed else ("fail" if r.score.executed else "error")
            print(f"case {r.case:2d} run {r.run} [{r.group}]: {verdict}: {r.score.reason}")
        print(f"case {r.case} run {r.run}: {time.perf_counter() - started:.1f} s", file=sys.stderr)

    try:
        results = await run_cases(
            cases, port, descriptions, args.reference, planner=args.planner, max_retries=args.max_retries,
            describer_model=config.node("describer").model, description_cache=cache, runs=args.runs, seed=args.seed,
            program_grammar=args.program_grammar, on_result=report,
        )
    finally:
        port.close()
    if args.replay:  # the models that answered when the trace was recorded
        from storyteller.orchestrator.llm.traces import read_trace

        models = sorted({a.model for a in read_trace(args.replay).attempts() if a.final})
    else:
        models = sorted({config.node(n).model for n in ("describer", "narrator", "event_parser", "planner")})
    header = (f"planner={args.planner} description={args.description} level={args.level} runs={args.runs} "
              f"seed={args.seed}{'' if args.program_grammar else ' free-programs'} models={','.join(models)}" + (" (replayed)" if args.replay else ""))
    print(format_summary(results, header))
    if args.json is not None:
        payload = {"header": header, "summary": [dict(zip(("cases", "runs", "success", "execution"), row, strict=True))
                                                 for row in summary_rows(results)],
                   "runs": [{**asdict(r), "score": asdict(r.score)} for r in results]}
        args.json.write_text(json.dumps(payload, indent=1), encoding="utf-8")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from storyteller.agents.llm_port import LLMError
    from storyteller.orchestrator.llm.config import ConfigError
    from storyteller.orchestrator.logging_setup import configure_logging

    configure_logging("WARNING")  # logs go to stderr; stdout holds only the verdicts and the table

    try:
        return asyncio.run(_main(args))
    except (BenchmarkCaseError, ConfigError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except LLMError as exc:  # a replay miss or an unusable model: the run cannot go on
        print(f"error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())

"""Run scenarios with ``storyteller run --pace lockstep`` (a subprocess each) and score them.

The subprocess is the documented interface of a run: the same arguments the user would type,
plus ``--record DIR/<scenario>.jsonl`` (keep the LLM trace) or ``--replay DIR/<scenario>.jsonl``
(serve every call and applied frame from it, no model loaded). ``--model M`` sets
``STORYTELLER_MODEL`` for the child, which every planning role then uses. A run whose command
fails still gets a row: its expectations are unmet with the command's last error line as the
reason, so a broken run lowers the score instead of hiding.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from storyteller.benchmark.story_suite.evaluate import ScenarioScore, StoryLogError, Verdict, score_run
from storyteller.benchmark.story_suite.scenario import Scenario
from storyteller.sim.no_follow_writes import write_file


@dataclass(frozen=True)
class RunOptions:
    out: Path
    model: str | None = None
    record: Path | None = None
    replay: Path | None = None


def storyteller_command() -> list[str]:
    """The ``storyteller`` entry point of this interpreter's environment."""
    beside = Path(sys.executable).with_name("storyteller")
    found = str(beside) if beside.is_file() else shutil.which("storyteller")
    if found is not None:
        return [found]
    return [sys.executable, "-c", "from storyteller.orchestrator.cli.app import app; app(prog_name='storyteller')"]


def run_args(scenario: Scenario, options: RunOptions) -> list[str]:
    args = [*storyteller_command(), *scenario.run_args(), "--out", str(options.out / scenario.name)]
    if options.replay is not None:
        args += ["--replay", str(options.replay / f"{scenario.name}.jsonl")]
    elif options.record is not None:
        args += ["--record", str(options.record / f"{scenario.name}.jsonl")]
    return args


def _failed(scenario: Scenario, reason: str) -> ScenarioScore:
    return ScenarioScore(
        scenario.name,
        tuple(Verdict(e.id, e.kind, False, f"run failed: {reason}") for e in scenario.expect),
        steps=0, events=0,
    )  # fmt: skip


def run_scenario(scenario: Scenario, options: RunOptions) -> tuple[ScenarioScore, float]:
    """Run one scenario and score its story log; also the wall seconds the run took."""
    if options.replay is not None and not (options.replay / f"{scenario.name}.jsonl").is_file():
        return _failed(scenario, f"no trace {options.replay / (scenario.name + '.jsonl')}"), 0.0
    if options.record is not None:
        options.record.mkdir(parents=True, exist_ok=True)
        # recording anew replaces the scenario's trace (a run refuses to append to one)
        (options.record / f"{scenario.name}.jsonl").unlink(missing_ok=True)
    run_dir = options.out / scenario.name
    if run_dir.is_dir() and not run_dir.is_symlink():
        shutil.rmtree(run_dir)  # the runner's own folder of an earlier suite run: the story starts over
    env = dict(os.environ)
    if options.model is not None:
        env["STORYTELLER_MODEL"] = options.model
    t0 = time.perf_counter()
    proc = subprocess.run(run_args(scenario, options), env=env, capture_output=True, text=True, check=False)
    seconds = time.perf_counter() - t0
    run_dir.mkdir(parents=True, exist_ok=True)
    # the run folder may hold a link planted at run.log: replaced, never written through
    write_file(run_dir / "run.log", (proc.stdout + proc.stderr).encode("utf-8", "surrogateescape"))
    if not (run_dir / "story.json").is_file():
        last = (proc.stderr.strip().splitlines() or [f"exit code {proc.returncode}"])[-1]
        return _failed(scenario, last), seconds
    try:
        return score_run(scenario, run_dir), seconds
    except StoryLogError as exc:
        return _failed(scenario, str(exc)), seconds


def record_scores(record: Path, scores: list[ScenarioScore], model: str) -> Path:
    """Merge the scores of recorded runs into ``record/scores.json`` (the replay test's truth)."""
    path = record / "scores.json"
    stored = json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {"scenarios": {}}
    stored["model"] = model
    stored["scenarios"].update({s.scenario: s.to_json() for s in scores})
    stored["scenarios"] = dict(sorted(stored["scenarios"].items()))
    path.write_text(json.dumps(stored, indent=2) + "\n", encoding="utf-8")
    return path


def write_results(out: Path, scores: list[ScenarioScore], meta: dict[str, object]) -> None:
    """``results.json`` (every verdict) and ``report.md`` (the table and the unmet reasons)."""
    from storyteller.benchmark.story_suite.report import markdown_report, totals

    payload = {**meta, **totals(scores), "scenarios": [s.to_json() for s in scores]}
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")
    (out / "report.md").write_text(markdown_report(scores, meta), encoding="utf-8")

"""``python -m storyteller.benchmark.story_suite run|score``: run the story suite, or re-score its runs.

::

    python -m storyteller.benchmark.story_suite run --out out/suite                      # live, default model
    python -m storyteller.benchmark.story_suite run --record traces/story_suite --out out/suite
    python -m storyteller.benchmark.story_suite run --replay traces/story_suite --out out/suite
    python -m storyteller.benchmark.story_suite score out/suite

Both print the table (expectations met / total and share, per scenario and in total) and
write ``results.json`` and ``report.md`` into the out folder. Exit code 2 on a bad scenario
file or a bad option; a run that fails is scored, not raised.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from storyteller.benchmark.story_suite.evaluate import StoryLogError, score_run
from storyteller.benchmark.story_suite.report import table, totals
from storyteller.benchmark.story_suite.runner import RunOptions, record_scores, run_scenario, write_results
from storyteller.benchmark.story_suite.scenario import ScenarioError, load_scenarios


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m storyteller.benchmark.story_suite", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="Run every scenario with storyteller run --pace lockstep and score it.")
    run.add_argument("--scenarios", default="*", help="Glob over scenario names (default: all).")
    run.add_argument("--model", default=None, help="Model of every planning role (STORYTELLER_MODEL), e.g. local/qwen2.5-coder-1.5b.")
    mode = run.add_mutually_exclusive_group()
    mode.add_argument("--record", type=Path, default=None,
                      help="Keep each run's trace as DIR/<scenario>.jsonl and its score in DIR/scores.json.")  # fmt: skip
    mode.add_argument("--replay", type=Path, default=None, help="Replay DIR/<scenario>.jsonl (no model loaded).")
    run.add_argument("--out", type=Path, required=True, help="Folder of the runs, results.json and report.md.")
    score = sub.add_parser("score", help="Re-score the runs in an out folder of 'run'.")
    score.add_argument("dir", type=Path)
    score.add_argument("--scenarios", default="*", help="Glob over scenario names (default: all with a run).")
    return p


def model_name(model: str | None) -> str:
    """The models the planning roles will use: ``--model``, else the run config's (env and
    ``STORYTELLER_CONFIG`` as ``storyteller run`` reads them)."""
    if model is not None:
        return model
    from storyteller.orchestrator.llm.config import ConfigError, load_config

    try:
        return ", ".join(sorted({node.model for node in load_config().nodes.values()}))
    except ConfigError as exc:
        return f"unknown ({exc})"


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        scenarios = load_scenarios(args.scenarios)
    except ScenarioError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.command == "run":
        if args.replay is not None and not args.replay.is_dir():
            print(f"error: --replay {args.replay}: not a folder of traces", file=sys.stderr)
            return 2
        options = RunOptions(out=args.out, model=args.model, record=args.record, replay=args.replay)
        scores, seconds = [], {}
        for scenario in scenarios:
            score, took = run_scenario(scenario, options)
            scores.append(score)
            seconds[scenario.name] = round(took, 1)
            print(f"{scenario.name}: {score.met}/{score.total} ({took:.0f} s)", file=sys.stderr, flush=True)
        mode = "replay" if args.replay else ("record" if args.record else "live")
        if args.record is not None:
            print(f"-> {record_scores(args.record, scores, model_name(args.model))}", file=sys.stderr)
        meta: dict[str, object] = {"command": "run", "mode": mode, "model": model_name(args.model),
                                   "seconds": seconds}  # fmt: skip
    else:
        ran = [s for s in scenarios if (args.dir / s.name).is_dir()]
        if not ran:
            print(f"error: {args.dir}: no scenario run folder in it", file=sys.stderr)
            return 2
        try:
            scores = [score_run(s, args.dir / s.name) for s in ran]
        except StoryLogError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        previous = args.dir / "results.json"
        meta = {"command": "score"}
        if previous.is_file():
            meta.update({k: v for k, v in json.loads(previous.read_text()).items() if k in ("mode", "model")})
        args.out = args.dir
    print(table(scores))
    write_results(args.out, scores, meta)
    t = totals(scores)
    print(f"-> {args.out / 'results.json'}, {args.out / 'report.md'} ({t['met']}/{t['total']} expectations met)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

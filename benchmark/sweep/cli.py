"""``storyteller bench``: run, re-score and report planning-benchmark sweeps.

A command plugin: ``pyproject.toml`` declares ``bench = "storyteller.benchmark.sweep.cli:register"`` in
the ``storyteller.commands`` entry-point group and ``storyteller.orchestrator.cli.app`` calls
:func:`register` with its app (``orchestrator`` never imports ``benchmark``). Only typer is
imported here at module level; each command imports the sweep machinery when it runs.

::

    storyteller bench run --cases ours --level 0 --level 2 --method ours --method direct \\
        --model local/qwen2.5-coder-0.5b --repeats 3 --out runs/sweep1
    storyteller bench score runs/sweep1     # replay every trace, rewrite the files
    storyteller bench report runs/sweep1    # rebuild results.csv, report.md, plots
"""

from __future__ import annotations

import errno
from pathlib import Path
from typing import Annotated, Any

import typer

bench = typer.Typer(name="bench", help="Planning benchmark sweeps: run, re-score from traces, report.",
                    no_args_is_help=True)


def register(app: typer.Typer) -> None:
    """Add the ``bench`` group to ``app`` (the ``storyteller.commands`` entry point)."""
    app.add_typer(bench, name="bench")


def _fail(message: str, code: int = 2) -> None:
    """One ``error:`` line (whatever the message quotes: a case file's text, a path) and exit."""
    from storyteller.orchestrator.safe_text import one_line
    from storyteller.orchestrator.terminal import say

    say(f"error: {one_line(message)}", err=True)
    raise typer.Exit(code)


_REFUSED = (errno.ELOOP, errno.EMLINK, errno.ENOTDIR, errno.EINVAL, errno.ENXIO, errno.EISDIR)
"""Errors of a write ``storyteller.sim.no_follow_writes`` refused in the sweep folder (a user error: exit 2)."""


def _guard(fn: Any) -> Any:
    """Run ``fn()``, turning user errors into one line and exit code 2 (1 for LLM errors)."""
    from storyteller.agents.llm_port import LLMError
    from storyteller.benchmark.reference_cases import BenchmarkCaseError
    from storyteller.benchmark.sweep.grid import SweepSpecError
    from storyteller.benchmark.sweep.sweep_files import SweepFileError
    from storyteller.orchestrator.llm.config import ConfigError
    from storyteller.orchestrator.llm.traces import TraceCorruptError
    from storyteller.orchestrator.reference_data import ReferenceDataNotFound

    try:
        return fn()
    except (SweepSpecError, SweepFileError, TraceCorruptError, BenchmarkCaseError, ConfigError,
            ReferenceDataNotFound) as exc:
        _fail(str(exc))
    except OSError as exc:  # a write refused (a link, a FIFO, a hard-linked file in the folder) or failed
        where = f"{exc.filename}: " if exc.filename else ""
        _fail(f"{where}{exc.strerror or exc}", code=2 if exc.errno in _REFUSED else 1)
    except LLMError as exc:
        _fail(f"{type(exc).__name__}: {exc}", code=1)


@bench.command("run")
def run_command(
    out: Annotated[Path, typer.Option("--out", help="Sweep folder (created; reused to resume).")],
    cases: Annotated[list[str] | None, typer.Option(
        "--cases", help="Case set: reference (default: the authors' 40 cases), ours (our whole pool), ours-dev / ours-test "
        "(one side of its split: develop on dev only), ours-ref / ours-ref-dev / ours-ref-test (our cases on the "
        "authors' scenes; need the reference data), or a folder in the reference format. Repeatable.")] = None,
    level: Annotated[list[int] | None, typer.Option("--level", help="Distraction level 0-2 (default 2). Repeatable.")] = None,
    repeats: Annotated[int, typer.Option("--repeats", min=1, help="Runs per case, seeds seed..seed+repeats-1.")] = 1,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the first repeat.")] = 0,
    method: Annotated[list[str] | None, typer.Option(
        "--method", help="ours, wo-event, object-list, scene-graph, direct (default: all five). Repeatable.")] = None,
    model: Annotated[list[str] | None, typer.Option("--model", help="A model for every role. Repeatable.")] = None,
    config: Annotated[list[Path] | None, typer.Option("--config", help="A run config (a model per role). Repeatable.")] = None,
    case_id: Annotated[list[int] | None, typer.Option("--case-id", help="Only these case ids. Repeatable.")] = None,
    feedback: Annotated[int, typer.Option("--feedback", min=0, help="Self-feedback retries per role (0: off, as the paper).")] = 0,
    program_grammar: Annotated[bool, typer.Option(
        "--program-grammar/--no-program-grammar", help="Local models write event programs under a grammar.")] = True,
    jobs: Annotated[int, typer.Option("--jobs", min=1, help="Runs at once (API models; the embedded model serialises).")] = 1,
    executor: Annotated[str, typer.Option("--executor", help="local or ray.")] = "local",
    ray_address: Annotated[str | None, typer.Option("--ray-address", help="Ray cluster address (default: a local Ray).")] = None,
) -> None:
    """Run (or resume) a sweep: case sets x levels x repeats x methods x models, one planning step per run."""

    def go() -> None:
        import asyncio

        from storyteller.benchmark.sweep.grid import (
            METHODS,
            SweepSpec,
            SweepSpecError,
            case_set_for,
            model_specs,
        )
        from storyteller.benchmark.sweep.progress import progress_for
        from storyteller.benchmark.sweep.runner import run_sweep
        from storyteller.orchestrator.reference_data import locate_reference
        from storyteller.orchestrator.terminal import say

        if executor not in ("local", "ray"):
            raise SweepSpecError(f"--executor {executor!r}: expected local or ray")
        reference = locate_reference()  # required by the case sets that need it (case_set_for)
        ours = Path(__file__).resolve().parents[1] / "cases" / "ours"
        spec = SweepSpec(
            case_sets=tuple(case_set_for(c, reference, ours) for c in (cases or ["reference"])),
            case_ids=tuple(sorted(set(case_id))) if case_id else None,
            levels=tuple(dict.fromkeys(level or [2])), repeats=repeats, seed=seed,
            methods=tuple(dict.fromkeys(method or list(METHODS))),
            models=model_specs(model or [], config or []), feedback=feedback, program_grammar=program_grammar,
        ).check()
        run_all = None
        if executor == "ray":
            from storyteller.benchmark.sweep.ray_executor import ray_executor

            run_all = ray_executor(jobs, address=ray_address)
        results = asyncio.run(run_sweep(spec, out, jobs=jobs, progress=progress_for(), executor=run_all))
        passed = sum(r.verdict == "pass" for r in results)
        say(f"{len(results)} runs, {passed} passed; report: {out / 'report.md'}")

    _guard(go)


@bench.command("score")
def score_command(out: Annotated[Path, typer.Argument(help="A sweep folder.")]) -> None:
    """Re-score a sweep from its traces (no model loaded) and rewrite its result files."""

    def go() -> None:
        import asyncio

        from storyteller.benchmark.sweep.runner import score_sweep
        from storyteller.orchestrator.terminal import say

        results = asyncio.run(score_sweep(out))
        say(f"{len(results)} runs re-scored, {sum(r.verdict == 'pass' for r in results)} passed")

    _guard(go)


@bench.command("report")
def report_command(out: Annotated[Path, typer.Argument(help="A sweep folder.")]) -> None:
    """Rebuild results.csv, report.md and the plots from results.jsonl."""

    def go() -> None:
        from storyteller.benchmark.sweep.runner import report_sweep
        from storyteller.orchestrator.terminal import say

        results = report_sweep(out)
        say(f"report of {len(results)} runs: {out / 'report.md'}")

    _guard(go)

"""Drive a sweep: resume, describe each scene once, run the pending runs, write the reports.

Folder layout (``--out DIR``)::

    DIR/sweep.json                          the grid (a restart must give the same arguments)
    DIR/results.jsonl                       one line per finished run (appended, fsync'd)
    DIR/results.csv, DIR/report.md, DIR/plots/*.png
    DIR/descriptions/<scene>-<model>.json   the scene description every describer run reads
    DIR/traces/descriptions/<scene>-<model>.jsonl, DIR/traces/runs/<run_id>.jsonl

Resume: the runs with a line in ``results.jsonl`` are skipped; every other run starts from
scratch (its trace, possibly cut short by the kill, is deleted first). A description is
reused when its JSON file exists (written after its trace is closed), otherwise redone.
When every run has a line, ``results.jsonl`` is rewritten in grid order and the reports are
written. :func:`score_sweep` replays every trace instead (no model) and writes the same files.

Runs execute ``jobs`` at a time in one event loop (API models answer concurrently; the
embedded model serialises its calls behind its own lock, ``storyteller.orchestrator.llm.local_model``),
or as Ray tasks (:mod:`storyteller.benchmark.sweep.ray_executor`). Pending runs go in
:func:`shared_prompt_order` (runs of one scene and tags together, so the embedded model's
prompt cache is warm for all but the first of them).
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Awaitable, Callable, Sequence
from pathlib import Path
from typing import Protocol

from storyteller.agents.messages import SceneDescription
from storyteller.benchmark.sweep.execute import (
    PortFactory,
    SweepWorkspace,
    describe,
    execute,
    record_port,
    replay_port,
)
from storyteller.benchmark.sweep.grid import (
    OURS_REF_SPLITS,
    OURS_SPLITS,
    CaseSetSpec,
    RunKey,
    SweepSpec,
    SweepSpecError,
    case_set_for,
    expand,
)
from storyteller.benchmark.sweep.results import (
    RunResult,
    append_result,
    read_results,
    repair_results,
    write_atomic,
    write_results,
)
from storyteller.benchmark.sweep.sweep_files import (
    parse_json_model,
    read_json_model,
    read_sweep_bytes,
    sweep_folder,
)
from storyteller.sim.no_follow_writes import remove_stale_temporaries


class Progress(Protocol):
    """What the driver tells a progress display."""

    def start(self, total: int, done: Sequence[RunResult]) -> None: ...

    def advance(self, result: RunResult) -> None: ...

    def close(self) -> None: ...


class NoProgress:
    def start(self, total: int, done: Sequence[RunResult]) -> None:
        return None

    def advance(self, result: RunResult) -> None:
        return None

    def close(self) -> None:
        return None


RunAll = Callable[[SweepWorkspace, list[RunKey], dict[str, SceneDescription], Callable[[RunResult], None]], Awaitable[None]]
"""An executor: run every key, calling back with each result as it finishes."""


def sweep_file(out: Path) -> Path:
    return out / "sweep.json"


def save_or_check_spec(spec: SweepSpec, out: Path) -> None:
    """Write ``sweep.json``, or check that the one there describes the same sweep
    (:meth:`SweepSpec.decisive`: the same arguments, wherever the cases and the config file
    are now; the file is then rewritten with the current locations)."""
    path = sweep_file(out)
    text = spec.model_dump_json(indent=1) + "\n"
    if path.exists():
        raw = read_sweep_bytes(path)
        old = parse_json_model(raw, SweepSpec, str(path))
        mine, theirs = spec.decisive(), old.decisive()
        if mine != theirs:
            field = next((k for k in mine if mine[k] != theirs.get(k)), "?")
            raise SweepSpecError(f"{path}: this folder holds a sweep with other arguments (field '{field}' differs); "
                                 "rerun with the same arguments to resume, or choose another --out")
        if raw == text.encode("utf-8"):
            return
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(path, text.encode("utf-8"))


def load_spec(out: Path) -> SweepSpec:
    """``sweep.json`` of ``out``, with the ``reference`` and ``ours`` case sets found where they
    are on this machine when the recorded folders are not here (a published sweep scored
    elsewhere)."""
    path = sweep_file(out)
    if not path.exists():
        raise SweepSpecError(f"{out}: not a sweep folder (no sweep.json)")
    return relocated(read_json_model(path, SweepSpec))


def relocated(spec: SweepSpec) -> SweepSpec:
    """``spec`` with each missing ``reference`` / ``ours`` case folder (or scene folder) replaced
    by this machine's (``$STORYTELLER_REFERENCE``, ``benchmark/cases/ours``); others stay as
    recorded. The reference data is looked for only by the case sets that need it
    (:func:`~storyteller.benchmark.sweep.grid.case_set_for`): ``ours`` relocates without it; a case set
    that needs it while it is absent stays as recorded (``bench report`` needs no case)."""
    if all(_here(c) for c in spec.case_sets):
        return spec
    from storyteller.orchestrator.reference_data import ReferenceDataNotFound, locate_reference

    reference = locate_reference()
    ours = Path(__file__).resolve().parents[1] / "cases" / "ours"

    def here_now(c: CaseSetSpec) -> CaseSetSpec:
        if c.name not in ("reference", "ours", *OURS_SPLITS, "ours-ref", *OURS_REF_SPLITS) or _here(c):
            return c
        try:
            return case_set_for(c.name, reference, ours)
        except ReferenceDataNotFound:
            return c

    return spec.model_copy(update={"case_sets": tuple(here_now(c) for c in spec.case_sets)})


def _here(case_set: CaseSetSpec) -> bool:
    """Whether the case set's folders are on this machine."""
    return Path(case_set.path).is_dir() and (case_set.scenes_root is None or Path(case_set.scenes_root).is_dir())


def grid(ws: SweepWorkspace) -> list[RunKey]:
    return expand(ws.spec, {name: sorted(cases) for name, cases in ws.cases.items()})


def shared_prompt_order(ws: SweepWorkspace, keys: Sequence[RunKey]) -> list[RunKey]:
    """``keys`` in the order they run: the runs whose prompts open alike one after another.

    A run's system prompts are fixed by its model, method, scene (description and action labels)
    and tags (in-context examples); the embedded model keeps the KV cache of each role's last
    prompt (``storyteller.orchestrator.llm.local_model``), so a run after one of the same group reads only
    its own request, not the whole prompt again. Groups keep the grid order of their first run,
    runs within a group their grid order; results are written in grid order whatever the order
    they ran in (:func:`finish`)."""

    def group(key: RunKey) -> tuple[str, str, str, tuple[str, ...]]:
        case = ws.cases[key.case_set][key.case]
        return key.model, key.method, case.scene_name, case.tags

    first: dict[tuple[str, str, str, tuple[str, ...]], int] = {}
    for i, key in enumerate(keys):
        first.setdefault(group(key), i)
    return sorted(keys, key=lambda k: first[group(k)])


async def descriptions_for(
    ws: SweepWorkspace, keys: list[RunKey], factory: PortFactory, *, replay: bool
) -> dict[str, SceneDescription]:
    """The description of every (scene, model) the describer runs among ``keys`` need: read
    from the sweep folder, else made (recorded) or, with ``replay``, replayed from its trace."""
    out: dict[str, SceneDescription] = {}
    for dkey, (run, _) in sorted(ws.description_needs(keys).items()):
        file, trace = ws.description_file(dkey), ws.description_trace(dkey)
        if file.exists() and not replay:
            out[dkey] = read_json_model(file, SceneDescription)
            continue
        if replay and not trace.exists():
            raise SweepSpecError(f"{trace}: missing (the sweep never described this scene for this model)")
        if not replay:
            sweep_folder(ws.out, "traces", "descriptions")
            trace.unlink(missing_ok=True)
        port = factory(ws.spec.model(run.model), trace)
        try:
            out[dkey] = await describe(ws, run, port)
        finally:
            port.close()
        if not replay:
            sweep_folder(ws.out, "descriptions")
            write_atomic(file, out[dkey].model_dump_json(indent=1).encode("utf-8") + b"\n")
    return out


def local_executor(jobs: int, factory: PortFactory, *, fresh: bool) -> RunAll:
    """Run keys ``jobs`` at a time in this process's event loop."""

    async def run_all(ws: SweepWorkspace, keys: list[RunKey], descriptions: dict[str, SceneDescription],
                      done: Callable[[RunResult], None]) -> None:
        from storyteller.benchmark.sweep.execute import description_key

        gate = asyncio.Semaphore(max(1, jobs))

        async def one(key: RunKey) -> None:
            async with gate:
                scene_name = ws.cases[key.case_set][key.case].scene_name
                desc = descriptions.get(description_key(scene_name, key.model))
                done(await execute(ws, key, factory, desc, fresh=fresh))

        await asyncio.gather(*(one(k) for k in keys))

    return run_all


def finish(ws: SweepWorkspace, results: list[RunResult]) -> None:
    """Rewrite ``results.jsonl`` in grid order and write the reports from it."""
    from storyteller.benchmark.sweep.report import write_reports

    order = {k.run_id: i for i, k in enumerate(grid(ws))}
    ordered = sorted(results, key=lambda r: order[r.run_id])
    write_results(ws.out / "results.jsonl", ordered)
    write_reports(ws.out, ws.spec, ordered)


async def run_sweep(
    spec: SweepSpec, out: Path, *, jobs: int = 1, factory: PortFactory = record_port,
    progress: Progress | None = None, executor: RunAll | None = None,
) -> list[RunResult]:
    """Run (or resume) the sweep in ``out``; returns every run's result in grid order."""
    spec.check()
    save_or_check_spec(spec, out)
    ws = SweepWorkspace(spec, out)
    sweep_folder(out, "plots")  # a link there is refused before a run is made
    for folder in (out, out / "plots", out / "descriptions"):  # what a sweep killed mid-write left
        remove_stale_temporaries(folder)
    keys = grid(ws)
    path = out / "results.jsonl"
    repair_results(path)
    finished = {r.run_id: r for r in read_results(path) if r.run_id in {k.run_id for k in keys}}
    pending = shared_prompt_order(ws, [k for k in keys if k.run_id not in finished])
    progress = progress or NoProgress()
    descriptions = await descriptions_for(ws, pending, factory, replay=False)
    progress.start(len(keys), list(finished.values()))  # after the descriptions: the ETA is the runs' pace
    try:

        def done(result: RunResult) -> None:
            append_result(path, result)
            finished[result.run_id] = result
            progress.advance(result)

        run_all = executor or local_executor(jobs, factory, fresh=True)
        await run_all(ws, pending, descriptions, done)
    finally:
        progress.close()
    results = list(finished.values())
    finish(ws, results)
    return read_results(path)


async def score_sweep(out: Path, *, factory: PortFactory = replay_port) -> list[RunResult]:
    """Re-score every run of ``out`` that has a result line by replaying its trace (no model
    loaded) and rewrite ``results.jsonl`` and the reports from the new verdicts."""
    spec = load_spec(out)
    ws = SweepWorkspace(spec, out)
    sweep_folder(out, "plots")  # a link there is refused before any file is rewritten
    for folder in (out, out / "plots", out / "descriptions"):  # what a sweep killed mid-write left
        remove_stale_temporaries(folder)
    listed = {r.run_id for r in read_results(out / "results.jsonl")}
    keys = [k for k in grid(ws) if k.run_id in listed]
    for k in keys:
        if not ws.run_trace(k).exists():
            raise SweepSpecError(f"{ws.run_trace(k)}: missing trace of a finished run")
    descriptions = await descriptions_for(ws, keys, factory, replay=True)
    results: list[RunResult] = []
    await local_executor(1, factory, fresh=False)(ws, keys, descriptions, results.append)
    finish(ws, results)
    return read_results(out / "results.jsonl")


def report_sweep(out: Path) -> list[RunResult]:
    """Rebuild ``results.csv``, ``report.md`` and the plots from ``results.jsonl``."""
    from storyteller.benchmark.sweep.report import write_reports

    spec = load_spec(out)
    results = read_results(out / "results.jsonl")
    write_reports(out, spec, results)
    return results


def describe_spec(spec: SweepSpec) -> str:
    """One line naming the sweep (for logs)."""
    return json.dumps({"case_sets": [c.name for c in spec.case_sets], "levels": spec.levels, "repeats": spec.repeats,
                       "methods": spec.methods, "models": [m.label for m in spec.models], "feedback": spec.feedback})

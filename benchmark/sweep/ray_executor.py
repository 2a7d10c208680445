"""``--executor ray``: the sweep's pending runs as Ray tasks, on this machine or a cluster.

Each run is one task (:func:`run_task`) that does exactly what the local executor does for it
(:func:`storyteller.benchmark.sweep.execute.execute`: delete a partial trace, run the planning step with a
port recording to the run's trace file, score it) and returns the result line; the driver
appends each line to ``results.jsonl`` as its task finishes, so resume, ``bench score`` and the
reports are the same as with the local executor. The sweep folder must be on storage every
node sees (a shared filesystem), since tasks write their traces there. At most ``jobs`` tasks
are in flight. Ray is an optional dependency (``pip install 'storyteller[ray]'``); it is
imported only when this executor runs.

The embedded model is loaded once per worker process and its lock is per process: with a
local model, keep ``--jobs`` at the number of workers whose memory can hold it.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

from storyteller.agents.messages import SceneDescription
from storyteller.benchmark.sweep.execute import (
    PortFactory,
    SweepWorkspace,
    description_key,
    execute,
    record_port,
)
from storyteller.benchmark.sweep.grid import RunKey, SweepSpec
from storyteller.benchmark.sweep.results import RunResult
from storyteller.benchmark.sweep.runner import RunAll


def run_task(spec_json: str, out: str, key_json: str, description_json: str | None, factory: PortFactory) -> str:
    """One run, in a Ray worker: the result line as JSON."""
    from pathlib import Path

    ws = SweepWorkspace(SweepSpec.model_validate_json(spec_json), Path(out))
    description = SceneDescription.model_validate_json(description_json) if description_json else None
    result = asyncio.run(execute(ws, RunKey.model_validate_json(key_json), factory, description, fresh=True))
    return result.model_dump_json()


def ray_executor(jobs: int, *, address: str | None = None, factory: PortFactory = record_port) -> RunAll:
    """An executor running each key as a Ray task (``ray.init(address)``; None: a local Ray)."""
    try:
        import ray
    except ImportError:
        from storyteller.benchmark.sweep.grid import SweepSpecError

        raise SweepSpecError("--executor ray needs Ray: pip install 'storyteller[ray]'") from None

    async def run_all(ws: SweepWorkspace, keys: list[RunKey], descriptions: dict[str, SceneDescription],
                      done: Callable[[RunResult], None]) -> None:
        if not keys:
            return
        if not ray.is_initialized():
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
        task: Any = ray.remote(num_cpus=1, max_retries=0)(run_task)
        gate = asyncio.Semaphore(max(1, jobs))
        spec_json, out = ws.spec.model_dump_json(), str(ws.out.resolve())

        async def one(key: RunKey) -> None:
            async with gate:
                desc = descriptions.get(description_key(ws.cases[key.case_set][key.case].scene_name, key.model))
                line = await task.remote(spec_json, out, key.model_dump_json(),
                                         desc.model_dump_json() if desc else None, factory)
                done(RunResult.model_validate_json(line))

        await asyncio.gather(*(one(k) for k in keys))

    return run_all

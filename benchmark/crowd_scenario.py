"""The world benchmarks' crowd scenario: walkers on random errands in the reference Office
(``IdleErrands``), the larger layouts made of Office copies (``tiled``: "Office x4", "Office x16"),
and the spread-out cell picks both use (``spread_cells``). Deterministic for a seed.

Used by ``benchmark/bench_world.py``, ``bench_world_overhead.py``, ``bench_motion_step.py`` and
``benchmark/motion_metrics``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from storyteller.orchestrator.reference_data import locate_reference
from storyteller.sim.paths.nav_grid import NavGrid
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.events import AssignEvent, Assignment

REFERENCE = locate_reference()  # absent: the scripts exit with REFERENCE.reason
OFFICE = REFERENCE.path / "configs" / "scenes" / "Office"


def tiled(scene: Scene, nx: int, ny: int) -> Scene:
    """``nx`` x ``ny`` copies of ``scene`` side by side (objects renamed, overrides dropped)."""
    (x0, y0), (x1, y1) = scene.bounds_min, scene.bounds_max
    w, h = x1 - x0, y1 - y0
    objs = []
    next_idx: dict[str, int] = {}
    for a in range(nx):
        for b in range(ny):
            for o in scene.objects:
                k = next_idx.get(o.label, 0)
                next_idx[o.label] = k + 1
                c = (o.center[0] + a * w, o.center[1] + b * h, o.center[2])
                objs.append(o.model_copy(update={"name": f"{o.label}_{k}", "idx": k, "center": c}))
    return Scene(name=f"{scene.name} x{nx * ny}", bounds_min=(x0, y0), bounds_max=(x0 + nx * w, y0 + ny * h),
                 objects=tuple(objs), nav=scene.nav.model_copy(update={"occupied": (), "unoccupied": ()}))


class Stamps:
    """How many taken cells lie within 1 cell (Chebyshev) of each grid cell: a cell is at least
    2 cells from every taken one when its count is 0. Adding or removing a taken cell is O(1)."""

    def __init__(self, cells: np.ndarray) -> None:
        self.count = np.zeros((int(cells[:, 0].max()) + 3, int(cells[:, 1].max()) + 3), dtype=np.int64)

    def add(self, c: np.ndarray, k: int = 1) -> None:
        i, j = int(c[0]), int(c[1])  # count[i + 1, j + 1] belongs to cell (i, j)
        if -1 <= i < self.count.shape[0] - 1 and -1 <= j < self.count.shape[1] - 1:  # else: blocks no cell
            self.count[max(0, i): i + 3, max(0, j): j + 3] += k

    def free(self, cells: np.ndarray) -> np.ndarray:
        return np.asarray(self.count[cells[:, 0] + 1, cells[:, 1] + 1] == 0)


def spread_cells(cells: np.ndarray, count: int, rng: np.random.Generator, taken: list[np.ndarray] | Stamps,
                 ) -> list[np.ndarray]:
    """``count`` cells of ``cells`` (rows (i, j)) in the order of one random permutation, each at
    least 2 cells (Chebyshev) from ``taken`` and from the ones picked before it (``taken``
    given as ``Stamps`` is left as it was). O(1) per candidate, not O(len(taken)); candidates
    are tested in chunks of the permutation, so one pick does not test every cell of a large
    layout (the permutation itself is drawn whole: the generator's draws stay the same)."""
    out: list[np.ndarray] = []
    perm = rng.permutation(len(cells))
    if count <= 0:
        return out
    stamps = taken if isinstance(taken, Stamps) else Stamps(cells)
    if not isinstance(taken, Stamps):
        for o in taken:
            stamps.add(o)
    chunk = 64  # candidates checked per vectorised test: usually the first chunk has a free one
    for lo in range(0, len(perm), chunk):
        part = perm[lo: lo + chunk]
        for k in part[stamps.free(cells[part])]:
            c = cells[k]
            if stamps.count[c[0] + 1, c[1] + 1] == 0:
                out.append(c)
                if len(out) == count:
                    break
                stamps.add(c)
        if len(out) == count:
            break
    if taken is stamps:
        for c in out[:-1]:
            stamps.add(c, -1)
    if len(out) == count:
        return out
    raise SystemExit(f"only {len(out)} of {count} characters fit 2 cells apart")


class IdleErrands:
    """The benchmark's crowd scenario: ``n`` walkers start on spread-out cells (2 cells
    apart); whenever a walker's event loops or fails it gets a new ``idle`` event at a random
    free cell 2 cells from everyone's target, facing a random direction. Deterministic for a
    seed (one generator draws the starts, then every target in order)."""

    def __init__(self, grid: NavGrid, n: int, seed: int) -> None:
        self.grid = grid
        self.cells = np.argwhere(grid.component == grid.main_component)
        self.rng = np.random.default_rng(seed)
        starts = spread_cells(self.cells, n, self.rng, [])
        self.names = [f"p{i:03d}" for i in range(n)]
        self.starts = {nm: (tuple(grid.center_of(*c)), 0.0) for nm, c in zip(self.names, starts, strict=True)}
        self.targets = dict(zip(self.names, starts, strict=True))
        self.stamps = Stamps(self.cells)  # every walker's current target
        for c in starts:
            self.stamps.add(c)
        self.count = dict.fromkeys(self.names, 0)
        self.todo = set(self.names)

    def commands(self) -> list[AssignEvent]:
        """New events for the walkers that need one (then none until ``observe`` says so)."""
        cmds = []
        for nm in sorted(self.todo):
            self.stamps.add(self.targets[nm], -1)  # 2 cells from every other walker's target
            cell = spread_cells(self.cells, 1, self.rng, self.stamps)[0]
            self.stamps.add(cell)
            self.targets[nm] = cell
            self.count[nm] += 1
            theta = float(self.rng.uniform(-math.pi, math.pi))
            cmds.append(AssignEvent(event_id=f"{nm}-{self.count[nm]}", assignments=(Assignment(
                character=nm, action="idle", target_xy=tuple(self.grid.center_of(*cell)),
                facing_xy=(math.cos(theta), math.sin(theta))),)))
        self.todo = set()
        return cmds

    def observe(self, out: Any) -> None:
        """Walkers whose event looped or failed in this step's output need a new one."""
        self.todo = {e.rsplit("-", 1)[0] for e in out.looping_events} | {f.character for f in out.failures}

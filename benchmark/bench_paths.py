"""Path planning time per replan: WHCA* vs a full-horizon prioritized space-time A* baseline.

Run: ``python -m storyteller.benchmark.bench_paths [--repeats 3]``. Reference Office scene (0.3 m cells,
r = 0.25 m). For N characters on random, well-separated starts and goals, one replan of all
of them with the windowed planner (window 20) next to the same planner without a window
(window = 150 steps, i.e. full horizon for this scene), measured in the same run; prints
milliseconds (CPU time) and the ratio, plus the windowed planner with the pure-Python backend
(``backend="python"``: the speed-up of the compiled search, same plans checked). The Office's main room holds at most ~130 bodies
0.5 m apart, so larger N are capped (printed).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from storyteller.orchestrator.reference_data import locate_reference
from storyteller.sim.paths.cooperative_astar import Agent, Cell, PathPlanner
from storyteller.sim.paths.nav_grid import build_nav_grid, with_reference_grid_origin
from storyteller.sim.scene.files import load_scene

REFERENCE = locate_reference()  # absent: main() exits with REFERENCE.reason
OFFICE = REFERENCE.path / "configs" / "scenes" / "Office"


def _spaced(cells: list[Cell], n: int, rng: np.random.Generator) -> list[Cell]:
    out: list[tuple[int, int]] = []
    for k in rng.permutation(len(cells)):
        c = cells[k]
        if all(max(abs(c[0] - o[0]), abs(c[1] - o[1])) >= 2 for o in out):
            out.append(c)
            if len(out) == n:
                break
    return out


def _time(
    planner: PathPlanner, starts: dict[Agent, Cell], goals: dict[Agent, Cell], repeats: int
) -> tuple[float, int]:
    best = float("inf")
    failed = 0
    for _ in range(repeats):
        t = time.process_time()
        result = planner.plan(starts, goals, t0=0)
        best = min(best, time.process_time() - t)
        failed = len(result.failed)
    return best * 1000.0, failed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if not REFERENCE.found:
        raise SystemExit(REFERENCE.reason)
    grid = build_nav_grid(with_reference_grid_origin(load_scene(OFFICE), OFFICE))
    cells: list[Cell] = [(int(i), int(j)) for i, j in np.argwhere(grid.component == grid.main_component)]
    whca = PathPlanner(grid, window=20, seed=args.seed)
    full = PathPlanner(grid, window=150, max_expansions=200_000, seed=args.seed)
    python = PathPlanner(grid, window=20, seed=args.seed, backend="python")
    for planner in (whca, full):  # load (or compile) the search kernels outside the timings
        planner.plan({0: cells[0]}, {0: cells[-1]})
    print(f"Office: {len(cells)} free cells in the main room, cell {grid.cell_size} m, r {grid.body_radius} m")
    print(f"{'N':>5} {'placed':>6} {'WHCA* ms':>9} {'full ms':>9} {'ratio':>7} {'fail W/F':>9} {'python ms':>10} {'ratio':>7} same")
    for n in (1, 10, 50, 200):
        rng = np.random.default_rng([args.seed, n])
        st = _spaced(cells, n, rng)
        gl = _spaced(cells, len(st), rng)
        m = min(len(st), len(gl))
        starts: dict[Agent, Cell] = {a: st[a] for a in range(m)}
        goals: dict[Agent, Cell] = {a: gl[a] for a in range(m)}
        for g in goals.values():  # heuristics are cached per goal; warm them for both
            whca.heuristic(g)
            full.heuristic(g)
            python.heuristic(g)
        tw, fw = _time(whca, starts, goals, args.repeats)
        tf, ff = _time(full, starts, goals, args.repeats)
        tp, _ = _time(python, starts, goals, args.repeats)
        same = whca.plan(starts, goals, t0=0) == python.plan(starts, goals, t0=0)
        print(f"{n:>5} {m:>6} {tw:>9.1f} {tf:>9.1f} {tf / max(tw, 1e-9):>6.1f}x {fw:>4}/{ff:<4} "
              f"{tp:>10.1f} {tp / max(tw, 1e-9):>6.1f}x {'yes' if same else 'NO'}")


if __name__ == "__main__":
    main()

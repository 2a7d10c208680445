"""Command start-up: how long each ``storyteller`` command takes to import and run, next to a
bare Python start-up and typer's own import.

Every sample is a fresh interpreter (``subprocess``), timed from the parent with the wall
clock, so it includes interpreter start-up, the imports and the command itself. Each case runs
``--repeats`` times, interleaved (case A, B, C, A, B, C, ...) so that a busy machine disturbs
all cases alike; the fastest and the median are printed, and the fastest minus the bare start-up
("over python"). The target (issue 14): ``storyteller --help`` within 0.5 s of ``python -c
pass`` plus ``import typer``.

``--importtime`` also runs each command once under ``python -X importtime`` and prints the
slowest top-level imports (cumulative), to find the module that made a command slow.

Figures (2026-12-03, ``--repeats 7``, quiet 2-core machine, fastest): ``python -c pass`` 0.042 s,
``import typer`` 0.090 s, ``storyteller --help`` 0.230 s (target 0.590 s: met), ``scene list``
0.329 s, ``model info`` 0.379 s, ``run --help`` 0.422 s, ``plan --help`` 0.457 s; importing the
planning graph (what ``run`` needs before its first step) 1.518 s.

Usage: ``python -m storyteller.benchmark.bench_startup [--repeats 7] [--importtime] [--top 8]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = "import sys; from storyteller.orchestrator.cli.app import app; app(sys.argv[1:])"

# (label, python arguments): the baselines first, then the commands.
CASES: list[tuple[str, list[str]]] = [
    ("python -c pass", ["-c", "pass"]),
    ("import typer", ["-c", "import typer"]),
    ("storyteller --help", ["-c", CLI, "--help"]),
    ("storyteller scene list", ["-c", CLI, "scene", "list"]),
    ("storyteller model info", ["-c", CLI, "model", "info"]),
    ("storyteller plan --help", ["-c", CLI, "plan", "--help"]),
    ("storyteller run --help", ["-c", CLI, "run", "--help"]),
    ("import planning graph", ["-c", "import storyteller.orchestrator.planning.graph"]),
]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    return env


def time_once(args: list[str], env: dict[str, str], cwd: str) -> float:
    """Wall seconds of one fresh interpreter running ``args``; a failing command is an error."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, *args], env=env, cwd=cwd, capture_output=True, text=True)
    elapsed = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{args}: exit code {proc.returncode}\n{proc.stderr[-2000:]}")
    return elapsed


def slowest_imports(args: list[str], env: dict[str, str], cwd: str, top: int) -> list[tuple[float, str]]:
    """(cumulative seconds, module) of the ``top`` slowest top-level imports under ``-X importtime``."""
    proc = subprocess.run(
        [sys.executable, "-X", "importtime", *args], env=env, cwd=cwd, capture_output=True, text=True
    )
    rows: list[tuple[float, str]] = []
    for line in proc.stderr.splitlines():
        if not line.startswith("import time:") or "cumulative" in line:
            continue
        _, cumulative, name = line.removeprefix("import time:").split("|")
        if name.startswith("  "):  # nested under another import: counted in its parent
            continue
        rows.append((int(cumulative) / 1e6, name.strip()))
    return sorted(rows, reverse=True)[:top]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=7, help="Fresh interpreters per case.")
    ap.add_argument("--importtime", action="store_true", help="Also list each command's slowest imports.")
    ap.add_argument("--top", type=int, default=8, help="Imports listed per command with --importtime.")
    args = ap.parse_args(argv)

    env = _env()
    with tempfile.TemporaryDirectory() as cwd:
        samples: dict[str, list[float]] = {label: [] for label, _ in CASES}
        for _ in range(args.repeats):
            for label, case in CASES:
                samples[label].append(time_once(case, env, cwd))
        bare = min(samples["python -c pass"])
        typer_only = min(samples["import typer"])
        print(f"{'case':28s} {'fastest s':>10s} {'median s':>10s} {'over python':>12s}")
        for label, _ in CASES:
            fastest, median = min(samples[label]), statistics.median(samples[label])
            print(f"{label:28s} {fastest:10.3f} {median:10.3f} {fastest - bare:+12.3f}")
        help_s = min(samples["storyteller --help"])
        budget = bare + (typer_only - bare) + 0.5
        print(
            f"\nstoryteller --help: {help_s:.3f} s; target <= python + typer import + 0.5 s = "
            f"{budget:.3f} s: {'met' if help_s <= budget else 'NOT met'} "
            f"({args.repeats} repeats, fastest)"
        )
        if args.importtime:
            for label, case in CASES[2:]:
                print(f"\nslowest imports of {label} (cumulative s):")
                for seconds, name in slowest_imports(case, env, cwd, args.top):
                    print(f"  {seconds:7.3f}  {name}")


if __name__ == "__main__":
    main()

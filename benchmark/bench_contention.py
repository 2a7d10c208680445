"""The README story on the machine as it is, then with one core kept busy by another process, in one run.

Each run is the README's main command without ``--video``::

    storyteller run home -n 2 -i "Ava makes coffee, then sits on the couch and drinks it." \\
        --duration 60 --max-events 4 --out <tmp>

in a fresh interpreter, timed from here with the wall clock. The first run gets the machine as
it is ("quiet"); for the second, a ``python -c "while True: pass"`` process is started and pinned
(``os.sched_setaffinity``) to the last of the cores this process may use, and stopped when the
run ends. For each run the script prints the wall time, the exit code, the embedded model's
thread choices (``metrics.json``: ``llm.local_threads``) and whether the story follows the
instruction: the story-suite scenario ``home_coffee_then_couch`` judges ``story.json`` (Ava
uses the coffee maker close to coffee_maker_1, then drinks seated on couch_1, in that order;
Ben not idle is shown, not required). Then the ratio busy / quiet against the target of issue
23 (the busy run finishes, follows the instruction and takes at most 1.5x the quiet one).

The 1-minute load average is printed before and after each run: other work on the machine
(other engineers share its cores) makes both times longer and the "quiet" run not quiet.
Figures belong in ``benchmark/results/``, not here.

Usage: ``python -m storyteller.benchmark.bench_contention [--keep DIR] [--threads N]`` (``--threads`` sets
``STORYTELLER_LOCAL_THREADS`` for both runs, to compare with a fixed choice).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from storyteller.orchestrator.child_process import stop_child

ROOT = Path(__file__).resolve().parents[1]
CLI = "import sys; from storyteller.orchestrator.cli.app import app; app(sys.argv[1:])"
INSTRUCTION = "Ava makes coffee, then sits on the couch and drinks it."
STORY_ARGS = ["run", "home", "-n", "2", "-i", INSTRUCTION, "--duration", "60", "--max-events", "4"]
SCENARIO = "home_coffee_then_couch"
REQUIRED_KINDS = ("does", "order")  # the scenario's expectations that are the instruction (not "not_idle")
TARGET_RATIO = 1.5
RUN_TIMEOUT_S = 3600.0


@dataclass(frozen=True)
class StoryRun:
    label: str
    wall_s: float
    exit_code: int
    load_before: float
    load_after: float
    threads: dict[str, Any] | None
    verdicts: dict[str, tuple[str, bool, str]]  # expectation id -> (kind, met, reason)
    error: str

    @property
    def follows(self) -> bool:
        required = [met for kind, met, _ in self.verdicts.values() if kind in REQUIRED_KINDS]
        return bool(required) and all(required)


def _load() -> float:
    return os.getloadavg()[0]


def start_busy_core() -> tuple[subprocess.Popen[bytes], int]:
    """A busy-looping Python process pinned to the last core we may use, and that core."""
    core = max(os.sched_getaffinity(0))
    proc = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    os.sched_setaffinity(proc.pid, {core})
    return proc, core


def judge(out: Path) -> dict[str, tuple[str, bool, str]]:
    """Verdict per expectation of the scenario on the run's story.json (empty when unreadable)."""
    from storyteller.benchmark.story_suite.evaluate import StoryLogError, score_run
    from storyteller.benchmark.story_suite.scenario import SCENARIO_DIR, load_scenario

    try:
        score = score_run(load_scenario(SCENARIO_DIR / f"{SCENARIO}.toml"), out)
    except StoryLogError:
        return {}
    return {v.id: (v.kind, v.met, v.reason) for v in score.verdicts}


def run_story(label: str, out: Path, env: dict[str, str]) -> StoryRun:
    load_before = _load()
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-c", CLI, *STORY_ARGS, "--out", str(out)], env=env, cwd=ROOT,
                              capture_output=True, text=True, timeout=RUN_TIMEOUT_S)
        code, err = proc.returncode, proc.stderr
    except subprocess.TimeoutExpired:
        code, err = -1, f"stopped after {RUN_TIMEOUT_S:.0f} s"
    wall = time.perf_counter() - t0
    threads = None
    metrics = out / "metrics.json"
    if metrics.is_file():
        threads = json.loads(metrics.read_text(encoding="utf-8")).get("llm", {}).get("local_threads")
    last_line = err.strip().splitlines()[-1] if err.strip() else ""
    return StoryRun(label, wall, code, load_before, _load(), threads, judge(out), "" if code == 0 else last_line)


def describe(r: StoryRun) -> list[str]:
    lines = [f"{r.label}: {r.wall_s:.1f} s wall, exit {r.exit_code}, load average {r.load_before:.2f} -> "
             f"{r.load_after:.2f}"]
    if r.error:
        lines.append(f"  error: {r.error}")
    lines.append(f"  threads: {json.dumps(r.threads) if r.threads else 'no local call recorded'}")
    lines.append(f"  follows the instruction: {'yes' if r.follows else 'no'}")
    for key, (kind, met, reason) in r.verdicts.items():
        shown = "" if kind in REQUIRED_KINDS else ", not required"
        lines.append(f"    {key}: {'met' if met else 'NOT met'} ({reason}{shown})")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--keep", type=Path, help="Copy both run folders here (quiet/, busy/).")
    parser.add_argument("--threads", type=int, help="Fix STORYTELLER_LOCAL_THREADS for both runs.")
    args = parser.parse_args(argv)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    env.pop("STORYTELLER_LOCAL_THREADS", None)
    if args.threads is not None:
        env["STORYTELLER_LOCAL_THREADS"] = str(args.threads)
    print(f"cores this process may use: {sorted(os.sched_getaffinity(0))}; command: storyteller "
          f"{' '.join(STORY_ARGS)} --out <tmp>", flush=True)
    with tempfile.TemporaryDirectory(prefix="bench_contention_") as tmp:
        quiet = run_story("quiet", Path(tmp) / "quiet", env)
        print("\n".join(describe(quiet)), flush=True)
        busy_proc, core = start_busy_core()
        try:
            busy = run_story(f"one core busy (core {core}, pid {busy_proc.pid})", Path(tmp) / "busy", env)
        finally:
            stop_child(busy_proc, grace_s=5)
        print("\n".join(describe(busy)), flush=True)
        if args.keep is not None:
            for name in ("quiet", "busy"):
                if (Path(tmp) / name).is_dir():
                    shutil.copytree(Path(tmp) / name, args.keep / name, dirs_exist_ok=True)
    ratio = busy.wall_s / quiet.wall_s if quiet.wall_s > 0 else float("inf")
    met = busy.exit_code == 0 and busy.follows and ratio <= TARGET_RATIO
    print(f"ratio busy / quiet: {ratio:.2f} (target <= {TARGET_RATIO}, busy run finished and follows the "
          f"instruction): {'met' if met else 'NOT met'}")
    return 0 if quiet.exit_code == 0 and busy.exit_code == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())

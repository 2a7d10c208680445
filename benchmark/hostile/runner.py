"""``python -m storyteller.benchmark.hostile_inputs``: an outside attacker's corpus against every file the
CLI reads back, built at run time in a temporary folder, each attack run as a subprocess.

The base is real: a short scripted run (``storyteller.benchmark.motion_metrics.scripted_story``, 3
simulated seconds, no LLM) and a one-run bench sweep of our own case 100 (the same kind of
scripted OpenAI-compatible server on 127.0.0.1). Each attack copies what it needs, breaks one
thing (a planted link or hard link, a FIFO, a link to ``/dev/zero``, deep nesting, huge numbers,
NaN, bytes that are not UTF-8, lone surrogates, control and bidi characters, duplicate keys,
objects of a million keys, compressed files, zip bombs, pickles, huge scenes and meshes, mesh
files naming FIFOs and sparse gigabyte files, instanced and deeply nested glTF nodes, hostile
``STORYTELLER_*`` variables (:attr:`Spec.env`), forged viewer requests) and runs
the command that reads it under an address-space limit (:data:`AS_LIMIT`) and a time limit
(the clean command's time + :data:`SLACK_S`). Both times are wall-clock less the time the
command's main thread waited for a CPU (:mod:`storyteller.benchmark.hostile.judging`): a busy machine does
not fail an attack, a command that works, sleeps or blocks longer does.

The verdict holds the issue's targets (issue 22): within the time, max RSS under 1 GiB; a bad
file is exit 2 with exactly one ``error:`` line on stderr (``expect="bad"``), an attack the
product may also accept is exit 0 or that (``"either"``); never a traceback; no Unicode control
or format character (Cc, Cf, Zl, Zp, but newline and tab) on stdout or stderr; no file written
or changed outside the run folder and the command's own outputs; the canary file that a
successful code execution would create is absent; and a refused command leaves the run folder
as it was (nothing lost).

Prints one table row per attack (kind, attack, exit, judged seconds, seconds waited for a CPU
besides, CPU seconds, max RSS, verdict) and a summary;
exit code 1 when an attack failed. ``--only SUBSTRING`` runs the attacks whose name holds it;
``--keep`` keeps the temporary folder. Several minutes on two cores (a clean ``resume`` takes
about 10 s): a benchmark, not a test. Regression tests for what it found are in ``tests/``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from collections.abc import Callable
from pathlib import Path

from storyteller.benchmark.hostile import (
    costs,
    folder_files,
    inputs,
    meshes,
    models,
    outputs,
    record_values,
    run_folders,
    scenes,
    sweeps,
)
from storyteller.benchmark.hostile.bases import BASE_COMMANDS, build_sweep, workspace
from storyteller.benchmark.hostile.harness import CANARY, CLEAN_PROGRAM, SLACK_S, Attack, Box, Spec
from storyteller.benchmark.hostile.judging import Outcome, digest, judge, run_command, tree_state
from storyteller.benchmark.hostile.viewer import VIEWER_KIND, run_viewer
from storyteller.benchmark.motion_metrics.scripted_story import build_story

ATTACKS: list[Attack] = [*run_folders.ATTACKS, *outputs.ATTACKS, *scenes.ATTACKS, *meshes.ATTACKS, *inputs.ATTACKS,
                         *sweeps.ATTACKS, *models.ATTACKS, *folder_files.ATTACKS, *record_values.ATTACKS,
                         *costs.ATTACKS]
"""Every attack but the viewer's (:func:`run_viewer`), by target."""


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m storyteller.benchmark.hostile_inputs", description=__doc__.splitlines()[0])
    p.add_argument("--only", default="", help="run only the attacks whose kind or name holds this text")
    p.add_argument("--keep", action="store_true", help="keep the temporary folder")
    args = p.parse_args(argv)
    chosen = [a for a in ATTACKS if args.only.lower() in f"{a[0]} {a[1]}".lower()]
    env = {k: v for k, v in os.environ.items() if k not in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL")}
    env["STORYTELLER_SCRIPTED_STORY_KEY"] = "scripted"  # not a secret: the local scripted servers ignore it
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    # the attacked CLI is this checkout's code (the installed package may be another checkout's)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(Path(__file__).resolve().parents[2]), env.get("PYTHONPATH")) if p)
    with workspace(args.keep) as root:
        base = root / "base"
        if build_story(base, seconds=3, names=("Zoe", "Max"), quiet=True) != 0:
            print("error: the base run failed", file=sys.stderr)
            return 2
        sweep = build_sweep(root, env) if any(kind == "bench" for kind, _, _ in chosen) else root
        shutil.copytree(base, root / "clean-resume")
        if sweep != root:
            shutil.copytree(sweep, root / "clean-sweep")
        (root / "clean.py").write_text(CLEAN_PROGRAM, encoding="utf-8")
        clean: dict[str, float] = {}  # the clean command's seconds, measured before its first attack
        outcomes = []
        print(f"{'kind':<11} {'attack':<66} {'exit':>4} {'s':>6} {'queued':>6} {'cpu':>6} {'MiB':>5}  verdict",
              flush=True)
        for i, (kind, name, build) in enumerate(chosen):
            box = Box(root / "attacks" / f"{i:02d}", base, sweep, root / "attacks" / f"{i:02d}" / CANARY)
            outcome = attempt(kind, name, build, box, root, sweep, env, clean)
            outcomes.append(outcome)
            print(row(outcome), flush=True)
        if args.only.lower() in f"{VIEWER_KIND[0]} {VIEWER_KIND[1]}".lower():
            box = Box(root / "attacks" / "viewer", base, sweep, root / "attacks" / "viewer" / CANARY)
            outcome = run_viewer(box, env)
            outcomes.append(outcome)
            print(row(outcome), flush=True)
        failed = [o for o in outcomes if o.problems]
        kinds: dict[str, int] = {}
        for o in outcomes:
            kinds[o.kind] = kinds.get(o.kind, 0) + 1
        print(f"{len(outcomes)} attacks ({', '.join(f'{k} {n}' for k, n in kinds.items())}): "
              f"{len(outcomes) - len(failed)} held, {len(failed)} failed")
        return 1 if failed else 0


def attempt(kind: str, name: str, build: Callable[[Box], Spec], box: Box, root: Path, sweep: Path,
            env: dict[str, str], clean: dict[str, float]) -> Outcome:
    spec = build(box)
    if spec.command not in clean:
        base_run = run_command(BASE_COMMANDS[spec.command](root, box.base, sweep), 600, env, root)
        clean[spec.command] = base_run.judged
        print(f"{'(clean)':<11} {spec.command:<66} {base_run.code!s:>4} {base_run.judged:6.1f} {base_run.queued:6.1f} "
              f"{base_run.cpu:6.1f} {base_run.rss >> 20:5d}", flush=True)
    limit = clean[spec.command] + SLACK_S
    skip = (box.run, *spec.writable, Path(env.get("HOME", "/nonexistent")))
    before_tree = tree_state(root, (*skip, root / "attacks" / "scratch"))
    before_run = digest(box.run)
    run = run_command(spec.argv, limit, {**env, **spec.env}, box.root, spec.stdin)
    code = run.code
    problems = judge(spec, run, limit)
    after_tree = tree_state(root, (*skip, root / "attacks" / "scratch"))
    changed = sorted(k for k in set(before_tree) | set(after_tree) if before_tree.get(k) != after_tree.get(k))
    if changed:
        problems.append("wrote outside the run folder: " + ", ".join(str(Path(c).relative_to(root)) for c in changed[:3]))
    if box.canary.exists():
        problems.append("CODE RAN (canary file created)")
    if code == 2 and before_run and digest(box.run) != before_run:
        problems.append("refused, yet the run folder changed")
    if spec.check_output is not None and (found := spec.check_output(run.stdout + run.stderr)):
        problems.append(found)
    if spec.check is not None and code == 0:
        found = spec.check()
        if found:
            problems.append(found)
    return Outcome(kind, name, code, run.judged, run.rss, problems, run.queued, run.cpu)


def row(o: Outcome) -> str:
    return (f"{o.kind:<11} {o.name[:66]:<66} {o.code!s:>4} {o.seconds:6.1f} {o.queued:6.1f} {o.cpu:6.1f} "
            f"{o.rss >> 20:5d}  {o.verdict}")

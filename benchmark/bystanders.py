"""``python -m storyteller.benchmark.bystanders``: do characters the instruction never names live their own lives?

Over finished runs (issue 23 item 3), per *bystander event* (an applied event, once per
character in it whom the instruction in force never names, ``storyteller.agents.bystanders.never_named``):

- **own**: the character's planned action label is neither the instruction's own activity (the
  labels of the plans of the run's events that carried out a part of the instruction, and the
  labels its parts' words rank first, ``storyteller.agents.bystanders.instruction_activities``) nor the
  label of that character's previous applied event. Target: >= 95% of bystander events.
- **areas**: the distinct scene areas (the describer's clusters, ``storyteller.tools.clusters``) of the
  bystanders' planned objects (the seat, else the first object of the planned area).
- **shared frames**: frames in which more characters act on one single-user object than it has
  places (``storyteller.tools.object_use.shared_use_frames`` over the ``<name>.track.npz`` tracks). Target 0.
- **shared seat frames**: frames in which two seated characters (an ``@seated`` action label)
  sit in one place of a seat (``storyteller.tools.areas.seat_slots``, the nearest within
  :data:`SLOT_REACH_M`): a chair is a single-user object too, though no action label says so.
  Counted apart (the issue's figure is the one above); target 0 as well.

The same counts for characters whose parts of the instruction are over ("done") are printed
apart: the issue's target is about the never named.

Sources: run folders already written (``--runs DIR``: every sub-folder with a ``story.json``),
replays of a recorded story suite (``--traces DIR``, default ``traces/story_suite``: a replay
fails with a replay miss once prompts changed after the recording, and is reported, not
counted), or fresh runs with the configured model (``--fresh DIR``: the story-suite scenarios
matching ``--scenarios``, each with ``--extra N`` more characters than it names, so every one
has bystanders, and ``--events K`` planning steps at least; the runs and their traces are kept
in DIR). Run it from the repository root of
the code to check (the runs are ``storyteller run`` subprocesses).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from storyteller.agents.bystanders import instruction_activities, never_named
from storyteller.agents.event_parser import scene_action_labels
from storyteller.agents.messages import PlannedCharacter
from storyteller.agents.story_text import planned_object
from storyteller.benchmark.story_text_fidelity import (
    replay_suite,
    report_replays,
    report_run_folders,
    run_lines,
    scene_of,
    share,
)
from storyteller.sim.scene.model import Scene
from storyteller.tools.areas import seat_slots
from storyteller.tools.clusters import cluster_objects
from storyteller.tools.object_use import shared_use_frames

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_TRACES = ROOT / "traces" / "story_suite"
TARGET_OWN = 0.95
SLOT_REACH_M = 0.35
"""Metres from a seat place within which a seated character's root is taken to sit in it."""


@dataclass
class RunCheck:
    """The counts of one run folder."""

    name: str
    events: int = 0  # bystander events (never named)
    own: int = 0
    done_events: int = 0  # events of characters whose parts are over
    done_own: int = 0
    areas: set[int] = field(default_factory=set)
    shared_frames: int = 0
    shared_seat_frames: int = 0
    frames: int = 0
    misses: list[str] = field(default_factory=list)
    error: str | None = None


def _instruction_at(story: dict[str, Any], frame: int) -> str:
    said = [i for i in story.get("instructions", []) if int(i.get("frame", 0)) <= frame]
    return str(said[-1]["text"]) if said else str(story.get("instruction", ""))


def check_run(run_dir: Path) -> RunCheck:
    """Count one run folder (see the module docstring)."""
    check = RunCheck(run_dir.name)
    try:
        story = json.loads((run_dir / "story.json").read_text(encoding="utf-8"))
        scene = scene_of(run_dir, story)
    except (OSError, ValueError, KeyError) as exc:
        check.error = f"{run_dir}: {exc}"
        return check
    names = [str(n) for n in story.get("characters", [])]
    labels = scene_action_labels(scene)
    object_labels = sorted(set(scene.labels))
    areas: dict[str, int] = {n: i for i, group in enumerate(cluster_objects(scene)) for n in group}
    plans_of = {int(s["index"]): [PlannedCharacter.model_validate(p) for p in s.get("plans", [])]
                for s in story.get("steps", []) if s.get("kind") == "event"}  # fmt: skip
    events = sorted((e for e in story.get("events", []) if plans_of.get(int(e["index"]))), key=lambda e: int(e["index"]))
    carried: dict[str, set[str]] = {}  # instruction -> labels of the plans that carried out its parts
    for e in events:
        if e.get("part"):
            instruction = _instruction_at(story, int(e["requested_frame"]))
            carried.setdefault(instruction, set()).update(p.action for p in plans_of[int(e["index"])])
    previous: dict[str, str] = {}
    for e in events:
        instruction = _instruction_at(story, int(e["requested_frame"]))
        asked = set(instruction_activities(instruction, names, labels, object_labels)) | carried.get(instruction, set())
        unnamed = set(never_named(instruction, names))
        for plan in plans_of[int(e["index"])]:
            who = plan.character
            repeat = previous.get(who) == plan.action
            own = plan.action not in asked and not repeat
            if who in unnamed:
                check.events += 1
                check.own += own
                obj = planned_object(plan, scene)
                if obj is not None and obj in areas:
                    check.areas.add(areas[obj])
                if not own:
                    why = "the instruction's activity" if plan.action in asked else "a repeat"
                    check.misses.append(f"{e['event_id']}: {who} {plan.action} ({why})")
            elif not e.get("part"):
                check.done_events += 1
                check.done_own += own
            previous[who] = plan.action
    check.shared_frames, check.shared_seat_frames, check.frames = _shared_frames(run_dir, names, scene)
    return check


def shared_seat_frames(labels: Mapping[str, Sequence[str]], positions: Mapping[str, np.ndarray], scene: Scene) -> int:
    """Frames where two seated characters sit in one seat place (module docstring)."""
    slots = np.array([s.position for o in scene.objects if o.is_seat for s in seat_slots(o)], dtype=float).reshape(-1, 2)
    n = min((len(v) for v in labels.values()), default=0)
    if not len(slots) or n == 0:
        return 0
    taken = []  # per character, per frame: the seat place it sits in, or -1
    for name, seq in labels.items():
        d = np.linalg.norm(positions[name][:n, None, :2] - slots[None, :, :], axis=2)
        seated = np.array([str(x).endswith("@seated") for x in seq[:n]])
        taken.append(np.where(seated & (d.min(axis=1) <= SLOT_REACH_M), d.argmin(axis=1), -1))
    places = np.stack(taken)  # (characters, frames)
    return sum(1 for f in range(n) if len(v := places[:, f][places[:, f] >= 0]) != len(set(v.tolist())))


def _shared_frames(run_dir: Path, names: list[str], scene: Scene) -> tuple[int, int, int]:
    """(frames where a single-user object has more users than places, frames where two sit in one
    seat place, frames read)."""
    labels: dict[str, Sequence[str]] = {}
    positions: dict[str, np.ndarray] = {}
    for name in names:
        path = run_dir / f"{name}.track.npz"
        if not path.is_file():
            continue
        with np.load(path, allow_pickle=False) as t:
            labels[name] = [str(x) for x in t["action_labels"]]
            positions[name] = np.asarray(t["root_positions"], dtype=float)[:, :2]
    if not labels:
        return 0, 0, 0
    frames = min(len(v) for v in labels.values())
    shared = len({f for f, _, _ in shared_use_frames(labels, positions, scene)})
    return shared, shared_seat_frames(labels, positions, scene), frames


def report(checks: list[RunCheck]) -> str:
    lines = run_lines(checks, lambda c: (
        f"bystander events of their own {share(c.own, c.events)} over {len(c.areas)} areas; "
        f"done characters {share(c.done_own, c.done_events)}; shared single-user frames {c.shared_frames} of {c.frames}"
        f"; shared seat frames {c.shared_seat_frames}"
    ))
    ok = [c for c in checks if not c.error]
    events = sum(c.events for c in ok)
    own = sum(c.own for c in ok)
    lines.append("")
    lines.append(f"runs: {len(ok)} checked, {len(checks) - len(ok)} unreadable")
    verdict = "" if not events else (" (target met)" if own >= TARGET_OWN * events else f" (target {TARGET_OWN:.0%} not met)")
    lines.append(f"bystander events (never named) neither repeating nor taking the instruction's activity: "
                 f"{share(own, events)}{verdict}")  # fmt: skip
    lines.append(f"  the same for characters whose parts are over: "
                 f"{share(sum(c.done_own for c in ok), sum(c.done_events for c in ok))}")  # fmt: skip
    lines.append(f"  areas per run with bystander events: {[len(c.areas) for c in ok if c.events]}")
    lines.append(f"frames where two characters use one single-user object: {sum(c.shared_frames for c in ok)} "
                 f"of {sum(c.frames for c in ok)} (target 0)")  # fmt: skip
    seats = [f"{c.name} {c.shared_seat_frames}" for c in ok if c.shared_seat_frames]
    lines.append(f"frames where two characters sit in one seat place: {sum(c.shared_seat_frames for c in ok)} "
                 f"of {sum(c.frames for c in ok)} (target 0){': ' + ', '.join(seats) if seats else ''}")  # fmt: skip
    return "\n".join(lines)


def _scenarios(patterns: str) -> list[Any]:
    """The scenarios matching any of the comma-separated globs (each once, in order)."""
    from storyteller.benchmark.story_suite.scenario import load_scenarios

    found = {s.name: s for p in patterns.split(",") if p.strip() for s in load_scenarios(p.strip())}
    return [found[n] for n in sorted(found)]


def fresh_runs(out: Path, pattern: str, extra: int, events: int = 0) -> list[tuple[Path, float, str | None]]:
    """Run the scenarios matching ``pattern`` with ``extra`` more characters (at most 6), at least
    ``events`` planning steps (and 12 simulated seconds per step, at most 120) and the configured
    model, recording each trace in ``out/traces``."""
    from storyteller.benchmark.story_suite.runner import RunOptions, run_args

    done = []
    options = RunOptions(out=out, record=out / "traces")
    (out / "traces").mkdir(parents=True, exist_ok=True)
    for scenario in _scenarios(pattern):
        steps = max(scenario.max_events, min(8, events))
        more = scenario.model_copy(update={
            "characters": min(6, scenario.characters + extra), "max_events": steps,
            "duration": min(120.0, max(scenario.duration, 12.0 * steps)),
        })
        t0 = time.perf_counter()
        proc = subprocess.run(run_args(more, options), capture_output=True, text=True, check=False)
        took = time.perf_counter() - t0
        run_dir = out / scenario.name
        (out / f"{scenario.name}.log").write_text(proc.stdout + proc.stderr, encoding="utf-8")
        said = proc.stderr.strip().splitlines()
        failure = None if proc.returncode == 0 and (run_dir / "story.json").is_file() else (said or ["failed"])[-1][:300]
        print(f"ran {scenario.name} with {more.characters} characters in {took:.0f} s" + (f": {failure}" if failure else ""),
              file=sys.stderr, flush=True)  # fmt: skip
        done.append((run_dir, took, failure))
    return done


def main(argv: list[str] | None = None) -> int:
    doc = __doc__ or ""
    p = argparse.ArgumentParser(prog="python -m storyteller.benchmark.bystanders", description=doc.splitlines()[0])
    source = p.add_mutually_exclusive_group()
    source.add_argument("--traces", type=Path, default=None,
                        help=f"Replay the recorded scenarios in this folder (default: {DEFAULT_TRACES.relative_to(ROOT)}).")  # fmt: skip
    source.add_argument("--runs", type=Path, default=None, help="Check the run folders in this folder; no replay.")
    source.add_argument("--fresh", type=Path, default=None, help="Run the scenarios anew with the model into this folder.")
    p.add_argument("--scenarios", default="*",
                   help="Globs over scenario names, comma-separated (replay and fresh runs; default: all).")
    p.add_argument("--extra", type=int, default=1, help="Fresh runs: characters added beyond the scenario's (default 1).")
    p.add_argument("--events", type=int, default=0, help="Fresh runs: planning steps at least (at most 8; default: the scenario's).")
    p.add_argument("--out", type=Path, default=None, help="Folder for the replayed runs (default: a temporary one).")
    args = p.parse_args(argv)
    from storyteller.benchmark.story_suite.scenario import ScenarioError

    try:
        return _run(args)
    except ScenarioError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def _run(args: argparse.Namespace) -> int:
    if args.runs is not None:
        return report_run_folders(args.runs, check_run, report)
    if args.fresh is not None:
        if args.extra < 0:
            print("error: --extra must be 0 or more", file=sys.stderr)
            return 2
        args.fresh.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        ran = fresh_runs(args.fresh, args.scenarios, args.extra, args.events)
        print(report([check_run(d) if failure is None else RunCheck(d.name, error=f"run failed: {failure}")
                      for d, _, failure in ran]))  # fmt: skip
        print(f"ran {len(ran)} scenarios in {time.perf_counter() - t0:.0f} s wall")
        return 0
    return report_replays(
        args.traces, args.out, "bystanders-",
        lambda traces, out: [r for s in _scenarios(args.scenarios) for r in replay_suite(traces, s.name, out)],
        check_run, lambda name, error: RunCheck(name, error=error), report,
    )

if __name__ == "__main__":
    raise SystemExit(main())

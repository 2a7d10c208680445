"""``python -m storyteller.benchmark.story_text_fidelity``: does the story a person reads say what the plans do?

Replays the story suite's recorded runs (``traces/story_suite/<scenario>.jsonl`` by default,
``--traces DIR`` for another recording such as ``traces/story_suite_1.5b``; no model is loaded,
each replay is a full ``storyteller run --replay``), or reads run folders already written
(``--runs DIR``: every sub-folder with a ``story.json``), and checks

- every applied event's ``text`` against its planning step's plans (``story.json``'s ``steps``):
  for every character it names the planned object (the seat, else the first object of the
  area; its id, label or human name) and an action word of the planned label
  (``storyteller.agents.narrator_words.agrees``);
- every ``narration`` shown: the narrator's words it shows (the event's ``activity``) by
  ``storyteller.agents.narrator_words.says_the_plan``, the judgement that gates them (the above, and no
  other action said, no object id the plans are not about);
- ``story.md``'s prose (the paragraphs before "What went wrong", which lists the simulation's
  and the planner's own messages) holds no raw id of an object whose label is unique in the
  scene.

Prints one line per run and the shares over all of them. The judgement reads only the run
folder's ``story.json``, ``story.md`` and scene (``scene.json``, else the bundled scene named in
``story.json``). Exit code 2 on a bad option; a replay that fails (a replay miss once the
prompts changed after the recording: re-record the suite, or run this from a checkout of the
recording's code) is reported as such, not raised and not counted.

What it shows and what it does not: the event text is built from the plans, so a miss here
means the text lost the plan on its way (a label without its words, an object left unnamed, a
stale ``text``); it does not judge the English. Run it from the repository root of the code to
check: the event-program worker is started with ``python -m`` and imports from the current
folder.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, TypeVar

from storyteller.agents.messages import PlannedCharacter
from storyteller.agents.narrator_words import agrees, says_the_plan
from storyteller.agents.story_text import ObjectNames
from storyteller.sim.scene.model import Scene

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_TRACES = ROOT / "traces" / "story_suite"
PROSE_END = "\n## What went wrong"
C = TypeVar("C")


@dataclass
class RunCheck:
    """The verdicts of one run folder."""

    name: str
    events: int = 0
    faithful: int = 0
    narrations: int = 0
    narrations_faithful: int = 0
    raw_ids: list[str] = field(default_factory=list)
    misses: list[str] = field(default_factory=list)
    error: str | None = None


def scene_of(run_dir: Path, story: dict[str, Any]) -> Scene:
    """A run folder's scene: its ``scene.json``, else the bundled scene ``story.json`` names
    (``storyteller.benchmark.bystanders`` reads runs the same way)."""
    from storyteller.sim.scene.bundled import load_bundled_scene
    from storyteller.sim.scene.files import load_scene_json

    path = run_dir / "scene.json"
    return load_scene_json(path) if path.is_file() else load_bundled_scene(str(story["scene"]))


def prose(markdown: str) -> str:
    """``story.md``'s story: everything before its "What went wrong" section."""
    return markdown.split(PROSE_END, 1)[0]


def raw_ids(markdown: str, scene: Scene) -> list[str]:
    """Ids of uniquely named objects that appear in ``story.md``'s prose (raw or
    markdown-escaped, ``coffee\\_maker\\_1``)."""
    names = ObjectNames(scene)
    told = prose(markdown)
    found = []
    for o in scene.objects:
        if names.unique(o.name):
            pattern = re.escape(o.name).replace("_", r"\\?_")
            if re.search(rf"(?<![A-Za-z0-9_]){pattern}(?![A-Za-z0-9_])", told):
                found.append(o.name)
    return found


def check_run(run_dir: Path) -> RunCheck:
    """Check one run folder (see the module docstring)."""
    check = RunCheck(run_dir.name)
    try:
        story = json.loads((run_dir / "story.json").read_text(encoding="utf-8"))
        markdown = (run_dir / "story.md").read_text(encoding="utf-8")
        scene = scene_of(run_dir, story)
    except (OSError, ValueError, KeyError) as exc:
        check.error = f"{run_dir}: {exc}"
        return check
    plans_of = {s["index"]: [PlannedCharacter.model_validate(p) for p in s.get("plans", [])]
                for s in story["steps"] if s["kind"] == "event"}  # fmt: skip
    for e in story["events"]:
        plans = plans_of.get(e["index"], [])
        text = str(e.get("text") or "")
        check.events += 1
        if agrees(text, plans, scene):
            check.faithful += 1
        else:
            check.misses.append(f"{e['event_id']}: {text!r} for {[(p.action, p.seat or p.area) for p in plans]}")
        if e.get("narration"):
            check.narrations += 1
            said = " ".join(str(e.get("activity") or e["narration"]).split())
            if says_the_plan(said, plans, scene):
                check.narrations_faithful += 1
            else:
                check.misses.append(f"{e['event_id']}: narrator's words shown {said!r} for {[p.action for p in plans]}")
    check.raw_ids = raw_ids(markdown, scene)
    return check


def replay_suite(traces: Path, pattern: str, out: Path) -> list[tuple[Path, float, str | None]]:
    """Replay every recorded scenario in ``traces`` matching ``pattern`` into ``out``: (run
    folder, wall seconds, the failure when the run wrote no story)."""
    from storyteller.benchmark.story_suite.runner import RunOptions, run_args
    from storyteller.benchmark.story_suite.scenario import load_scenarios

    done = []
    options = RunOptions(out=out, replay=traces)
    for scenario in load_scenarios(pattern):
        if not (traces / f"{scenario.name}.jsonl").is_file():
            continue
        t0 = time.perf_counter()
        proc = subprocess.run(run_args(scenario, options), capture_output=True, text=True, check=False)
        took = time.perf_counter() - t0
        run_dir = out / scenario.name
        said = proc.stderr.strip().splitlines()
        last = ([line for line in said if line.startswith("error:")] or said or [f"exit code {proc.returncode}"])[-1]
        failure = None if proc.returncode == 0 and (run_dir / "story.json").is_file() else last[:300]
        print(f"replayed {scenario.name} in {took:.0f} s" + (f": {failure}" if failure else ""), file=sys.stderr, flush=True)
        done.append((run_dir, took, failure))
    return done


def share(part: int, whole: int) -> str:
    """``part/whole (pct%)``, as every line of the run-folder reports shows a share."""
    return f"{part}/{whole} ({100.0 * part / whole:.1f}%)" if whole else "0/0"


class _Checked(Protocol):
    name: str
    misses: list[str]
    error: str | None


K = TypeVar("K", bound=_Checked)


def run_lines(checks: list[K], verdict: Callable[[K], str]) -> list[str]:
    """A report's line per run (``name: error``, else ``name: verdict`` and a line per miss)."""
    lines = []
    for c in checks:
        if c.error:
            lines.append(f"{c.name}: {c.error}")
            continue
        lines.append(f"{c.name}: {verdict(c)}")
        lines += [f"    miss {m}" for m in c.misses]
    return lines


def report(checks: list[RunCheck]) -> str:
    def verdict(c: RunCheck) -> str:
        ids = f", raw ids in story.md: {', '.join(c.raw_ids)}" if c.raw_ids else ""
        return f"text names the plan in {share(c.faithful, c.events)} events; narrator's words shown {c.narrations}{ids}"

    lines = run_lines(checks, verdict)
    ok = [c for c in checks if not c.error]
    events = sum(c.events for c in ok)
    lines.append("")
    lines.append(f"runs: {len(ok)} checked, {len(checks) - len(ok)} unreadable")
    lines.append(f"event text names the planned object and an action word of the planned label: "
                 f"{share(sum(c.faithful for c in ok), events)}")  # fmt: skip
    lines.append(f"narrator's words shown: {sum(c.narrations for c in ok)} of {events} events, agreeing "
                 f"{share(sum(c.narrations_faithful for c in ok), sum(c.narrations for c in ok))}")  # fmt: skip
    lines.append(f"story.md with no raw id of a uniquely named object: {share(sum(not c.raw_ids for c in ok), len(ok))}")
    return "\n".join(lines)


def report_run_folders(runs: Path, check: Callable[[Path], C], report_of: Callable[[list[C]], str]) -> int:
    """``--runs``: ``check`` every sub-folder of ``runs`` with a ``story.json`` and print their
    report; the exit code (2: ``runs`` is not a folder)."""
    if not runs.is_dir():
        print(f"error: --runs {runs}: not a folder", file=sys.stderr)
        return 2
    folders = sorted(d for d in runs.iterdir() if (d / "story.json").is_file())
    print(report_of([check(d) for d in folders]))
    return 0


def report_replays(
    traces: Path | None,
    out: Path | None,
    prefix: str,
    replay: Callable[[Path, Path], list[tuple[Path, float, str | None]]],
    check: Callable[[Path], C],
    failed: Callable[[str, str], C],
    report_of: Callable[[list[C]], str],
) -> int:
    """``--traces``: ``replay`` the recorded runs of ``traces`` (default: the story suite's) into
    ``out`` (default: a temporary folder named with ``prefix``), ``check`` each run that wrote a
    story (``failed(name, error)`` for one that did not) and print their report; the exit code
    (2: ``traces`` is not a folder)."""
    traces = traces if traces is not None else DEFAULT_TRACES
    if not traces.is_dir():
        print(f"error: --traces {traces}: not a folder of recorded runs", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
        folder = out if out is not None else Path(tmp)
        t0 = time.perf_counter()
        replayed = replay(traces, folder)
        print(report_of([check(d) if failure is None else failed(d.name, f"replay failed: {failure}")
                         for d, _, failure in replayed]))  # fmt: skip
        print(f"replayed {len(replayed)} recorded runs from {traces} in {time.perf_counter() - t0:.0f} s wall")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m storyteller.benchmark.story_text_fidelity", description=__doc__.splitlines()[0])
    source = p.add_mutually_exclusive_group()
    source.add_argument("--traces", type=Path, default=None,
                        help=f"Replay the recorded scenarios in this folder (default: {DEFAULT_TRACES.relative_to(ROOT)}).")  # fmt: skip
    source.add_argument("--runs", type=Path, default=None, help="Check the run folders in this folder; no replay.")
    p.add_argument("--scenarios", default="*", help="Glob over scenario names (replay only; default: all).")
    p.add_argument("--out", type=Path, default=None, help="Folder for the replayed runs (default: a temporary one).")
    args = p.parse_args(argv)
    if args.runs is not None:
        return report_run_folders(args.runs, check_run, report)
    return report_replays(
        args.traces, args.out, "story-text-", lambda traces, out: replay_suite(traces, args.scenarios, out),
        check_run, lambda name, error: RunCheck(name, error=error), report,
    )

if __name__ == "__main__":
    raise SystemExit(main())

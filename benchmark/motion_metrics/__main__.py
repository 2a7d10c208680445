"""``python -m storyteller.benchmark.motion_metrics [RUN_DIR ...] --out DIR``: motion quality as papers report it.

Measures every run folder given (a folder of run folders, such as the ``--out`` of
``python -m storyteller.benchmark.story_suite run``, stands for each), all of them pooled, a crowd of
``--crowd`` walkers on random errands in the reference Office (no LLM), and the real clips
(``STORYTELLER_MOCAP``, else ``../shared/mocap``), and ``--partners`` pairs sent to chat, shake
hands and hug in the home scene (:mod:`.partners`). Prints five tables (feet, furniture and
bodies; walking against the real walks at the same speed; cadence by speed; interactions;
partners) and writes ``report.md``, ``metrics.json``, ``gait_vs_speed.png`` and ``strips/strip_<label>.png``
into ``--out``. Exit code 2 on a folder it cannot read (one line naming it).

``--scripted-story RUN_DIR`` first builds the scripted home story the published figures are
measured on (``storyteller.benchmark.motion_metrics.scripted_story``: Zoe, Max and Ava, 90 simulated s, a
scripted planner, no LLM, no network) into ``RUN_DIR`` (new or empty) and measures it with the
rest: ``python -m storyteller.benchmark.motion_metrics --scripted-story RUN_DIR --out OUT --crowd 50
--crowd-seconds 20`` reproduces ``benchmark/results/2026-12-06-motion-metrics.md``'s set-up.

Targets (issue 25): skating ratio <= 0.03; walking within 20% of real on bob, cadence, step
length and arm swing, jerk 0.5x-2x; facing at start median <= 10, p95 <= 25 degrees; hands
within 15 cm at 90% of reaches; seat height within 3 cm; furniture p99 <= 2 cm; overlap 0 frames;
partners face each other at a social distance, a handshake's hands meet.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from storyteller.benchmark.motion_metrics.measure import Measured, measure_run, pooled
from storyteller.benchmark.motion_metrics.partners import PLANNED_GAP_M, partner_pairs, partner_table
from storyteller.benchmark.motion_metrics.report import (
    as_markdown,
    as_text,
    cadence_table,
    contact_table,
    figures_json,
    gait_figure,
    gait_table,
    interaction_table,
)
from storyteller.benchmark.motion_metrics.scripted_story import NAMES, SECONDS, StoryBuildError, build_story
from storyteller.benchmark.motion_metrics.sources import (
    RunMotion,
    SourceError,
    crowd_motion,
    load_run_motion,
    real_clips,
    run_folders,
)
from storyteller.benchmark.motion_metrics.strips import draw_strips


def _clean(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    return value


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m storyteller.benchmark.motion_metrics", description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="*", type=Path, help="run folders, or folders of run folders")
    p.add_argument("--out", type=Path, required=True, help="folder for report.md, metrics.json and the PNGs")
    p.add_argument("--crowd", type=int, default=50, help="walkers in the crowd (0: no crowd)")
    p.add_argument("--crowd-seconds", type=float, default=20.0, help="simulated seconds of the crowd")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-real", action="store_true", help="leave the real clips out (no ratios to them)")
    p.add_argument("--no-strips", action="store_true", help="draw no strips")
    p.add_argument("--partners", type=int, default=12,
                   help="pairs sent to chat / shake hands / hug in the home scene (0: none; .partners)")
    p.add_argument("--scripted-story", type=Path, metavar="RUN_DIR",
                   help="build the scripted home story into RUN_DIR (new or empty) first, and measure it too")
    p.add_argument("--story-seconds", type=float, default=SECONDS, help="simulated seconds of the scripted story")
    p.add_argument("--story-names", default=",".join(NAMES), help="its characters, among Zoe,Max,Ava")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.partners < 0:
        print("error: --partners must be >= 0", file=sys.stderr)
        return 2
    if args.crowd < 0 or not (args.crowd_seconds > 0 and math.isfinite(args.crowd_seconds)):
        print("error: --crowd must be >= 0 and --crowd-seconds a positive number", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    if args.scripted_story is not None:
        try:
            names = [n.strip() for n in args.story_names.split(",")]
            code = build_story(args.scripted_story, seconds=args.story_seconds, names=names, seed=args.seed)
        except StoryBuildError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        if code != 0:
            print(f"error: the scripted story failed (storyteller run exit code {code})", file=sys.stderr)
            return code
        args.runs.append(args.scripted_story)
    try:
        folders = run_folders(args.runs)
        runs: list[RunMotion] = [load_run_motion(f) for f in folders]
    except SourceError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    notes: list[str] = []
    items: list[Measured] = [measure_run(r) for r in runs]
    if len(items) > 1:
        items.append(pooled(f"all {len(items)} runs", items))
    if args.crowd > 0:
        try:
            crowd = crowd_motion(args.crowd, args.crowd_seconds, args.seed)
            runs.append(crowd)
            items.append(measure_run(crowd, facing=False))
        except SourceError as exc:
            notes.append(f"crowd skipped: {exc}")
    real: Measured | None = None
    if not args.no_real:
        clips, note = real_clips()
        notes.append(note)
        if clips.characters:
            walks = RunMotion("real walks", clips.fps, None, tuple(c for c in clips.characters if c.labels[:1] == ("walk",)))
            real = measure_run(walks, bodies=False, facing=False)
    if not items:
        print("error: nothing to measure: give run folders or --crowd N", file=sys.stderr)
        return 2
    tables = [("Feet, furniture and bodies", contact_table(items, real))]
    if real is not None and real.gait:
        tables.append(("Walking against the real walks at the same speed", gait_table(items, real)))
        tables.append(("Cadence and step length by speed", cadence_table(items, real)))
    tables.append(("Interactions", interaction_table(items)))
    if args.partners > 0:
        tables.append((f"Partners ({args.partners} pairs in the home scene, planned {PLANNED_GAP_M[0]:g}-"
                       f"{PLANNED_GAP_M[1]:g} m apart)", partner_table(partner_pairs(args.partners, args.seed))))
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    pictures = []
    if real is not None and real.gait:
        pictures.append(gait_figure(items, real, out / "gait_vs_speed.png"))
    if not args.no_strips:
        pictures += draw_strips(runs, out / "strips")
    elapsed = time.perf_counter() - t0
    text = [f"motion metrics: {len(folders)} run folder(s){', crowd' if args.crowd else ''} ({elapsed:.1f} s)"]
    text += notes
    md = ["# Motion metrics", "", f"Sources: {', '.join(str(f) for f in folders) or 'none'}; "
          f"crowd {args.crowd} walkers x {args.crowd_seconds:g} s (seed {args.seed}).", "",
          *[f"- {n}" for n in notes], ""]
    for title, table in tables:
        text += ["", title, as_text(table)]
        md += [f"## {title}", "", as_markdown(table), ""]
    md += ["## Figures", ""] + [f"![{p.stem}]({p.relative_to(out).as_posix()})" for p in pictures]
    (out / "report.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    (out / "metrics.json").write_text(json.dumps(_clean(figures_json(items, real)), indent=1) + "\n", encoding="utf-8")
    print("\n".join(text))
    print(f"-> {out / 'report.md'}, {out / 'metrics.json'}, {len(pictures)} PNG")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

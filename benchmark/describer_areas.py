"""Describer areas against the room table: the share of areas that agree on the first reply and
after the check (issue 23, item 4; target: >= 90% on the first reply).

Runs the describer with the run config's model (the embedded model by default; ``--config``
for another) once per scene: the bundled scenes, then the authors' reference scenes (House,
Office, Restaurant; left out with the resolver's one-line reason when the data is absent). Each
call goes through the describer's own checks (``storyteller.agents.describer.judge_reply``): a reply whose
areas do not fit their objects gets the feedback and another try, at most ``--max-retries``
times, then the misfits are renamed from the table (``best_effort_areas``). No description
cache is read or written.

An area *agrees* when its name and purpose fit its objects (``storyteller.agents.area_fit.judge_area``);
areas the table cannot judge (a name it cannot read, or only plants and lamps) are counted
apart and left out of the share. A first reply that does not parse counts as one disagreeing
area per region.

Usage: ``python -m storyteller.benchmark.describer_areas [--config FILE] [--max-retries 3] [--scenes home,House]``.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from storyteller.agents.area_fit import area_labels, judge_area
from storyteller.agents.describer import (
    AreaList,
    DescriberInput,
    best_effort_areas,
    describer_input_from_scene,
    describer_request,
    judge_reply,
    load_areas,
    repair_areas,
)
from storyteller.agents.llm_port import LLMPort
from storyteller.agents.prompt_templates import PromptLibrary
from storyteller.agents.retry_feedback import Turn
from storyteller.agents.room_table import room_table
from storyteller.orchestrator.reference_data import locate_reference
from storyteller.sim.scene.bundled import bundled_scene_names, load_bundled_scene
from storyteller.sim.scene.model import Scene


@dataclass(frozen=True)
class Tally:
    agree: int = 0
    judged: int = 0
    unjudged: int = 0

    def __add__(self, other: Tally) -> Tally:
        return Tally(self.agree + other.agree, self.judged + other.judged, self.unjudged + other.unjudged)

    @property
    def share(self) -> str:
        return f"{self.agree}/{self.judged} = {self.agree / self.judged:.0%}" if self.judged else "n/a"


def tally(areas: AreaList, inp: DescriberInput, lines: list[str]) -> Tally:
    """Verdicts of ``areas``, one line each appended to ``lines``."""
    table, labels = room_table(), inp.all_labels
    agree = judged = unjudged = 0
    for a in areas.areas:
        fit = judge_area(a.name, a.purpose, area_labels(a.objects, labels), table)
        if not fit.judged:
            unjudged += 1
            verdict = "not judged"
        else:
            judged += 1
            agree += fit.agrees
            verdict = "agrees" if fit.agrees else f"disagrees (fits: {', '.join(fit.fitting[:3])})"
        lines.append(f"    {a.name} ({a.purpose}): {', '.join(a.objects[:5])}{', ...' if len(a.objects) > 5 else ''} -> {verdict}")
    return Tally(agree, judged, unjudged)


async def describe(port: LLMPort, prompts: PromptLibrary, inp: DescriberInput, max_retries: int) -> tuple[Tally, Tally, int, list[str]]:
    """(first reply's tally, final tally, calls, report lines) for one scene."""
    lines: list[str] = ["  first reply:"]
    turns: tuple[Turn, ...] = ()
    first: Tally | None = None
    final: AreaList | None = None
    for _ in range(max_retries + 1):
        response = await port.complete(describer_request(prompts, inp, turns))
        if first is None:
            try:
                first = tally(repair_areas(load_areas(response.text, inp), inp), inp, lines)
            except ValueError:
                first = Tally(0, len(inp.clusters), 0)
                lines.append(f"    (does not parse: {response.text[:80]!r})")
        judged = judge_reply(response.text, inp, prompts)
        if judged.areas is not None:
            final = judged.areas
            break
        assert judged.turn is not None
        turns = (*turns, judged.turn)
        lines.append(f"  feedback: {judged.turn.feedback[:300]}")
    if final is None:
        final = best_effort_areas(inp, turns)
        lines.append("  (the last reply still disagreed: misfits renamed from the table)")
    lines.append("  after the check:")
    assert first is not None
    return first, tally(final, inp, lines), len(turns) + 1, lines


def scenes(selected: Sequence[str] | None) -> list[Scene]:
    from storyteller.sim.scene.files import load_scene

    out = [load_bundled_scene(n) for n in bundled_scene_names()]
    reference = locate_reference()
    if reference.found:
        root = reference.path / "configs" / "scenes"
        out += [load_scene(p) for p in sorted(root.iterdir()) if p.is_dir()]
    else:
        print(f"reference scenes left out: {reference.reason}", file=sys.stderr)
    return [s for s in out if not selected or s.name in selected]


async def run(args: argparse.Namespace) -> int:
    from storyteller.orchestrator.session.port_setup import describer_mode_for, open_port

    port, model = open_port(args.config, None, None)
    mode = describer_mode_for(model)
    prompts = PromptLibrary()
    first_total, final_total, calls = Tally(), Tally(), 0
    try:
        for scene in scenes(args.scenes.split(",") if args.scenes else None):
            started = time.perf_counter()
            first, final, n, lines = await describe(port, prompts, describer_input_from_scene(scene, mode=mode), args.max_retries)
            print(f"{scene.name}: first reply {first.share}, after the check {final.share}, "
                  f"{n} call(s), {time.perf_counter() - started:.1f} s")
            print("\n".join(lines))
            first_total, final_total, calls = first_total + first, final_total + final, calls + n
    finally:
        port.close()
    print(f"model {model} ({mode} mode), load average {os.getloadavg()[0]:.2f}: "
          f"areas agreeing with the room table: first reply {first_total.share} (target >= 90%), "
          f"after the check {final_total.share}; not judged {first_total.unjudged} / {final_total.unjudged}; {calls} calls")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m storyteller.benchmark.describer_areas", description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("--config", type=Path, help="TOML run config (the describer's model)")
    p.add_argument("--max-retries", type=int, default=3)
    p.add_argument("--scenes", help="comma-separated scene names (default: all)")
    return asyncio.run(run(p.parse_args(argv)))


if __name__ == "__main__":
    raise SystemExit(main())

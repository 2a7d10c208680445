"""Offline check of the seat-choice lever (agents/place_choice.py), no model needed.

For every case of one side of our pool (level 2) whose expected plan sits one character on a
named seat, with the case's instruction standing in for the event's text: is the expected seat
among the seats the event grammar offered before the lever (the shortlist), among the lever's
candidates, and among those meeting the stated relations (``allowed``); and how many are left
for the model to choose from (1 = decided by the scene)::

    PYTHONPATH=$PWD python benchmark/results/seat_choice_recall.py dev        # develop on this
    PYTHONPATH=$PWD python benchmark/results/seat_choice_recall.py dev -v     # one line per case
    PYTHONPATH=$PWD python benchmark/results/seat_choice_recall.py ref-dev    # our cases on the authors' scenes
    PYTHONPATH=$PWD python benchmark/results/seat_choice_recall.py ref-dev --descriptions RUN/descriptions

``--descriptions``: a bench run's folder of cached scene descriptions (``storyteller bench run
--out RUN``); with it the candidates are limited by the areas the words name, as in a run.

Only ``dev`` and ``ref-dev`` print case lines; ``test`` prints the counts alone (test is measured, not read).
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from storyteller.agents.area_words import DescribedArea, described_areas
from storyteller.agents.place_choice import seat_candidates
from storyteller.agents.place_phrases import plain_places
from storyteller.agents.program_grammar import event_options
from storyteller.benchmark.reference_cases import load_cases, planning_inputs, scene_dir
from storyteller.orchestrator.reference_data import locate_reference
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene

ROOT = Path(__file__).resolve().parents[1]
POOLS = {"": (ROOT / "cases" / "ours", ROOT / "own_cases" / "split.json"),
         "ref-": (ROOT / "cases" / "ours_ref", ROOT / "own_cases" / "split_ref.json")}
_SIT = re.compile(r"^sit on ([a-z_]+_\d+)$")


def _areas(folder: Path | None, scene: Scene, scene_name: str) -> tuple[DescribedArea, ...]:
    if folder is None:
        return ()
    stem = scene_name.replace(":", "-")
    found = sorted(folder.glob(f"{stem}-*.json"))
    if not found:
        return ()
    return described_areas(json.loads(found[0].read_text(encoding="utf-8"))["text"], scene.object_names)


def recall(side: str, verbose: bool = False, descriptions: Path | None = None) -> str:
    pool, split = POOLS["ref-" if side.startswith("ref-") else ""]
    ids = set(json.loads(split.read_text(encoding="utf-8"))[side.removeprefix("ref-")])
    scenes: dict[str, Scene] = {}
    n = before = cand = allowed = decided = 0
    for case in (c.at_level(2) for c in load_cases(str(pool)) if c.id in ids):
        if len(case.expected_plans) != 1:
            continue
        m = _SIT.match((case.expected_plans[0].relationships or "").strip())
        if m is None:
            continue
        if case.scene_name not in scenes:
            scenes[case.scene_name] = load_scene(scene_dir(str(locate_reference().require()), case))
        scene = scenes[case.scene_name]
        inputs = planning_inputs(case, scene)
        who = case.expected_plans[0].character
        options = event_options(scene, [who], inputs.roster, inputs.seats_in_use, case.action_labels, case.user_instruction)
        seats = seat_candidates(scene, plain_places(case.user_instruction), options.free_seats, options.others, options.labels,
                                areas=_areas(descriptions, scene, case.scene_name))
        want = m.group(1)
        n += 1
        before += want in options.seats
        cand += want in seats.candidates
        allowed += want in seats.allowed
        decided += len(seats.allowed) == 1 and seats.allowed[0] == want
        if verbose and side.endswith("dev"):
            print(f"{case.id}: want {want}; before {list(options.seats)}; allowed {list(seats.allowed)} "
                  f"of {len(seats.candidates)}; {case.user_instruction}")
    return (f"{side}: {n} one-seat cases; expected seat offered before {before}/{n}; candidate {cand}/{n}; "
            f"meets the stated relations {allowed}/{n}; decided by the scene alone {decided}/{n}")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "-v"]
    folder = Path(args[args.index("--descriptions") + 1]) if "--descriptions" in args else None
    side = next((a for a in args if not a.startswith("--") and Path(a) != folder), "dev")
    print(recall(side, verbose="-v" in sys.argv, descriptions=folder))

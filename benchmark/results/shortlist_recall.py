"""Offline check of the shortlist lever (agents/shortlist.py), no model needed.

For every case of a case set (level 2), the objects and seats the event grammar offers with the
shortlist (the case's instruction standing in for the narrator's activity text) and without it
(every object, every free seat), and whether each expected character's relationship / position
expression still has an alternative (``||``) whose named objects are all offered::

    PYTHONPATH=$PWD python benchmark/results/shortlist_recall.py benchmark/cases/ours
"""

from __future__ import annotations

import re
import sys

from storyteller.agents.shortlist import event_shortlist
from storyteller.benchmark.reference_cases import load_cases, planning_inputs, scene_dir
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene

_NAME = re.compile(r"(?<![A-Za-z_])[A-Za-z]+(?:_[A-Za-z]+)*_\d+")  # a run of letters starts once: linear


def recall(reference: str) -> str:
    scenes: dict[str, Scene] = {}
    n = hit_all = hit_short = size_all = size_short = 0
    for case in (c.at_level(2) for c in load_cases(reference)):
        if case.scene_name not in scenes:
            scenes[case.scene_name] = load_scene(scene_dir(reference, case))
        scene = scenes[case.scene_name]
        taken = set(planning_inputs(case, scene).seats_in_use)
        free = [o.name for o in scene.objects if o.is_seat and o.name not in taken]
        names = {o.name for o in scene.objects}
        plans = []
        for p in case.expected_plans:
            expr = " ".join(x for x in (p.relationships, p.sampled_position) if x).replace("(", " ").replace(")", " ")
            alts = [objs for alt in expr.split("||") if (objs := set(_NAME.findall(alt)) & names)]
            if alts:
                plans.append(alts)
        if not plans:
            continue
        short = event_shortlist(scene, case.user_instruction, free, case.action_labels)
        offered_all = names | set(free)
        offered_short = set(short.objects or names) | set(short.seats or free)
        n += 1
        hit_all += all(any(a <= offered_all for a in alts) for alts in plans)
        hit_short += all(any(a <= offered_short for a in alts) for alts in plans)
        size_all += len(offered_all)
        size_short += len(offered_short)
    return (f"{reference}: {n} cases with named answers; answer offered: all {hit_all}/{n}, shortlist {hit_short}/{n}; "
            f"alternatives per event: all {size_all / n:.1f}, shortlist {size_short / n:.1f}")


if __name__ == "__main__":
    for ref in sys.argv[1:]:
        print(recall(ref))

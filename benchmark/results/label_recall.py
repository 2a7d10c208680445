"""Offline check of the action-label lever (agents/action_shortlist.py), no model needed.

For every case of a case set (level 2), with the case's instruction standing in for the event's
text: is an expected action of each character the suggested label (the one the prompt names),
and is it on the label shortlist the event grammar offers (every label when the shortlist is
empty)? Also the shortlist's mean size, and whether the posture the words give (sit / stand,
``storyteller.agents.action_shortlist.posture``) agrees with the expected relationship ("sit on ...")::

    PYTHONPATH=$PWD python benchmark/results/label_recall.py benchmark/cases/ours [-v]
"""

from __future__ import annotations

import sys

from storyteller.agents.action_shortlist import action_shortlist, posture, suggested_action
from storyteller.benchmark.plan_scoring import action_matches
from storyteller.benchmark.reference_cases import load_cases


def recall(reference: str, verbose: bool = False) -> str:
    n = top = offered = size = 0
    postures = {"sit_ok": 0, "stand_ok": 0, "wrong": 0, "none": 0}
    for case in (c.at_level(2) for c in load_cases(reference)):
        said = posture(case.user_instruction)
        for plan in case.expected_plans:
            alternatives = [a.strip(" ()") for a in (plan.relationships or "").split("||") if a.strip()]
            sits = bool(alternatives) and all(a.startswith("sit on") for a in alternatives)
            if said is None:
                postures["none"] += 1
            elif (said == "sit") == sits:
                postures["sit_ok" if sits else "stand_ok"] += 1
            else:
                postures["wrong"] += 1
                if verbose:
                    print(f"  case {case.id} {plan.character}: posture {said!r} but want {plan.relationships!r}")
        short = action_shortlist(case.user_instruction, case.action_labels) or case.action_labels
        best = suggested_action(case.user_instruction, case.action_labels)
        for plan in case.expected_plans:
            if not plan.target_action:
                continue
            n += 1
            size += len(short)
            top += action_matches(plan.target_action, best)
            hit = any(action_matches(plan.target_action, label) for label in short)
            offered += hit
            if verbose and not action_matches(plan.target_action, best):
                print(f"  case {case.id} {plan.character}: want {plan.target_action!r}, suggested {best!r}, "
                      f"offered {list(short)[:6]} | {case.user_instruction}")
    return (f"{reference}: {n} expected actions; suggested label right {top}/{n}; offered by the grammar "
            f"{offered}/{n}; labels offered per character {size / max(n, 1):.1f}; posture from the words "
            f"(sit right / stand right / wrong / not said): {postures['sit_ok']} / {postures['stand_ok']} / "
            f"{postures['wrong']} / {postures['none']}")


if __name__ == "__main__":
    verbose = "-v" in sys.argv
    for ref in [a for a in sys.argv[1:] if a != "-v"]:
        print(recall(ref, verbose))

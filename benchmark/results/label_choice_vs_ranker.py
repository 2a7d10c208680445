"""Does the embedded model's scored choice beat the label ranker where the ranker is unsure?

For every development-side case of our pools (level 2; test ids skipped, test is measured, not
read), each instruction part with one actor and an expected action whose ranked labels
(``agents.action_shortlist.rank_action_labels``) have a second label scoring at least ``RATIO``
of the first: the ranker's best label against the label the model picks among the ranker's
shortlist with the action-choice prompt (``agents.action_choice.action_choice_request``, one
prompt, scored continuations). Loads the default embedded model::

    PYTHONPATH=$PWD python benchmark/results/label_choice_vs_ranker.py [RATIO]

At 5bf4c72 (ratio 0.6): 57 parts; ranker right 44/57, model right 41/57.
"""

from __future__ import annotations

import asyncio
import sys
from dataclasses import dataclass

from storyteller.agents.action_choice import action_choice_request
from storyteller.agents.action_shortlist import action_shortlist, rank_action_labels
from storyteller.agents.instruction_parts import split_instruction
from storyteller.agents.scored_choice import choose
from storyteller.benchmark.own_cases.split import split_ids
from storyteller.benchmark.plan_scoring import action_matches
from storyteller.benchmark.reference_cases import load_cases
from storyteller.orchestrator.llm.client import LiteLLMClient
from storyteller.orchestrator.llm.config import default_config

POOLS = ("ours", "ours_ref", "ours_para", "ours_para2")


@dataclass(frozen=True)
class ClosePart:
    pool: str
    case: int
    text: str
    actor: str
    want: str
    ranker: str
    shortlist: tuple[str, ...]


def close_parts(ratio: float) -> list[ClosePart]:
    test = set(split_ids("test")) | set(split_ids("test", "ours_ref"))
    out: list[ClosePart] = []
    for pool in POOLS:
        for case in (c.at_level(2) for c in load_cases(f"benchmark/cases/{pool}")):
            if pool in ("ours", "ours_ref") and case.id in test:
                continue
            names = [p.character for p in case.expected_plans]
            for part in split_instruction(case.user_instruction, names):
                wanted = [p.target_action for p in case.expected_plans
                          if len(part.actors) == 1 and p.character == part.actors[0] and p.target_action]
                ranked = rank_action_labels(part.text, case.action_labels)
                if not wanted or len(ranked) < 2 or ranked[1].score < ratio * ranked[0].score:
                    continue
                out.append(ClosePart(pool, case.id, part.text, part.actors[0], wanted[0], ranked[0].label,
                                     action_shortlist(part.text, case.action_labels)))
    return out


async def compare(parts: list[ClosePart]) -> tuple[int, int]:
    port = LiteLLMClient(default_config())
    ranker = model = 0
    for p in parts:
        picked = (await choose(port, action_choice_request(p.shortlist, (p.actor,), p.text, p.text, seed=0))).choice
        ranker += action_matches(p.ranker, p.want)
        model += action_matches(picked, p.want)
        print(f"{p.pool} {p.case} want={p.want} ranker={p.ranker} model={picked} | {p.text[:90]}")
    return ranker, model


def main() -> None:
    ratio = float(sys.argv[1]) if len(sys.argv) > 1 else 0.6
    parts = close_parts(ratio)
    ranker, model = asyncio.run(compare(parts))
    print(f"{len(parts)} parts; ranker right {ranker}/{len(parts)}, model right {model}/{len(parts)}")


if __name__ == "__main__":
    main()

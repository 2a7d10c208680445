"""Our case pool split once, by a fixed seed, into a development set and a test set.

The rule (README, "Our own cases"): levers are developed on the development set only; the
test set is measured, never read for tuning (no looking at its instructions, programs or
failures to write a rule, a word list or a prompt). A figure is published with both, plus the
authors' cases; a development-minus-test gap above 0.05 is a finding to fix.

How the split is made (:data:`SPLIT_SEED`):

- the 40 hand-written cases (ids 100-169) are development cases: levers were developed on them;
- a generated case's side is decided before it is written (:mod:`.generate`): within each
  recipe, the sentence shapes are shuffled by the seed and dealt to the two sides, and so are
  the activity phrases of every phrase bank; a recipe's cases on one scene alternate sides in
  turn. So a test case's sentence shape and activity wording never occur in a development
  case, and each recipe on each scene (hence each tag group and each scene) is split half and
  half, to within one case.

``benchmark/own_cases/split.json`` records the result as data (case ids per side, and the
seed); ``python -m storyteller.benchmark.own_cases.split`` rewrites it from the case folder and
``--check`` compares. :func:`split_ids` is what ``storyteller bench run --cases ours-dev`` /
``--cases ours-test`` read. The pool on the authors' scenes (``benchmark/cases/ours_ref``, all
generated, by the same deal) has its own file, ``split_ref.json`` (``--pool ours_ref``; read by
``--cases ours-ref-dev`` / ``--cases ours-ref-test``).

Guarantee: the two sides are disjoint and cover the pool; the same seed gives the same sides.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
from collections.abc import Iterable, Sequence
from importlib import resources
from pathlib import Path
from typing import Literal

SPLIT_SEED = 24
Side = Literal["dev", "test"]
SIDES: tuple[Side, Side] = ("dev", "test")
SPLIT_FILE = "split.json"
SPLIT_FILES: dict[str, str] = {"ours": SPLIT_FILE, "ours_ref": "split_ref.json"}
"""The committed split of each pool (``ours``: bundled scenes; ``ours_ref``: the authors' scenes)."""


def split_file(pool: str = "ours") -> Path:
    """The committed split of ``pool`` (``benchmark/own_cases/split.json`` / ``split_ref.json``)."""
    if pool not in SPLIT_FILES:
        raise ValueError(f"unknown case pool {pool!r}; expected {' or '.join(SPLIT_FILES)}")
    return Path(str(resources.files("storyteller.benchmark.own_cases") / SPLIT_FILES[pool]))


def deal(items: Sequence[str], key: str, seed: int = SPLIT_SEED) -> dict[str, Side]:
    """``items`` shuffled by ``seed`` (and ``key``) and dealt to the two sides in turn; the side
    that gets the first item is drawn too, so an odd count favours neither side overall."""
    rng = random.Random(f"{seed}:{key}")
    order = sorted(set(items))
    rng.shuffle(order)
    first = rng.randrange(2)
    return {item: SIDES[(first + i) % 2] for i, item in enumerate(order)}


def on_side(items: Sequence[str], key: str, side: Side, seed: int = SPLIT_SEED) -> list[str]:
    """The members of ``items`` dealt to ``side`` (all of them when fewer than two)."""
    if len(set(items)) < 2:
        return list(items)
    sides = deal(items, key, seed)
    return [i for i in items if sides[i] == side]


def first_side(stream: str, seed: int = SPLIT_SEED) -> int:
    """Which side (0 dev, 1 test) the first case of a stream (a recipe on a scene) goes to."""
    return random.Random(f"{seed}:first:{stream}").randrange(2)


def split_of(cases: Iterable[dict[str, object]]) -> dict[str, list[int]]:
    """Case ids per side: hand-written cases (no ``generated`` block) are development cases,
    generated ones go to the side their block records."""
    out: dict[str, list[int]] = {"dev": [], "test": []}
    for case in cases:
        generated = case.get("generated")
        side = generated.get("side", "dev") if isinstance(generated, dict) else "dev"
        out[str(side)].append(int(str(case["id"])))
    return {k: sorted(v) for k, v in out.items()}


def read_split(path: Path | None = None) -> dict[str, list[int]]:
    """The committed split: ``{"dev": [...], "test": [...]}``."""
    data = json.loads((path or split_file()).read_text(encoding="utf-8"))
    return {side: [int(i) for i in data[side]] for side in SIDES}


def split_ids(side: str, pool: str = "ours") -> tuple[int, ...]:
    """The case ids of one side of ``pool``'s committed split (``dev`` or ``test``)."""
    if side not in SIDES:
        raise ValueError(f"unknown split side {side!r}; expected dev or test")
    return tuple(read_split(split_file(pool))[side])


def render(split: dict[str, list[int]], seed: int = SPLIT_SEED) -> str:
    data = {
        "seed": seed,
        "rule": "Levers are developed on dev only; test is measured, never read for tuning.",
        "dev": split["dev"],
        "test": split["test"],
    }
    return json.dumps(data, indent=1) + "\n"


def _folder_cases(folder: Path) -> list[dict[str, object]]:
    return [json.loads(p.read_text(encoding="utf-8")) for p in sorted(folder.glob("*/testcase_*.json"))]


def main(argv: list[str] | None = None) -> int:
    from storyteller.benchmark.own_cases.check import ours_folder, ours_ref_folder

    parser = argparse.ArgumentParser(prog="python -m storyteller.benchmark.own_cases.split", description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only compare the split file with the case folder")
    parser.add_argument("--pool", choices=sorted(SPLIT_FILES), default="ours",
                        help="ours (split.json, default) or ours_ref (split_ref.json, the authors' scenes)")
    args = parser.parse_args(argv)
    folder = ours_ref_folder() if args.pool == "ours_ref" else ours_folder()
    text = render(split_of(_folder_cases(folder)))
    path = split_file(args.pool)
    if args.check:
        same = path.exists() and path.read_text(encoding="utf-8") == text
        print(f"{path}: {'matches' if same else 'differs from'} the case folder")
        return 0 if same else 1
    path.write_text(text, encoding="utf-8")
    split = json.loads(text)
    print(f"{path}: dev {len(split['dev'])}, test {len(split['test'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

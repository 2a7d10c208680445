"""Generate our case pool's templated cases from the bundled scenes' geometry.

``python -m storyteller.benchmark.own_cases.generate`` writes the generated cases (ids from
:data:`FIRST_ID`) into ``benchmark/cases/ours/<k>_<TAGS>/`` next to the 40 hand-written ones,
removing generated files of an earlier run; ``--check`` only compares and exits 1 when the
folder differs from what the code generates. ``--pool ours_ref`` does the same on the authors'
three reference scenes (:data:`REF_SCENES`, loaded through the reference-data lookup; absent:
one line, exit 2) into ``benchmark/cases/ours_ref/`` (ids from :data:`REF_FIRST_ID`, all
generated).

How a case is made: a *recipe* (:mod:`.recipes`, one per kind of question, e.g. "the seat of a kind nearest a
landmark", "join a friend's table", "wait for a device in use") looks at a scene (objects,
:mod:`storyteller.tools.scene_graph` relations, region clusters) and proposes *drafts* (:mod:`.drafts`): the tags, the
answer as a derivation query (:mod:`.derivation`), the action, the characters already in
place, and the slot values of its sentence shapes (:mod:`.phrasing`). A draft is kept only
when the answer is clear to a reader as well as to the code: for nearest / farthest the runner-up
is at least :data:`.scene_facts.MARGIN_M` farther (nearer); a ``count: one`` query selects exactly one
object. Each kept draft is then written (:mod:`.case_writer`) as a case with named characters and level-1 / level-2
distractors (characters and history events that touch none of the objects the question is
about) and checked by :func:`storyteller.benchmark.own_cases.check.check_case`; a draft whose case fails
the check with every distractor choice tried is dropped.

Guarantee: deterministic (the same code gives the same files, byte for byte); every case
written passes the check (its expected answer is what the geometry and the history derive, the
same at levels 0, 1 and 2); per tag group the cases come round-robin from the scenes and the
recipes, each recipe's shapes taken in turn, so no shape dominates; no text is taken from any
benchmark case.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from storyteller.benchmark.own_cases import recipes
from storyteller.benchmark.own_cases.case_writer import GENERATOR_SEED, NoDistractorError, as_case, write_case
from storyteller.benchmark.own_cases.check import _Scenes, check_case, ours_folder, ours_ref_folder
from storyteller.benchmark.own_cases.drafts import Draft
from storyteller.benchmark.own_cases.phrasing import SHAPES
from storyteller.benchmark.own_cases.scene_facts import SceneFacts
from storyteller.benchmark.own_cases.split import SIDES, first_side, on_side
from storyteller.benchmark.reference_cases import BUNDLED_PREFIX
from storyteller.orchestrator.reference_data import ReferenceDataNotFound
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.files import load_scene
from storyteller.tools.clusters import cluster_objects
from storyteller.tools.scene_graph import build_scene_graph

SCENES: tuple[str, ...] = ("home", "office", "restaurant")
FIRST_ID = 200
"""Generated cases are numbered from here (the hand-written ones are 100-169)."""
REF_SCENES: tuple[str, ...] = ("House", "Office", "Restaurant")
"""The authors' reference scenes (``configs/scenes/<name>`` of the reference data)."""
REF_FIRST_ID = 500
"""The reference-scene pool's cases are numbered from here (no id shared with ``ours``)."""
ATTEMPTS = 6
"""Distractor choices tried per draft before it is dropped."""

GROUPS: tuple[str, ...] = ("OA", "RC", "SS", "OA+RC", "OA+SS", "RC+SS", "PI")
FOLDERS: dict[str, str] = {g: f"{i}_{g.replace('+', '_')}" for i, g in enumerate(GROUPS)}
TARGETS: dict[str, int] = {"OA": 25, "RC": 25, "SS": 25, "OA+RC": 25, "OA+SS": 25, "RC+SS": 25, "PI": 50}
"""Generated cases per group: with the 40 hand-written ones the pool keeps the reference's
mix (an eighth per single tag and per pair, a quarter PI)."""

ACTION_LABELS: dict[str, tuple[str, ...]] = {
    "home": ("idle", "drink", "eat", "watch_tv", "dance", "chat", "handshake", "listen_to_music",
             "turn_on_record_player", "turn_off_record_player", "turn_on_tv", "turn_off_tv", "open_fridge",
             "close_fridge", "open_cabinet", "close_cabinet", "use_coffee_maker", "use_toaster", "use_microwave",
             "use_dishwasher", "use_smartphone", "use_laptop", "read_book"),
    "office": ("idle", "chat", "discuss", "attend_meeting", "handshake", "drink", "work_on_computer", "use_laptop",
               "use_smartphone", "read_book", "eat", "open_fridge", "close_fridge", "open_cabinet", "close_cabinet",
               "use_coffee_maker", "use_microwave", "use_water_dispenser", "take_out_document", "take_out_book",
               "clean_white_board", "write_on_white_board", "turn_on_tv", "turn_off_tv"),
    "restaurant": ("idle", "eat", "drink", "chat", "order_food", "order_drink", "pay_bill", "take_order",
                   "serve_food", "serve_drink", "deliver_menu", "clean_table", "use_coffee_maker", "use_smartphone",
                   "open_cabinet", "close_cabinet"),
}
"""The action labels each scene's cases offer (as the hand-written cases of that scene)."""

REF_ACTIONS: dict[str, str] = {"House": "home", "Office": "office", "Restaurant": "restaurant"}
"""A reference scene's cases offer the labels of the bundled scene of the same kind."""


@dataclass(frozen=True)
class Pool:
    """One generated case pool: its scenes, where they load from, its folder and its ids."""

    name: str
    """``ours`` (bundled scenes, next to the hand-written cases) or ``ours_ref`` (the authors' scenes)."""
    scenes: tuple[str, ...]
    first_id: int
    reference: bool
    """Whether the scenes are the reference data's (found by :func:`locate_reference`), not bundled."""

    def folder(self) -> Path:
        return ours_ref_folder() if self.reference else ours_folder()

    def scenes_root(self) -> Path:
        """Where :class:`_Scenes` finds the pool's scenes (raises ``ReferenceDataNotFound``
        with the lookup's one-line reason when a reference pool's data is absent)."""
        if not self.reference:
            return ours_folder()
        from storyteller.orchestrator.reference_data import locate_reference

        return locate_reference().require()

    def scene_name(self, scene: str) -> str:
        return scene if self.reference else BUNDLED_PREFIX + scene

    def actions(self, scene: str) -> tuple[str, ...]:
        return ACTION_LABELS[REF_ACTIONS[scene] if self.reference else scene]


OURS_POOL = Pool("ours", SCENES, FIRST_ID, reference=False)
REF_POOL = Pool("ours_ref", REF_SCENES, REF_FIRST_ID, reference=True)
POOLS: dict[str, Pool] = {p.name: p for p in (OURS_POOL, REF_POOL)}


def _facts(pool: Pool = OURS_POOL) -> dict[str, SceneFacts]:
    out = {}
    for name in pool.scenes:
        scene = load_scene(pool.scenes_root() / "configs" / "scenes" / name) if pool.reference \
            else load_bundled_scene(name)
        out[name] = SceneFacts(name, scene, build_scene_graph(scene), cluster_objects(scene), pool.actions(name),
                               pool.scene_name(name))
    return out


def _order(drafts: list[Draft], rng: random.Random, scenes: tuple[str, ...] = SCENES) -> list[Draft]:
    """Round-robin over scenes, and within a scene over recipes, each list shuffled."""
    by_scene: dict[str, dict[str, list[Draft]]] = {}
    for d in drafts:
        by_scene.setdefault(d.scene, {}).setdefault(d.recipe, []).append(d)
    streams = []
    for scene in scenes:
        recipes = by_scene.get(scene, {})
        for lst in recipes.values():
            rng.shuffle(lst)
        queues = [recipes[r] for r in sorted(recipes)]
        merged = []
        while any(queues):
            for q in queues:
                if q:
                    merged.append(q.pop(0))
        streams.append(merged)
    out = []
    while any(streams):
        for s in streams:
            if s:
                out.append(s.pop(0))
    return out


def generate(pool: Pool = OURS_POOL) -> list[dict[str, Any]]:
    """Every generated case of ``pool``, in id order (see the module docstring)."""
    facts = _facts(pool)
    scenes = _Scenes(pool.scenes_root())
    cases: list[dict[str, Any]] = []
    next_id = pool.first_id
    for group in GROUPS:
        rng = random.Random(f"{GENERATOR_SEED}:{group}")
        drafts = [d for f in facts.values() for recipe in recipes.RECIPES[group] for d in recipe(f)]
        made: dict[str, int] = {}
        turn: dict[tuple[str, str], int] = {}
        kept = 0
        for draft in _order(drafts, rng, pool.scenes):
            if kept == TARGETS[group]:
                break
            stream = f"{draft.recipe}:{draft.scene}"
            side = SIDES[(first_side(stream) + made.get(stream, 0)) % 2]
            shapes = on_side(sorted(SHAPES[draft.recipe]), f"shape:{draft.recipe}", side)
            shape_id = f"{draft.recipe}.{shapes[turn.get((draft.recipe, side), 0) % len(shapes)]}"
            for attempt in range(ATTEMPTS):
                try:
                    data = write_case(draft, facts[draft.scene], next_id, shape_id, side, attempt)
                except NoDistractorError:
                    continue  # another attempt may draw fewer distractors
                if not check_case(as_case(data, FOLDERS[group]), scenes).problems:
                    cases.append(data)
                    made[stream] = made.get(stream, 0) + 1
                    turn[(draft.recipe, side)] = turn.get((draft.recipe, side), 0) + 1
                    next_id += 1
                    kept += 1
                    break
    return cases


def render(data: dict[str, Any]) -> str:
    return json.dumps(data, indent=2, ensure_ascii=False) + "\n"


def write_pool(folder: Path, cases: list[dict[str, Any]], first_id: int = FIRST_ID) -> list[Path]:
    """Write ``cases`` under ``folder`` (removing generated files not among them); the paths written."""
    wanted = {folder / FOLDERS["+".join(c["tags"])] / f"testcase_{c['id']}.json": render(c) for c in cases}
    for old in folder.glob("*/testcase_*.json"):
        if int(old.stem.split("_")[-1]) >= first_id and old not in wanted:
            old.unlink()
    for path, text in wanted.items():
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")
    return sorted(wanted)


def differences(folder: Path, cases: list[dict[str, Any]], first_id: int = FIRST_ID) -> list[str]:
    """Files of ``folder`` that differ from ``cases`` (missing, changed or extra generated files)."""
    wanted = {folder / FOLDERS["+".join(c["tags"])] / f"testcase_{c['id']}.json": render(c) for c in cases}
    out = [f"{p}: missing" for p in wanted if not p.exists()]
    out += [f"{p}: differs" for p, t in wanted.items() if p.exists() and p.read_text(encoding="utf-8") != t]
    out += [f"{p}: not generated" for p in folder.glob("*/testcase_*.json")
            if int(p.stem.split("_")[-1]) >= first_id and p not in wanted]
    return sorted(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m storyteller.benchmark.own_cases.generate", description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only compare the folder with what the code generates")
    parser.add_argument("--pool", choices=sorted(POOLS), default=OURS_POOL.name,
                        help="ours: the bundled scenes (default); ours_ref: the authors' scenes (needs the reference data)")
    parser.add_argument("folder", nargs="?", type=Path, default=None,
                        help="case folder (default: the pool's, benchmark/cases/ours or benchmark/cases/ours_ref)")
    args = parser.parse_args(argv)
    pool = POOLS[args.pool]
    folder = args.folder or pool.folder()
    try:
        cases = generate(pool)
    except ReferenceDataNotFound as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.check:
        diffs = differences(folder, cases, pool.first_id)
        for d in diffs:
            print(d)
        print(f"{len(cases)} generated cases; {len(diffs)} file(s) differ")
        return 1 if diffs else 0
    write_pool(folder, cases, pool.first_id)
    counts: dict[str, int] = {}
    for c in cases:
        counts["+".join(c["tags"])] = counts.get("+".join(c["tags"]), 0) + 1
    print(f"{len(cases)} generated cases written to {folder}: " + ", ".join(f"{g} {counts.get(g, 0)}" for g in GROUPS))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Re-derive every expected answer of a case set and report each disagreement.

``python -m storyteller.benchmark.own_cases.check [FOLDER]`` (default: our set, ``benchmark/cases/ours``;
``benchmark/cases/ours_ref`` for the cases on the authors' scenes, which load from the reference
data: its absence is one line and exit 2) prints one line per case and exits 1 when any case has
a problem. A case has a problem when:

- its ``derivation`` block is missing or cannot be evaluated (see :mod:`.derivation`);
- the atoms its query derives differ from the expected expression's atoms, or a ``count: one``
  query selects more than one object (ambiguous) or none;
- the derived answer (or whether waiting is allowed) differs between distraction levels 0, 1
  and 2: a distractor changed it;
- an answer seat is taken by somebody, or no position the project's sampler finds for a
  non-seat answer passes :func:`storyteller.benchmark.position_check.check_position`;
- its shape is off: not 3-8 characters, no level-1 or no level-2 distractor event, a history
  event less distracting than its characters, an expected character that is a distractor or
  busy, an action outside the case's labels or the simulation's, or a folder not named after
  the tags.
"""

from __future__ import annotations

import argparse
import sys
import zlib
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

import numpy as np

from storyteller.benchmark.own_cases import OURS, OURS_REF
from storyteller.benchmark.own_cases.derivation import (
    CaseWorld,
    DerivationError,
    atoms_of,
    derivation_of,
    evaluate,
    expression_atoms,
)
from storyteller.benchmark.position_check import check_position
from storyteller.benchmark.reference_cases import (
    BUNDLED_PREFIX,
    BenchmarkCase,
    BenchmarkCaseError,
    load_cases,
    scene_dir,
)
from storyteller.orchestrator.reference_data import ReferenceDataNotFound, locate_reference
from storyteller.sim.motion.action_labels import ACTION_LABELS
from storyteller.sim.scene.files import load_scene
from storyteller.sim.scene.model import Scene
from storyteller.tools.character_states import area_from_text
from storyteller.tools.clusters import cluster_objects
from storyteller.tools.errors import UnsatisfiableAreaError
from storyteller.tools.position_sampling import Constraints, FloorMap, sample_position
from storyteller.tools.scene_graph import SceneGraph, build_scene_graph

LEVELS = (0, 1, 2)
MIN_CHARACTERS, MAX_CHARACTERS = 3, 8
SAMPLE_SEEDS = 8
"""Seeds tried per atom when looking for a position that passes the expected expression."""


def ours_folder() -> Path:
    """Our case set as shipped with the package."""
    return Path(str(resources.files("storyteller.benchmark") / "cases" / OURS))


def ours_ref_folder() -> Path:
    """Our case set on the authors' reference scenes (``benchmark/cases/ours_ref``)."""
    return Path(str(resources.files("storyteller.benchmark") / "cases" / OURS_REF))


@dataclass(frozen=True)
class Derived:
    """What a case's derivation gives at one level: expected atoms per character, and waiting."""

    atoms: tuple[tuple[str, frozenset[str]], ...]
    wait: bool | None


@dataclass(frozen=True)
class CaseReport:
    case: int
    source: str
    derived: Derived | None
    problems: tuple[str, ...]


class _Scenes:
    """Scene, scene graph and clusters per scene name, computed once."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self._cache: dict[str, tuple[Scene, SceneGraph, list[list[str]]]] = {}

    def get(self, case: BenchmarkCase) -> tuple[Scene, SceneGraph, list[list[str]]]:
        if case.scene_name not in self._cache:
            scene = load_scene(scene_dir(self.folder, case))
            self._cache[case.scene_name] = (scene, build_scene_graph(scene), cluster_objects(scene))
        return self._cache[case.scene_name]


def derive(case: BenchmarkCase, scene: Scene, graph: SceneGraph, clusters: list[list[str]]) -> tuple[Derived, list[str]]:
    """The case's answers derived in the world of ``case`` (take ``case.at_level(k)`` for a level)."""
    derivation = derivation_of(case)
    world = CaseWorld.of(case, scene, graph, clusters)
    problems: list[str] = []
    atoms = []
    for plan in derivation.plans:
        objects = evaluate(plan.objects, world)
        if not objects:
            problems.append(f"{plan.character}: the query selects no object")
            continue
        if plan.count == "one" and len(objects) > 1:
            problems.append(f"{plan.character}: ambiguous, {len(objects)} objects fit: {', '.join(sorted(objects))}")
        atoms.append((plan.character, atoms_of(plan.relations, objects)))
    wait = None
    if derivation.wait_for is not None:
        needed = evaluate(derivation.wait_for, world)
        if not needed:
            problems.append("wait_for selects no object")
        wait = bool(needed) and needed <= world.in_use
    return Derived(tuple(atoms), wait), problems


def _shape_problems(case: BenchmarkCase, folder_name: str) -> list[str]:
    problems = []
    if folder_name.split("_", 1)[-1] != "_".join(case.tags):
        problems.append(f"folder {folder_name!r} does not match tags {list(case.tags)}")
    n = len(case.current_states)
    if not MIN_CHARACTERS <= n <= MAX_CHARACTERS:
        problems.append(f"{n} characters (expected {MIN_CHARACTERS}-{MAX_CHARACTERS})")
    event_levels = {e.distraction_level for e in case.planning_history}
    for level in (1, 2):
        if level not in event_levels:
            problems.append(f"no level-{level} distractor event in the history")
    level_of = {c.name: c.distraction_level for c in case.current_states}
    for e in case.planning_history:
        for name in e.characters:
            if name not in level_of:
                problems.append(f"history event {e.idx} names {name!r}, who is not in current_states")
            elif level_of[name] > e.distraction_level:
                problems.append(f"history event {e.idx} (level {e.distraction_level}) involves level-{level_of[name]} {name}")
    unknown = sorted(set(case.action_labels) - set(ACTION_LABELS))
    if unknown:
        problems.append(f"action labels the simulation cannot play: {unknown}")
    for expected in case.expected_plans:
        if level_of.get(expected.character) != 0:
            problems.append(f"expected character {expected.character!r} is not an essential (level-0) character")
        state = next((c for c in case.current_states if c.name == expected.character), None)
        if state is not None and state.state != "idle":
            problems.append(f"expected character {expected.character!r} is busy ({state.state})")
        if expected.target_action:
            labels = {a.strip(" ()") for a in expected.target_action.replace("&&", "||").split("||")}
            if missing := sorted(labels - set(case.action_labels)):
                problems.append(f"{expected.character}: action(s) {missing} not in action_labels")
    return problems


def _reachable(case: BenchmarkCase, scene: Scene, world: CaseWorld, character: str, expression: str) -> bool:
    """Whether the sampler finds, for some atom, a position that passes the whole expression;
    an "adjacent to" / "close to" atom within its own distance (not the wider rings the
    product's sampler falls back to in a cramped spot: the pool's answers must have room where
    their words say, as when it was derived)."""
    floor = FloorMap(scene)
    avoid = world.world.points_to_avoid(exclude={character})
    for atom in sorted(expression_atoms(expression)):
        area = area_from_text(atom, scene)
        area = replace(area, relaxations=tuple(r for r in area.relaxations if not r.ring))
        for seed in range(SAMPLE_SEEDS):
            rng = np.random.default_rng(zlib.crc32(f"{case.id}:{atom}:{seed}".encode()))
            try:
                placement = sample_position(area, floor, Constraints(avoid=avoid), rng)
            except UnsatisfiableAreaError:
                break
            if check_position(scene, expression, placement.position, seat=placement.seat).passed:
                return True
    return False


def check_case(case: BenchmarkCase, scenes: _Scenes) -> CaseReport:
    """All problems of one case (see the module docstring)."""
    problems = _shape_problems(case, Path(case.source).parent.name)
    try:
        scene, graph, clusters = scenes.get(case)
        per_level = {}
        for level in LEVELS:
            derived, level_problems = derive(case.at_level(level), scene, graph, clusters)
            per_level[level] = derived
            problems += [f"level {level}: {p}" for p in level_problems]
    except (DerivationError, BenchmarkCaseError) as exc:
        return CaseReport(case.id, case.source, None, (*problems, str(exc)))
    top = per_level[max(LEVELS)]
    for level in LEVELS[:-1]:
        if per_level[level] != top:
            problems.append(f"level-{level} answer {_show(per_level[level])} differs from level-2 answer {_show(top)}")
    expected = {p.character: p for p in case.expected_plans}
    derived_names = sorted(c for c, _ in top.atoms)
    placed = sorted(c for c, p in expected.items() if p.relationships or p.sampled_position)
    if derived_names != placed:
        problems.append(f"derivation covers {derived_names}, expected positions cover {placed}")
    world = CaseWorld.of(case, scene, graph, clusters)
    plans = {p.character: p for p in derivation_of(case).plans}
    for character, atoms in top.atoms:
        plan = expected.get(character)
        if plan is None:
            continue
        field = plans[character].field
        expression = getattr(plan, field)
        if not expression:
            problems.append(f"{character}: the expected plan has no {field}")
            continue
        try:
            written = expression_atoms(expression)
        except DerivationError as exc:
            problems.append(f"{character}: {exc}")
            continue
        if written != atoms:
            problems.append(f"{character}: expected {sorted(written)}, derived {sorted(atoms)}")
            continue
        taken = sorted(a for a in atoms if a.startswith("sit on ") and a[len("sit on "):] in world.in_use)
        if taken:
            problems.append(f"{character}: answer seat(s) already taken: {taken}")
        if not all(a.startswith("sit on ") for a in atoms) and not _reachable(case, scene, world, character, expression):
            problems.append(f"{character}: no sampled position passes {expression!r}")
    if top.wait is not None and top.wait != case.allow_null_plan:
        problems.append(f"allow_null_plan is {case.allow_null_plan}, derived {top.wait}")
    return CaseReport(case.id, case.source, top, tuple(problems))


def _show(derived: Derived) -> str:
    parts = [f"{c}: {' || '.join(sorted(a))}" for c, a in derived.atoms]
    if derived.wait is not None:
        parts.append(f"wait: {derived.wait}")
    return "; ".join(parts) or "nothing"


def check_folder(folder: str | Path) -> list[CaseReport]:
    """Check every case of a case set. Cases on scenes that are not bundled load them from the
    reference data (:func:`locate_reference`; absent: :class:`ReferenceDataNotFound`), unless the
    folder is inside a checkout of it."""
    cases = load_cases(folder)
    root = Path(folder)
    if any(not c.scene_name.startswith(BUNDLED_PREFIX) for c in cases):
        inside = next((p for p in (root, *root.resolve().parents) if (p / "configs" / "scenes").is_dir()), None)
        root = inside or locate_reference().require()
    scenes = _Scenes(root)
    return [check_case(case, scenes) for case in cases]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m storyteller.benchmark.own_cases.check", description=__doc__.splitlines()[0])
    parser.add_argument("folder", nargs="?", type=Path, default=None, help="case set (default: benchmark/cases/ours)")
    args = parser.parse_args(argv)
    folder = args.folder or ours_folder()
    try:
        reports = check_folder(folder)
    except (BenchmarkCaseError, ReferenceDataNotFound) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for r in reports:
        status = "ok" if not r.problems else "FAIL"
        print(f"case {r.case} [{Path(r.source).parent.name}] {status}: {_show(r.derived) if r.derived else '-'}")
        for p in r.problems:
            print(f"    {p}")
    failed = sum(1 for r in reports if r.problems)
    print(f"{len(reports) - failed}/{len(reports)} cases derive their expected answers")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

"""Our own case set (``benchmark/cases/ours``): it loads like the reference cases, has the
reference's tag mix, 3-8 characters and level-1/2 distractors, every expected answer is what
its derivation computes from the scene and the history at every level, and no instruction
shares seven consecutive words with the authors' cases. The checker itself is shown to fail
on wrong, ambiguous, distractor-dependent and self-answering cases."""

from __future__ import annotations

import copy
import json
import re
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from storyteller.benchmark.own_cases.check import LEVELS, check_folder, derive, main, ours_folder
from storyteller.benchmark.own_cases.derivation import DerivationError, expression_atoms
from storyteller.benchmark.reference_cases import BenchmarkCaseError, load_case, load_cases, scene_dir
from storyteller.sim.scene.files import load_scene
from tests.support.reference import REFERENCE, TEST_CASES, requires_reference

OURS = ours_folder()
# the reference's mix: 5 cases per single tag and per pair, 10 PI (of 40)
MIX = {"OA": 5, "RC": 5, "SS": 5, "OA+RC": 5, "OA+SS": 5, "RC+SS": 5, "PI": 10}
WINDOW = 7


@pytest.fixture(scope="module")
def cases() -> list[Any]:
    return load_cases(OURS)


@pytest.fixture(scope="module")
def reports() -> list[Any]:
    return check_folder(OURS)


def test_every_case_loads_with_the_reference_loader_and_names_a_bundled_scene(cases: list[Any]) -> None:
    assert len(cases) >= 40
    assert len({c.id for c in cases}) == len(cases)
    scenes = {c.scene_name for c in cases}
    assert scenes == {"bundled:home", "bundled:office", "bundled:restaurant"}
    for name in scenes:
        case = next(c for c in cases if c.scene_name == name)
        scene = load_scene(scene_dir(OURS, case))
        assert scene.name == name.removeprefix("bundled:")


def test_the_tag_mix_is_the_references(cases: list[Any]) -> None:
    counts = Counter(c.group for c in cases)
    total = sum(MIX.values())
    assert {g: n * total for g, n in counts.items()} == {g: n * len(cases) for g, n in MIX.items()}


@requires_reference
def test_the_mix_is_read_off_the_reference() -> None:
    assert Counter(c.group for c in load_cases(REFERENCE)) == MIX


def test_characters_and_distractor_levels(cases: list[Any]) -> None:
    for case in cases:
        assert 3 <= len(case.current_states) <= 8, case.source
        levels = {e.distraction_level for e in case.planning_history}
        assert {1, 2} <= levels, case.source
        # each level drops something: level 0 has fewer characters or events than level 2
        full, bare = case.at_level(2), case.at_level(0)
        assert len(bare.current_states) < len(full.current_states), case.source


def test_every_expected_answer_is_derived_and_unambiguous(reports: list[Any]) -> None:
    problems = {r.source: r.problems for r in reports if r.problems}
    assert not problems
    assert len(reports) >= 40


def test_distractors_never_change_the_derived_answer(cases: list[Any]) -> None:
    scenes: dict[str, Any] = {}
    from storyteller.tools.clusters import cluster_objects
    from storyteller.tools.scene_graph import build_scene_graph

    for case in cases:
        if case.scene_name not in scenes:
            scene = load_scene(scene_dir(OURS, case))
            scenes[case.scene_name] = (scene, build_scene_graph(scene), cluster_objects(scene))
        derived = [derive(case.at_level(level), *scenes[case.scene_name])[0] for level in LEVELS]
        assert derived[0] == derived[1] == derived[2], case.source
        assert derived[0].atoms or derived[0].wait, case.source


def _words(text: str) -> list[str]:
    return re.findall(r"[a-z0-9_']+", text.lower())


def _windows(text: str) -> set[tuple[str, ...]]:
    words = _words(text)
    return {tuple(words[i : i + WINDOW]) for i in range(len(words) - WINDOW + 1)}


def test_the_overlap_rule_catches_a_copied_phrase() -> None:
    original = "Alice reads a long book on the sofa in the quiet living room."
    assert _windows(original) & _windows("Then BOB reads a long book on the sofa, happily.")
    assert not _windows(original) & _windows("Bob reads a long novel on the sofa.")


@requires_reference
def test_no_seven_word_overlap_with_the_reference(cases: list[Any]) -> None:
    reference: set[tuple[str, ...]] = set()
    for path in sorted(TEST_CASES.glob("*/testcase_*.json")):
        data = json.loads(path.read_text())
        reference |= _windows(data["user_instruction"])
        for event in data.get("planning_history", []):
            reference |= _windows(event["activity"])
    assert reference
    for case in cases:
        texts = [case.user_instruction, *(e.activity for e in case.planning_history)]
        shared = [" ".join(w) for t in texts for w in _windows(t) & reference]
        assert not shared, f"{case.source}: {shared}"


@pytest.mark.slow
def test_the_check_command(capsys: pytest.CaptureFixture[str]) -> None:
    n = len(load_cases(OURS))
    assert main([]) == 0
    assert f"{n}/{n} cases derive their expected answers" in capsys.readouterr().out


# ----- the checker fails where it must ------------------------------------------------------
def _copy_case(tmp_path: Path, case_id: int, edit: Any) -> Path:
    source = next(OURS.glob(f"*/testcase_{case_id}.json"))
    data = json.loads(source.read_text())
    edit(data)
    folder = tmp_path / source.parent.name
    folder.mkdir(parents=True, exist_ok=True)
    (folder / source.name).write_text(json.dumps(data))
    return tmp_path


def _problems(folder: Path) -> list[str]:
    (report,) = check_folder(folder)
    return list(report.problems)


def test_the_copied_case_passes_unchanged(tmp_path: Path) -> None:
    assert _problems(_copy_case(tmp_path, 120, lambda d: None)) == []


def test_a_wrong_expected_answer_fails(tmp_path: Path) -> None:
    def edit(d: dict[str, Any]) -> None:
        d["expected_plans"][0]["relationships"] = "sit on chair_2 || sit on chair_1"  # chair_1 is taken

    problems = _problems(_copy_case(tmp_path, 120, edit))
    assert any("derived ['sit on chair_2', 'sit on chair_3']" in p for p in problems)


def test_an_ambiguous_single_answer_fails(tmp_path: Path) -> None:
    def edit(d: dict[str, Any]) -> None:
        d["derivation"]["plans"][0]["count"] = "one"

    problems = _problems(_copy_case(tmp_path, 120, edit))
    assert any("ambiguous, 2 objects fit: chair_2, chair_3" in p for p in problems)


def test_a_distractor_on_an_answer_seat_is_caught(tmp_path: Path) -> None:
    def edit(d: dict[str, Any]) -> None:
        dmitri = next(c for c in d["current_states"] if c["name"] == "Dmitri")  # a level-1 reader
        dmitri["position"] = ["sit on chair_3"]
        for event in d["planning_history"]:
            for detail in event["details"]:
                if detail["character"] == "Dmitri":
                    detail["position"] = ["sit on chair_3"]

    problems = _problems(_copy_case(tmp_path, 120, edit))
    assert any(p.startswith("level-0 answer") and "differs from level-2" in p for p in problems)


def test_a_query_cannot_name_an_object_the_instruction_does_not(tmp_path: Path) -> None:
    def edit(d: dict[str, Any]) -> None:
        d["derivation"]["plans"][0]["objects"] = {"or": [{"object": "chair_2"}, {"object": "chair_3"}]}

    problems = _problems(_copy_case(tmp_path, 120, edit))
    assert any("not named in the instruction" in p for p in problems)


def test_an_unreachable_position_fails(tmp_path: Path) -> None:
    def edit(d: dict[str, Any]) -> None:  # behind the fridge is the wall
        d["expected_plans"][0]["relationships"] = "behind fridge_1"
        d["derivation"]["plans"][0] = {**d["derivation"]["plans"][0], "relations": ["behind"],
                                       "objects": {"label": "fridge"}}

    problems = _problems(_copy_case(tmp_path, 101, edit))
    assert any("no sampled position passes 'behind fridge_1'" in p for p in problems)


def test_a_wait_case_must_match_whether_the_object_is_busy(tmp_path: Path) -> None:
    def edit(d: dict[str, Any]) -> None:
        d["allow_null_plan"] = False

    problems = _problems(_copy_case(tmp_path, 121, edit))
    assert "allow_null_plan is False, derived True" in problems


def test_the_command_fails_on_a_broken_set(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = _copy_case(tmp_path, 120, lambda d: d["derivation"]["plans"][0].update(count="one"))
    assert main([str(folder)]) == 1
    assert "FAIL" in capsys.readouterr().out
    assert main([str(tmp_path / "nowhere")]) == 2


def test_expression_atoms_normalise_and_refuse_conjunctions() -> None:
    assert expression_atoms("between b_1 and a_1 ||  sit on x_1") == {"between a_1 and b_1", "sit on x_1"}
    with pytest.raises(DerivationError):
        expression_atoms("(close to a_1 && close to b_1)")


# ----- scene resolution ----------------------------------------------------------------------
def test_bundled_scene_names_resolve_whatever_the_folder(tmp_path: Path) -> None:
    case = load_case(next(OURS.glob("*/testcase_*.json")))
    assert scene_dir(tmp_path, case).name == f"{case.scene_name.removeprefix('bundled:')}.json"
    assert scene_dir(None, case) == scene_dir(tmp_path, case)  # no reference data needed
    unknown = case.model_copy(update={"scene_name": "bundled:castle"})
    with pytest.raises(BenchmarkCaseError, match="'castle' is not a bundled scene"):
        scene_dir(tmp_path, unknown)
    with pytest.raises(BenchmarkCaseError, match="no test cases"):
        load_cases(tmp_path)


def test_reference_scene_names_still_name_reference_folders(tmp_path: Path) -> None:
    case = load_case(next(OURS.glob("*/testcase_*.json")))
    legacy = case.model_copy(update={"scene_name": "House"})
    assert scene_dir(tmp_path, legacy) == tmp_path / "configs" / "scenes" / "House"
    with pytest.raises(BenchmarkCaseError, match="'House' is a scene of the reference data, which was not given"):
        scene_dir(None, legacy)


def test_a_level_copy_keeps_the_derivation_block() -> None:
    case = load_case(next(OURS.glob("*/testcase_*.json")))
    assert copy.deepcopy(case.at_level(0).raw["derivation"]) == case.raw["derivation"]

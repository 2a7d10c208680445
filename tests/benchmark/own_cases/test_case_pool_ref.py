"""Our generated cases on the authors' reference scenes (``benchmark/cases/ours_ref``): the folder
is what the generator makes from those scenes today, every answer re-derives, the split
(``benchmark/own_cases/split_ref.json``) is disjoint, covers the folder and follows the seed, and
``--cases ours-ref-dev`` / ``ours-ref-test`` select one side each (one line, exit 2, without the
reference data). Tests that load the scenes skip when the reference data is absent."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from storyteller.benchmark.own_cases import generate, split
from storyteller.benchmark.own_cases.check import check_folder, ours_folder, ours_ref_folder
from storyteller.benchmark.reference_cases import BUNDLED_PREFIX
from storyteller.orchestrator.reference_data import DataFolder, ReferenceDataNotFound, locate_reference
from tests.support.reference import TEST_CASES, requires_reference
from tests.support.word_windows import windows

OURS_REF = ours_ref_folder()


@pytest.fixture(scope="module")
def raw() -> list[dict[str, Any]]:
    return [json.loads(p.read_text(encoding="utf-8")) for p in sorted(OURS_REF.glob("*/testcase_*.json"))]


def test_the_folder_holds_generated_cases_on_the_three_reference_scenes_only(raw: list[dict[str, Any]]) -> None:
    assert len(raw) >= 150
    assert all("generated" in c and c["id"] >= generate.REF_FIRST_ID for c in raw)
    assert {c["scene_name"] for c in raw} == set(generate.REF_SCENES)
    assert not any(c["scene_name"].startswith(BUNDLED_PREFIX) for c in raw)
    assert {"+".join(c["tags"]) for c in raw} == set(generate.GROUPS)
    ours_ids = {int(p.stem.split("_")[-1]) for p in ours_folder().glob("*/testcase_*.json")}
    assert not ours_ids & {c["id"] for c in raw}  # an id names one case across both pools


@requires_reference
@pytest.mark.slow
def test_the_generator_check_says_the_folder_is_what_the_code_produces(capsys: pytest.CaptureFixture[str]) -> None:
    assert generate.main(["--pool", "ours_ref", "--check"]) == 0
    assert "0 file(s) differ" in capsys.readouterr().out
    assert generate.differences(OURS_REF, generate.generate(generate.REF_POOL), generate.REF_FIRST_ID) == []


@requires_reference
@pytest.mark.slow
def test_every_answer_re_derives_unambiguously() -> None:
    reports = check_folder(OURS_REF)
    assert reports and not [(r.case, r.problems) for r in reports if r.problems]


def test_the_generator_and_the_check_say_one_line_without_the_reference_data(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from storyteller.benchmark.own_cases import check

    monkeypatch.setenv("STORYTELLER_REFERENCE", str(tmp_path / "absent"))
    assert generate.main(["--pool", "ours_ref", "--check"]) == 2
    assert check.main([str(OURS_REF)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("error: reference data not found") for line in err)


# ----- the split ---------------------------------------------------------------------------------
def test_the_split_is_disjoint_covers_the_folder_and_is_fixed(raw: list[dict[str, Any]]) -> None:
    committed = split.read_split(split.split_file("ours_ref"))
    dev, test = set(committed["dev"]), set(committed["test"])
    assert not dev & test
    assert dev | test == {c["id"] for c in raw}
    assert committed == split.split_of(raw)
    assert split.split_file("ours_ref").read_text(encoding="utf-8") == split.render(split.split_of(raw))
    assert json.loads(split.split_file("ours_ref").read_text(encoding="utf-8"))["seed"] == split.SPLIT_SEED
    assert split.split_ids("dev", "ours_ref") == tuple(committed["dev"])
    assert len(dev) >= 75 and len(test) >= 75
    by_scene = Counter((c["scene_name"], c["generated"]["side"]) for c in raw)
    for scene in generate.REF_SCENES:
        assert abs(by_scene[(scene, "dev")] - by_scene[(scene, "test")]) <= 6, scene
    shapes: dict[str, set[str]] = {}
    for c in raw:
        shapes.setdefault(c["generated"]["shape"], set()).add(c["generated"]["side"])
    assert all(len(s) == 1 for s in shapes.values())  # no sentence shape on both sides


def test_the_bundled_pool_keeps_its_own_split_file() -> None:
    assert split.split_file() == split.split_file("ours") != split.split_file("ours_ref")
    with pytest.raises(ValueError, match="unknown case pool"):
        split.split_file("nope")


@requires_reference
def test_no_generated_text_shares_six_words_with_the_authors_cases(raw: list[dict[str, Any]]) -> None:
    reference: set[tuple[str, ...]] = set()
    for path in sorted(TEST_CASES.glob("*/testcase_*.json")):
        data = json.loads(path.read_text(encoding="utf-8"))
        reference |= windows(data["user_instruction"])
        for event in data.get("planning_history", []):
            reference |= windows(event["activity"])
    assert reference
    texts = [t for c in raw for t in (c["user_instruction"], *(e["activity"] for e in c["planning_history"]))]
    assert not sorted({" ".join(w) for t in texts for w in windows(t) & reference})


# ----- one command per side ----------------------------------------------------------------------
@requires_reference
def test_ours_ref_dev_and_ours_ref_test_select_one_side_each(tmp_path: Path) -> None:
    from storyteller.benchmark.sweep.execute import SweepWorkspace
    from storyteller.benchmark.sweep.grid import SweepSpec, case_set_for, model_specs
    from storyteller.benchmark.sweep.runner import relocated

    reference = locate_reference()
    sets = tuple(case_set_for(n, reference, ours_folder()) for n in ("ours-ref-dev", "ours-ref-test", "ours-ref"))
    assert all(s.scenes_root == str(reference.path) for s in sets)
    spec = SweepSpec(case_sets=sets, models=model_specs(["openai/scripted"], []))
    ws = SweepWorkspace(spec, tmp_path)
    committed = split.read_split(split.split_file("ours_ref"))
    assert sorted(ws.cases["ours-ref-dev"]) == committed["dev"]
    assert sorted(ws.cases["ours-ref-test"]) == committed["test"]
    assert len(ws.cases["ours-ref"]) == len(committed["dev"]) + len(committed["test"])
    moved = spec.model_copy(update={"case_sets": tuple(s.model_copy(update={"path": "/nowhere"}) for s in sets)})
    assert relocated(moved).case_sets == sets


def test_ours_ref_without_the_reference_data_is_one_line_and_exit_2(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from typer.testing import CliRunner

    from storyteller.benchmark.sweep.grid import case_set_for
    from storyteller.orchestrator.cli.app import app

    absent = DataFolder(tmp_path / "absent", False, "reference data not found: (how to provide it)")
    for name in ("ours-ref", "ours-ref-dev", "ours-ref-test"):
        with pytest.raises(ReferenceDataNotFound, match=f"--cases {name}: these cases are on the authors' scenes"):
            case_set_for(name, absent, ours_folder())
    monkeypatch.setenv("STORYTELLER_REFERENCE", str(tmp_path / "absent"))
    res = CliRunner().invoke(app, ["bench", "run", "--cases", "ours-ref-dev", "--method", "ours", "--model",
                                   "openai/scripted", "--out", str(tmp_path / "sweep")])
    assert res.exit_code == 2
    assert len(res.output.strip().splitlines()) == 1 and "ours-ref-dev" in res.output

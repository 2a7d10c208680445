"""Our case pool (``benchmark/cases/ours``): at least 150 cases with every tag group and every
distraction level, the templated ones reproduced by the generator from the scenes' geometry;
the development / test split fixed by its seed, disjoint, balanced, with no sentence shape on
both sides; the wording varied and sharing no six words in a row with the authors' cases; and
``bench run --cases ours-dev`` / ``--cases ours-test`` running one side each.

(Every case's expected answer is re-derived from the geometry by ``tests/benchmark/own_cases/test_own_cases.py``,
which checks the whole folder.)"""

from __future__ import annotations

import json
import string
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from storyteller.benchmark.own_cases import generate, phrasing, recipes, split
from storyteller.benchmark.own_cases.case_writer import as_case, write_case
from storyteller.benchmark.own_cases.check import ours_folder
from storyteller.benchmark.own_cases.drafts import Draft
from storyteller.benchmark.reference_cases import TAGS, load_cases
from tests.support.reference import TEST_CASES, requires_reference
from tests.support.word_windows import windows

OURS = ours_folder()


@pytest.fixture(scope="module")
def raw() -> list[dict[str, Any]]:
    return [json.loads(p.read_text(encoding="utf-8")) for p in sorted(OURS.glob("*/testcase_*.json"))]


@pytest.fixture(scope="module")
def generated(raw: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [c for c in raw if "generated" in c]


def test_the_pool_has_150_cases_every_tag_group_and_level(raw: list[dict[str, Any]]) -> None:
    cases = load_cases(OURS)
    assert len(cases) >= 150
    assert len({c.id for c in cases}) == len(cases)
    assert {t for c in cases for t in c.tags} == set(TAGS)
    assert set(Counter(c.group for c in cases)) == set(generate.GROUPS)
    for case in cases:  # every case runs at levels 0, 1 and 2, each adding distractors
        sizes = [len(case.at_level(k).current_states) + len(case.at_level(k).planning_history) for k in (0, 1, 2)]
        assert sizes[0] < sizes[1] < sizes[2], case.source
    scenes = Counter(c.scene_name for c in cases if c.id >= generate.FIRST_ID)
    assert set(scenes) == {f"bundled:{s}" for s in generate.SCENES} and min(scenes.values()) >= 40


@pytest.mark.slow
def test_the_generator_reproduces_the_committed_cases() -> None:
    """The templated cases are what the code derives from the scenes today (run
    ``python -m storyteller.benchmark.own_cases.generate`` after changing a recipe, a phrase or the scenes)."""
    assert generate.differences(OURS, generate.generate()) == []


def test_a_generated_case_that_does_not_hold_is_not_written(monkeypatch: pytest.MonkeyPatch) -> None:
    """A recipe whose answer the check refutes (here: every seat said to be the one nearest the
    fridge) yields no case: drafts go through the same check as the folder."""
    facts = generate._facts()["home"]
    bad = Draft("RC", "home", "rc.seat_near", "all-chairs", {"seat": ["chair"], "seats": ["chairs"],
                "lm": ["fridge"], "act": ["read a book"]}, "read_book", objects={"label": "chair"}, count="one")
    data = write_case(bad, facts, 999, "rc.seat_near.a", "dev", 0)
    from storyteller.benchmark.own_cases.check import _Scenes, check_case

    problems = check_case(as_case(data, "1_RC"), _Scenes(OURS)).problems
    assert any("ambiguous" in p for p in problems)
    monkeypatch.setattr(recipes, "RECIPES", {**recipes.RECIPES, "RC": (lambda f: iter([bad]) if f.name == "home" else iter([]),)})
    monkeypatch.setattr(generate, "TARGETS", {g: (5 if g == "RC" else 0) for g in generate.GROUPS})
    assert generate.generate() == []


# ----- the split ---------------------------------------------------------------------------------
def test_the_split_is_disjoint_covers_the_pool_and_matches_the_folder(raw: list[dict[str, Any]]) -> None:
    committed = split.read_split()
    dev, test = set(committed["dev"]), set(committed["test"])
    assert not dev & test
    assert dev | test == {c["id"] for c in raw}
    assert committed == split.split_of(raw)
    assert split.split_file().read_text(encoding="utf-8") == split.render(split.split_of(raw))
    assert all(c["id"] in dev for c in raw if "generated" not in c)  # levers were developed on these
    assert len(test) >= 75 and len(dev) >= 75


def test_the_split_is_stable_and_follows_the_seed() -> None:
    shapes = sorted(phrasing.SHAPES["rc.seat_near"])
    assert split.deal(shapes, "shape:rc.seat_near") == split.deal(shapes, "shape:rc.seat_near")
    items = [f"x{i}" for i in range(20)]
    assert split.deal(items, "k", seed=1) == split.deal(items, "k", seed=1)
    assert split.deal(items, "k", seed=1) != split.deal(items, "k", seed=2)
    sides = Counter(split.deal(items, "k").values())
    assert sides["dev"] == sides["test"] == 10


def test_no_sentence_shape_or_activity_wording_is_on_both_sides(generated: list[dict[str, Any]]) -> None:
    sides: dict[str, set[str]] = {}
    for c in generated:
        sides.setdefault(c["generated"]["shape"], set()).add(c["generated"]["side"])
    assert all(len(s) == 1 for s in sides.values()), {k: v for k, v in sides.items() if len(v) > 1}
    banks = [list(p) for uses in phrasing.DEVICE_USES.values() for _, p in uses]
    banks += [list(p) for p in (*phrasing.SEATED.values(), *phrasing.STANDING.values(), *phrasing.SEATED_USES.values())]
    for bank in banks:
        dev = split.on_side(bank, "act:" + "|".join(sorted(bank)), "dev")
        test = split.on_side(bank, "act:" + "|".join(sorted(bank)), "test")
        assert dev and test and not set(dev) & set(test), bank


def test_each_tag_group_and_scene_is_split_half_and_half(generated: list[dict[str, Any]]) -> None:
    by_group = Counter(("+".join(c["tags"]), c["generated"]["side"]) for c in generated)
    for group in generate.GROUPS:
        assert abs(by_group[(group, "dev")] - by_group[(group, "test")]) <= 3, group
    by_scene = Counter((c["scene_name"], c["generated"]["side"]) for c in generated)
    for scene in generate.SCENES:
        assert abs(by_scene[(f"bundled:{scene}", "dev")] - by_scene[(f"bundled:{scene}", "test")]) <= 6, scene


# ----- wording -----------------------------------------------------------------------------------
def test_the_wording_varies(generated: list[dict[str, Any]]) -> None:
    shapes = Counter(c["generated"]["shape"] for c in generated)
    assert len(shapes) >= 40
    assert max(shapes.values()) <= 0.05 * len(generated), shapes.most_common(3)
    texts = [c["user_instruction"] for c in generated]
    assert len(set(texts)) == len(texts)
    openings = Counter(" ".join(t.split()[1:3]) for t in texts)  # the words after the first
    assert max(openings.values()) <= 0.1 * len(texts), openings.most_common(3)


def _template_texts() -> list[str]:
    """Every literal stretch of every shape (between slots) and every phrase of the banks."""
    texts = []
    for shapes in phrasing.SHAPES.values():
        for shape in shapes.values():
            texts += [lit for lit, _, _, _ in string.Formatter().parse(shape) if lit]
    for uses in phrasing.DEVICE_USES.values():
        texts += [p for _, phrases in uses for p in phrases]
    for bank in (phrasing.SEATED, phrasing.STANDING, phrasing.SEATED_USES):
        texts += [p for phrases in bank.values() for p in phrases]
    return texts


def test_the_overlap_rule_catches_a_six_word_run() -> None:
    assert windows("she sits on the couch by the window") & windows("Then sits on the couch by the door")
    assert not windows("she sits on the couch by the window") & windows("sits on the sofa by the window")


@requires_reference
def test_no_template_or_generated_text_shares_six_words_with_the_authors_cases(generated: list[dict[str, Any]]) -> None:
    reference: set[tuple[str, ...]] = set()
    for path in sorted(TEST_CASES.glob("*/testcase_*.json")):
        data = json.loads(path.read_text(encoding="utf-8"))
        reference |= windows(data["user_instruction"])
        for event in data.get("planning_history", []):
            reference |= windows(event["activity"])
    assert reference
    texts = _template_texts()
    texts += [t for c in generated for t in (c["user_instruction"], *(e["activity"] for e in c["planning_history"]))]
    shared = sorted({" ".join(w) for t in texts for w in windows(t) & reference})
    assert not shared


# ----- one command per side ----------------------------------------------------------------------
def test_ours_dev_and_ours_test_select_one_side_each(tmp_path: Path) -> None:
    from storyteller.benchmark.sweep.execute import SweepWorkspace
    from storyteller.benchmark.sweep.grid import SweepSpec, case_set_for, model_specs
    from storyteller.benchmark.sweep.runner import relocated
    from storyteller.orchestrator.reference_data import locate_reference

    sets = tuple(case_set_for(name, locate_reference(), OURS) for name in ("ours-dev", "ours-test", "ours"))
    spec = SweepSpec(case_sets=sets, models=model_specs(["openai/scripted"], []))
    ws = SweepWorkspace(spec, tmp_path)
    committed = split.read_split()
    assert sorted(ws.cases["ours-dev"]) == committed["dev"]
    assert sorted(ws.cases["ours-test"]) == committed["test"]
    assert len(ws.cases["ours"]) == len(committed["dev"]) + len(committed["test"])
    moved = spec.model_copy(update={"case_sets": tuple(s.model_copy(update={"path": "/nowhere"}) for s in sets)})
    assert relocated(moved).case_sets == sets  # a published sweep finds the split where it is now
    assert "case_ids" not in sets[2].model_dump()  # the whole set's sweep.json is as before


def test_bench_run_runs_one_side_by_one_command(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from typer.testing import CliRunner

    import storyteller.benchmark.sweep.runner as runner
    from storyteller.orchestrator.cli.app import app
    from tests.support.scripted_sweep import scripted

    calls: list[str] = []
    real_run_sweep = runner.run_sweep

    async def scripted_run_sweep(*args: Any, **kw: Any) -> object:  # run_sweep's own arguments, passed through
        return await real_run_sweep(*args, **{**kw, "factory": scripted(calls, lambda request: "{}")})

    monkeypatch.setattr(runner, "run_sweep", scripted_run_sweep)
    committed = split.read_split()
    dev_id, test_id = committed["dev"][0], committed["test"][0]
    out = tmp_path / "sweep"
    res = CliRunner().invoke(app, ["bench", "run", "--cases", "ours-test", "--case-id", str(dev_id), "--case-id",
                                   str(test_id), "--method", "ours", "--model", "openai/scripted", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "sweep: 1 runs" in res.output  # the dev case is not a test case
    (line,) = (out / "results.jsonl").read_text(encoding="utf-8").splitlines()
    assert json.loads(line)["run_id"].startswith(f"ours-test-c{test_id:03d}-")
    saved = json.loads((out / "sweep.json").read_text(encoding="utf-8"))
    assert saved["case_sets"][0]["case_ids"] == committed["test"]

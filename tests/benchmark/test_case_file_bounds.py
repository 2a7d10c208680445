"""Benchmark case files and story-suite scenarios are outside text: a case that is not UTF-8,
nested thousands deep, oversized, or named ``testcase_one.json`` used to be a traceback. Each is
one ``BenchmarkCaseError`` / ``ScenarioError`` naming the file, and one line with exit code 2
through ``storyteller bench run`` (which reads the cases before it needs a model)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from storyteller.benchmark.reference_cases import MAX_CASE_BYTES, BenchmarkCaseError, case_files, load_case
from storyteller.benchmark.story_suite.scenario import ScenarioError, load_scenario
from storyteller.orchestrator.cli.app import app
from tests.support.finished_run import one_error_line

ROOT = Path(__file__).resolve().parents[2]
GOOD_CASE = sorted((ROOT / "benchmark" / "cases" / "ours").rglob("testcase_*.json"))[0]


def case_folder(tmp_path: Path, name: str, content: bytes) -> Path:
    folder = tmp_path / "cases"
    (folder / "0_OA").mkdir(parents=True)
    (folder / "0_OA" / "testcase_1.json").write_bytes(GOOD_CASE.read_bytes())
    (folder / "0_OA" / name).write_bytes(content)
    return folder


def bench_run(folder: Path, tmp_path: Path) -> str:
    result = CliRunner().invoke(
        app, ["bench", "run", "--cases", str(folder), "--out", str(tmp_path / "sweep"), "--method", "ours",
              "--model", "local/qwen2.5-coder-0.5b"]
    )
    return one_error_line(result)


@pytest.mark.parametrize(
    ("name", "content", "words"),
    [
        ("testcase_2.json", b'{"id": 2, "scene_name": "caf\xe9"}', "UTF-8"),
        ("testcase_2.json", b"[" * 100_000 + b"]" * 100_000, "nested"),
        ("testcase_2.json", b'{"id": ' + b"9" * 5_000 + b"}", "digits"),
        ("testcase_2.json", b'{"id": 2, "x": NaN}', "finite"),
        ("testcase_one.json", b"{}", "numeric id"),
        ("testcase_" + "9" * 200 + ".json", b"{}", "numeric id"),  # int() of it was fine; 9 digits at most
    ],
)
def test_a_bad_case_file_is_one_line_naming_it(tmp_path: Path, name: str, content: bytes, words: str) -> None:
    folder = case_folder(tmp_path, name, content)
    with pytest.raises(BenchmarkCaseError, match=words) as info:
        [load_case(p) for p in case_files(folder)]
    assert name in str(info.value) and "\n" not in str(info.value)
    assert name in bench_run(folder, tmp_path)


def test_an_oversized_case_file(tmp_path: Path) -> None:
    path = tmp_path / "testcase_3.json"
    with path.open("wb") as f:  # sparse
        f.truncate(MAX_CASE_BYTES + 1)
    with pytest.raises(BenchmarkCaseError, match="allowed"):
        load_case(path)


def test_the_good_case_still_loads(tmp_path: Path) -> None:
    case = load_case(GOOD_CASE)
    assert case.id == json.loads(GOOD_CASE.read_text(encoding="utf-8"))["id"]


@pytest.mark.parametrize(
    ("content", "words"),
    [(b"x = " + b"[" * 5_000 + b"]" * 5_000, "nested too deeply"), (b'scene = "caf\xe9"', "UTF-8")],
)
def test_a_bad_scenario_file_is_one_scenario_error(tmp_path: Path, content: bytes, words: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_bytes(content)
    with pytest.raises(ScenarioError, match=words) as info:
        load_scenario(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)

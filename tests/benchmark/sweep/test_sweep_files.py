"""A sweep folder is untrusted input (issue 22): ``bench score`` re-scores anyone's sweep.

Found by ``benchmark/hostile_inputs.py``: a ``results.jsonl`` link, a run trace that is a link
to ``/dev/zero`` or nested 100,000 deep, a ``sweep.json`` with a 5,000-digit case id and a
results line that is not a result each gave a traceback (exit 1); ``plots/`` linked to a folder
outside had the plots written there, and ``write_atomic`` wrote through a planted ``.tmp``.
Now every read goes through ``storyteller.benchmark.sweep.sweep_files`` (bounded, no links, validated: one
line, exit 2) and every write replaces the name, never what a link there points at.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from storyteller.benchmark.sweep.grid import CaseSetSpec, ModelSpec, SweepSpec, model_specs
from storyteller.benchmark.sweep.plots import write_plots
from storyteller.benchmark.sweep.results import read_results, write_atomic
from storyteller.benchmark.sweep.sweep_files import SweepFileError, append_line, read_json_model
from storyteller.orchestrator.cli.app import app
from tests.support.finished_run import one_error_line

OURS = Path(__file__).resolve().parents[3] / "benchmark" / "cases" / "ours"


def _spec() -> SweepSpec:
    return SweepSpec(case_sets=(CaseSetSpec(name="ours", path=str(OURS)),), case_ids=(100,), levels=(2,),
                     methods=("ours",),
                     models=(ModelSpec(label="scripted", config=model_specs(["openai/scripted"], [])[0].config),))


@pytest.fixture
def sweep(tmp_path: Path) -> Path:
    out = tmp_path / "sweep"
    out.mkdir()
    (out / "sweep.json").write_text(_spec().model_dump_json(indent=1) + "\n", encoding="utf-8")
    (tmp_path / "victim.txt").write_text("victim\n", encoding="utf-8")
    return out


def _score(out: Path) -> str:
    return one_error_line(CliRunner().invoke(app, ["bench", "score", str(out)]))


def test_results_that_are_a_link_deep_or_not_results_are_one_line(sweep: Path) -> None:
    results = sweep / "results.jsonl"
    results.symlink_to(sweep.parent / "victim.txt")
    assert "symbolic link" in _score(sweep)
    results.unlink()
    results.write_text("[" * 100_000 + "]" * 100_000 + "\n", encoding="utf-8")
    assert "line 1" in _score(sweep) and "nested" in _score(sweep)
    results.write_text('{"run_id": "\\u202e"}\n', encoding="utf-8")
    line = _score(sweep)
    assert "results.jsonl: line 1: field" in line and "\u202e" not in line
    results.write_bytes(b'{"run_id": "x"')  # a torn line only: no result, nothing to score
    assert read_results(results) == []


def test_a_spec_with_huge_numbers_or_duplicates_is_one_line(sweep: Path) -> None:
    path = sweep / "sweep.json"
    path.write_text(path.read_text(encoding="utf-8").replace('"case_ids": [', '"case_ids": [' + "9" * 5000 + ", "),
                    encoding="utf-8")
    assert "sweep.json" in _score(sweep)
    os.unlink(path)
    os.mkfifo(path)
    assert "not a regular file" in _score(sweep)
    with pytest.raises(SweepFileError, match="not a regular file"):
        read_json_model(path, SweepSpec)


def test_writes_replace_planted_links_and_refuse_a_linked_folder(sweep: Path, tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    for name in ("report.md", "report.md.tmp"):
        (sweep / name).symlink_to(victim)
    write_atomic(sweep / "report.md", b"# report\n")
    assert victim.read_text(encoding="utf-8") == "victim\n"
    assert not (sweep / "report.md").is_symlink() and (sweep / "report.md").read_bytes() == b"# report\n"
    os.link(victim, sweep / "results.jsonl")
    with pytest.raises(OSError) as refused:
        append_line(sweep / "results.jsonl", b"{}\n")
    assert refused.value.errno == errno.EMLINK and victim.read_text(encoding="utf-8") == "victim\n"
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (sweep / "plots").symlink_to(outside)
    with pytest.raises(OSError) as linked:
        write_plots(sweep / "plots", [])
    assert linked.value.errno == errno.ELOOP and list(outside.iterdir()) == []
    (sweep / "results.jsonl").unlink()
    (sweep / "results.jsonl").write_text("", encoding="utf-8")
    before = {p.name: p.read_bytes() for p in sweep.iterdir() if p.is_file() and not p.is_symlink()}
    assert "plots" in _score(sweep) and "symbolic link" in _score(sweep)  # refused before anything is rewritten
    assert {p.name: p.read_bytes() for p in sweep.iterdir() if p.is_file() and not p.is_symlink()} == before


def test_a_sweep_of_more_runs_than_allowed_is_one_line(sweep: Path) -> None:
    """Found by the second hostile corpus: a sweep.json of 10**9 repeats made ``bench score``
    expand a billion runs (killed after 11 s at 1.9 GB). The grid is counted before it is built."""
    from storyteller.benchmark.sweep.grid import MAX_RUNS, SweepSpecError, expand

    path = sweep / "sweep.json"
    path.write_text(path.read_text(encoding="utf-8").replace('"repeats": 1', f'"repeats": {10**9}'), encoding="utf-8")
    assert "repeats" in _score(sweep)
    wide = _spec().model_copy(update={"repeats": MAX_RUNS})
    with pytest.raises(SweepSpecError, match=f"{2 * MAX_RUNS} runs"):
        expand(wide, {"ours": [100, 101]})
    assert len(expand(wide, {"ours": [100]})) == MAX_RUNS

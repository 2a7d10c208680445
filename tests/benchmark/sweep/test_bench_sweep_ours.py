"""``storyteller bench`` on our own cases (bundled scenes), which need no reference data, and
the execution rate with self-feedback on: a reply rejected on the first attempt and accepted
on the retry counts as executed after feedback but not on the first attempt.

A scripted port writes real traces (:mod:`tests.support.scripted_sweep`); no model is loaded.
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from storyteller.agents.llm_port import LLMRequest
from storyteller.benchmark.sweep.execute import PortFactory
from storyteller.benchmark.sweep.grid import CaseSetSpec, ModelSpec, SweepSpec, model_specs
from storyteller.benchmark.sweep.results import read_results
from storyteller.benchmark.sweep.runner import run_sweep, score_sweep
from tests.support.scripted_sweep import TracedScript, scripted

OURS = Path(__file__).resolve().parents[3] / "benchmark" / "cases" / "ours"
CASE = 100  # bundled:home, OA: Ines uses the laptop sitting on chair_5 (Bruno reads in armchair_1 from level 1)
NARRATION = json.dumps({"reasoning": "asked for", "event": {"characters": ["Ines"], "activity": "type notes on the laptop"}})
PROGRAM = ('a = get_character("Ines")\n    a.set_position(get_area_to_sit_on("chair_5"))\n'
           '    a.set_target_action("use_laptop")')
REJECTED = {  # first replies the graph's checks reject
    "narrator": json.dumps({"reasoning": "x", "event": {"characters": ["Bruno"], "activity": "type notes"}}),  # busy
    "event_parser": PROGRAM.replace("chair_5", "chair_99"),  # no such object
}
FILES = ("results.jsonl", "results.csv", "report.md", "plots/success_by_characters.png",
         "plots/tokens_by_description.png")


def reply(node: str, program: str = PROGRAM) -> str:
    if node == "describer":
        return "{}"  # unusable: the graph repairs the description from the clusters
    if node == "narrator":
        return NARRATION
    return f"```python\ndef parse_event():\n    {program}\n```"


def answer(request: LLMRequest) -> str:
    return reply(request.node)


def first_rejected(calls: list[str], faults: dict[str, str]) -> PortFactory:
    """Every reply right, except the first reply to the node ``faults[tag]`` in the runs whose
    trace name holds ``tag`` (e.g. ``-r0-``: repeat 0)."""

    def factory(model: ModelSpec, trace: Path) -> TracedScript:
        node = next((n for tag, n in faults.items() if tag in trace.name), None)
        served: set[str] = set()

        def flaky(request: LLMRequest) -> str:
            if request.node == node and node not in served:
                served.add(node)
                bad = REJECTED[node]
                return bad if node == "narrator" else reply(node, bad)
            return reply(request.node)

        return TracedScript(trace, calls, flaky)

    return factory


def spec(**changes: object) -> SweepSpec:
    base = SweepSpec(
        case_sets=(CaseSetSpec(name="ours", path=str(OURS)),), case_ids=(CASE,), levels=(2,), methods=("ours",),
        models=(ModelSpec(label="scripted", config=model_specs(["openai/scripted"], [])[0].config),),
    )
    return base.model_copy(update=changes)


@pytest.mark.parametrize("where", ["absent", "empty"])
@pytest.mark.slow
def test_a_sweep_of_our_cases_needs_no_reference_data(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, where: str,
) -> None:
    """``bench run --cases ours`` with ``STORYTELLER_REFERENCE`` on a missing or empty folder
    runs, and ``bench score`` / ``bench report`` reproduce it, also after the sweep moved; the
    case sets that need the reference data still refuse with the lookup's reason."""
    import storyteller.benchmark.sweep.runner as runner
    from storyteller.orchestrator.cli.app import app

    folder = tmp_path / where
    if where == "empty":
        folder.mkdir()
    monkeypatch.setenv("STORYTELLER_REFERENCE", str(folder))
    calls: list[str] = []
    real_run_sweep = runner.run_sweep

    async def scripted_run_sweep(*args: Any, **kw: Any) -> object:  # the CLI's live port -> the script
        return await real_run_sweep(*args, **{**kw, "factory": scripted(calls, answer)})

    monkeypatch.setattr(runner, "run_sweep", scripted_run_sweep)
    out = tmp_path / "sweep"
    cli = CliRunner()
    res = cli.invoke(app, ["bench", "run", "--cases", "ours", "--case-id", str(CASE), "--method", "ours",
                           "--model", "openai/scripted", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "1 runs, 1 passed" in res.output and calls == ["describer", "narrator", "event_parser"]
    saved = json.loads((out / "sweep.json").read_text(encoding="utf-8"))
    assert saved["case_sets"] == [{"name": "ours", "path": str(OURS), "scenes_root": None}]
    files = {f: (out / f).read_bytes() for f in FILES}

    published = json.loads((out / "sweep.json").read_text(encoding="utf-8"))  # as recorded on another machine
    published["case_sets"] = [{"name": "ours", "path": "/nowhere/ours", "scenes_root": "/nowhere/reference"}]
    (out / "sweep.json").write_text(json.dumps(published), encoding="utf-8")
    for name in ("results.csv", "report.md"):
        (out / name).unlink()
    res = cli.invoke(app, ["bench", "score", str(out)])
    assert res.exit_code == 0 and "1 runs re-scored, 1 passed" in res.output, res.output
    assert {f: (out / f).read_bytes() for f in FILES} == files
    (out / "report.md").unlink()
    res = cli.invoke(app, ["bench", "report", str(out)])
    assert res.exit_code == 0 and {f: (out / f).read_bytes() for f in FILES} == files, res.output

    if where == "empty":
        return  # an empty folder counts as found: what needs it fails later, on its files
    res = cli.invoke(app, ["bench", "run", "--cases", "reference", "--model", "m", "--out", str(tmp_path / "ref")])
    assert res.exit_code == 2 and f"reference data not found: STORYTELLER_REFERENCE={folder}" in res.output
    mine = tmp_path / "mine" / "0_OA"
    mine.mkdir(parents=True)
    case = json.loads((OURS / "0_OA" / f"testcase_{CASE}.json").read_text(encoding="utf-8"))
    (mine / f"testcase_{CASE}.json").write_text(json.dumps({**case, "scene_name": "House"}), encoding="utf-8")
    res = cli.invoke(app, ["bench", "run", "--cases", str(mine.parent), "--model", "m", "--out", str(tmp_path / "m")])
    assert res.exit_code == 2, res.output
    assert f"case {CASE} is on the reference scene 'House'; reference data not found" in res.output


@pytest.mark.slow
def test_execution_on_the_first_attempt_and_after_feedback(tmp_path: Path) -> None:
    """Three repeats of one case: the first reply of the event parser (repeat 0) or of the
    narrator (repeat 1) is rejected, repeat 2 is right at once. With one feedback retry all
    three execute and pass, but only repeat 2 on the first attempt; without feedback the two
    rejected replies are execution failures."""
    faults = {"-r0-": "event_parser", "-r1-": "narrator"}
    calls: list[str] = []
    out = tmp_path / "feedback"
    asyncio.run(run_sweep(spec(repeats=3, feedback=1), out, factory=first_rejected(calls, faults)))
    results = read_results(out / "results.jsonl")
    assert [(r.repeat, r.verdict, r.executed, r.executed_first) for r in results] == [
        (0, "pass", True, False), (1, "pass", True, False), (2, "pass", True, True)], [r.reason for r in results]
    assert [[(c.node) for c in r.calls] for r in results] == [
        ["narrator", "event_parser", "event_parser"], ["narrator", "narrator", "event_parser"],
        ["narrator", "event_parser"]]
    report = (out / "report.md").read_text(encoding="utf-8")
    assert "| scripted | Ours | 1.00 (0.33) | 1.00 (0.33) | - | - |" in report
    table = report.split("### Execution after up to 1 feedback retries\n\n")[1].split("###")[0]
    assert table == "| Model | Method | Execution |\n|---|---|---|\n| scripted | Ours | 1.00 |\n\n"
    files = {f: (out / f).read_bytes() for f in FILES}
    asyncio.run(score_sweep(out))  # the replay reads the same acceptances from the traces
    assert {f: (out / f).read_bytes() for f in FILES} == files

    out = tmp_path / "no-feedback"
    asyncio.run(run_sweep(spec(repeats=3), out, factory=first_rejected([], faults)))
    results = read_results(out / "results.jsonl")
    assert [(r.verdict, r.executed, r.executed_first, r.error_class) for r in results] == [
        ("error", False, False, "failure:event_parser"), ("error", False, False, "failure:narrator"),
        ("pass", True, True, None)]
    report = (out / "report.md").read_text(encoding="utf-8")
    assert "| scripted | Ours | 0.33 (0.33) | 0.33 (0.33) | - | - |" in report
    assert "feedback retries" not in report

"""``storyteller bench`` sweeps on three reference cases x two methods with a scripted model that
writes real traces: every file is written, a killed sweep resumes with only its missing runs,
``bench score`` replays the traces into the same bytes, the report has the paper's layout, and
the command group registers as an entry-point plugin."""

from __future__ import annotations

import asyncio
import json
import re
from importlib.metadata import EntryPoint
from pathlib import Path
from typing import Any

import pytest
import typer
from typer.testing import CliRunner

from storyteller.agents.llm_port import LLMRequest
from storyteller.benchmark.sweep.execute import PortFactory
from storyteller.benchmark.sweep.grid import (
    CaseSetSpec,
    ModelSpec,
    RunKey,
    SweepSpec,
    SweepSpecError,
    model_specs,
)
from storyteller.benchmark.sweep.progress import LineProgress
from storyteller.benchmark.sweep.results import read_results
from storyteller.benchmark.sweep.runner import report_sweep, run_sweep, score_sweep
from storyteller.orchestrator.reference_data import locate_reference
from tests.support.reference import REFERENCE, requires_reference
from tests.support.scripted_sweep import scripted as scripted_port

pytestmark = requires_reference

PROGRAMS = {  # correct answers, as an event parser would write them
    0: ("Ryan", "text a friend near table_3", 'a = get_character("Ryan")\n'
        '    a.set_position(get_area_close_to("table_3"))\n    a.set_target_action("use_smartphone")'),
    20: ("Taylor", "read a book sitting on chair_3", 'a = get_character("Taylor")\n'
         '    a.set_position(get_area_to_sit_on("chair_3"))\n    a.set_target_action("read_book")'),
    60: ("Theodore", "wait in front of the fridge", 'a = get_character("Theodore")\n'
         '    a.set_position(get_area_in_front_of("fridge_1"))\n    a.set_target_action("idle")'),
}
FILES = ("sweep.json", "results.jsonl", "results.csv", "report.md", "plots/success_by_characters.png",
         "plots/tokens_by_description.png")


def answer(request: LLMRequest) -> str:
    """The describer gets an unusable reply (the graph repairs it from the clusters); the
    narrator and parser get the known-good reply of the case whose character they name."""
    if request.node == "describer":
        return "{}"
    text = " ".join(m.content for m in request.messages if m.role == "user")
    case = next(c for c, (who, _, _) in PROGRAMS.items() if who in text)
    who, activity, program = PROGRAMS[case]
    if request.node == "narrator":
        return json.dumps({"reasoning": "asked for", "event": {"characters": [who], "activity": activity}})
    if request.choices is not None:  # the action choice of an event whose words name no action
        return json.dumps({"choice": program.rsplit('set_target_action("', 1)[1].split('"')[0]})
    return f"```python\ndef parse_event():\n    {program}\n```"


def scripted(calls: list[str]) -> PortFactory:
    return scripted_port(calls, answer)


def spec(**changes: object) -> SweepSpec:
    base = SweepSpec(
        case_sets=(CaseSetSpec(name="reference", path=str(REFERENCE), scenes_root=str(REFERENCE)),),
        case_ids=(0, 20, 60), levels=(2,), methods=("ours", "object-list"),
        models=(ModelSpec(label="scripted", config=model_specs(["openai/scripted"], [])[0].config),),
    )
    return base.model_copy(update=changes)


def sweep(out: Path, calls: list[str] | None = None, **kw: Any) -> list[str]:
    """``run_sweep`` on ``spec()`` with the scripted port; ``kw``: run_sweep's own keywords."""
    calls = [] if calls is None else calls
    asyncio.run(run_sweep(spec(), out, factory=scripted(calls), **kw))
    return calls


def snapshot(out: Path) -> dict[str, bytes]:
    return {f: (out / f).read_bytes() for f in FILES}


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str], dict[str, bytes]]:
    out = tmp_path_factory.mktemp("sweep")
    calls = sweep(out)
    return out, calls, snapshot(out)


def test_sweep_writes_every_file_with_one_line_per_run(finished: tuple[Path, list[str], dict[str, bytes]]) -> None:
    out, calls, files = finished
    results = read_results(out / "results.jsonl")
    assert [(r.case, r.method) for r in results] == [
        (0, "ours"), (0, "object-list"), (20, "ours"), (20, "object-list"), (60, "ours"), (60, "object-list")]
    assert calls.count("describer") == 1  # one description of House for the model, shared by the ours runs
    # cases 20 and 60 name no action the label ranker knows: one action choice each, per method
    assert calls.count("narrator") == 6 and calls.count("event_parser") == 10
    assert all(r.verdict == "pass" and r.executed_first and r.error_class is None for r in results), \
        [r.reason for r in results]
    r = results[0]
    assert r.models == {"describer": "openai/scripted", "event_parser": "openai/scripted",
                        "narrator": "openai/scripted", "planner": "openai/scripted"}
    assert [c.node for c in r.calls] == ["narrator", "event_parser"] and r.latency_s == 0.5
    assert r.prompt_tokens == sum(c.prompt_tokens for c in r.calls) > 0
    assert (out / "descriptions" / "House-scripted.json").exists()
    assert len(list((out / "traces" / "runs").glob("*.jsonl"))) == 6
    header, *rows = files["results.csv"].decode().splitlines()
    assert header.startswith("run_id,case_set,case,group,characters,level") and len(rows) == 6
    assert files["plots/success_by_characters.png"].startswith(b"\x89PNG")


def test_report_has_the_papers_layout(finished: tuple[Path, list[str], dict[str, bytes]]) -> None:
    report = finished[2]["report.md"].decode()
    assert "| Model | Method | Total | OA | RC | SS |" in report
    assert "| scripted | Ours | 1.00 (1.00) | 1.00 (1.00) | - | 1.00 (1.00) |" in report
    assert "| scripted | Object List | 1.00 (1.00) | 1.00 (1.00) | - | 1.00 (1.00) |" in report
    pi = report.split("### Position inference (PI)")[1]
    assert "| scripted | Ours | 1.00 (1.00) |" in pi.split("###")[0]
    assert "| Model | Method | level 2 |" in report
    assert re.search(r"\| Model \| Method \| 1 char\. \| 5 char\. \| 6 char\. \|", report)
    assert "| object-list | narrator | 3 |" in report and "| describer | event_parser | 5 |" in report
    assert "| scripted | narrator | 6 | 0.25 | 0.25 | 0.25 |" in report


@pytest.mark.slow
def test_score_replays_the_traces_into_the_same_bytes(
    finished: tuple[Path, list[str], dict[str, bytes]], tmp_path: Path
) -> None:
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(finished[0], out)
    for name in ("results.csv", "report.md"):
        (out / name).write_text("stale", encoding="utf-8")
    replayed: list[str] = []

    def counting_replay(model: ModelSpec, trace: Path) -> Any:
        from storyteller.orchestrator.llm.replay import ReplayClient

        replayed.append(trace.name)
        return ReplayClient(trace)

    asyncio.run(score_sweep(out, factory=counting_replay))
    assert snapshot(out) == finished[2]
    assert len(replayed) == 7  # one description, six runs
    asyncio.run(score_sweep(out))
    assert snapshot(out) == finished[2]
    report_sweep(out)
    assert snapshot(out) == finished[2]


def test_score_fails_with_a_diff_when_a_trace_does_not_match(
    finished: tuple[Path, list[str], dict[str, bytes]], tmp_path: Path
) -> None:
    import shutil

    from storyteller.agents.llm_port import ReplayMissError

    out = tmp_path / "copy"
    shutil.copytree(finished[0], out)
    sweep_json = json.loads((out / "sweep.json").read_text())
    sweep_json["seed"] = 5  # other seeds: other requests than the recorded ones
    (out / "sweep.json").write_text(json.dumps(sweep_json))
    with pytest.raises(ReplayMissError, match="replay miss for node"):
        asyncio.run(score_sweep(out))


@pytest.mark.slow
def test_a_killed_sweep_redoes_only_its_missing_runs(
    finished: tuple[Path, list[str], dict[str, bytes]], tmp_path: Path
) -> None:
    out = tmp_path / "killed"
    sweep(out)
    lines = (out / "results.jsonl").read_bytes().splitlines(keepends=True)
    (out / "results.jsonl").write_bytes(b"".join(lines[:2]) + lines[2][:40])  # killed mid-append
    in_flight = out / "traces" / "runs" / (json.loads(lines[3])["run_id"] + ".jsonl")
    in_flight.write_bytes(in_flight.read_bytes()[:-30])  # its trace cut short too
    for name in ("results.csv", "report.md"):
        (out / name).unlink()
    calls = sweep(out)
    assert calls == ["narrator", "event_parser", "event_parser"] * 4  # four runs redone (cases 20 and 60, with
    # their action choices), the description reused
    assert snapshot(out) == finished[2]
    assert sweep(out) == []  # nothing left to do


@pytest.mark.slow
def test_parallel_runs_give_the_same_files(finished: tuple[Path, list[str], dict[str, bytes]], tmp_path: Path) -> None:
    out = tmp_path / "jobs"
    calls = sweep(out, jobs=3)
    assert len(calls) == 17
    assert snapshot(out) == finished[2]


def test_other_arguments_in_the_same_folder_are_refused(finished: tuple[Path, list[str], dict[str, bytes]]) -> None:
    with pytest.raises(SweepSpecError, match="field 'levels' differs"):
        asyncio.run(run_sweep(spec(levels=(0, 2)), finished[0], factory=scripted([])))


def test_a_sweep_moved_to_another_machine_resumes_where_its_cases_and_config_now_are(
    finished: tuple[Path, list[str], dict[str, bytes]], tmp_path: Path,
) -> None:
    """Where the reference cases and the config file are is not part of the sweep: the same
    arguments from another folder resume it (nothing to redo) and sweep.json takes the new places."""
    import shutil

    out = tmp_path / "moved"
    shutil.copytree(finished[0], out)
    cases = tmp_path / "elsewhere"
    cases.symlink_to(REFERENCE)
    base = spec()
    config = base.models[0].config.model_copy(update={"source": "/another/machine/config.toml"})
    moved = base.model_copy(update={
        "case_sets": (CaseSetSpec(name="reference", path=str(cases), scenes_root=str(cases)),),
        "models": (base.models[0].model_copy(update={"config": config}),),
    })
    calls: list[str] = []
    asyncio.run(run_sweep(moved, out, factory=scripted(calls)))
    assert calls == []
    assert {k: v for k, v in snapshot(out).items() if k != "sweep.json"} == {
        k: v for k, v in finished[2].items() if k != "sweep.json"}
    saved = json.loads((out / "sweep.json").read_text(encoding="utf-8"))
    assert saved["case_sets"][0]["path"] == str(cases)
    assert saved["models"][0]["config"]["source"] == "/another/machine/config.toml"
    renamed = moved.model_copy(update={"case_sets": (CaseSetSpec(name="mine", path=str(cases), scenes_root=str(cases)),)})
    with pytest.raises(SweepSpecError, match="field 'case_sets' differs"):
        asyncio.run(run_sweep(renamed, out, factory=scripted([])))


@pytest.mark.slow
def test_a_published_sweep_scores_on_a_machine_where_its_case_folder_is_elsewhere(
    finished: tuple[Path, list[str], dict[str, bytes]], tmp_path: Path,
) -> None:
    """sweep.json names the folder of the machine that ran it; ``bench score`` elsewhere finds
    the reference cases through the resolver and writes the same files."""
    import shutil

    out = tmp_path / "published"
    shutil.copytree(finished[0], out)
    recorded = (out / "sweep.json").read_text(encoding="utf-8")
    away = recorded.replace(json.dumps(str(REFERENCE)), json.dumps("/nowhere/reference"))
    assert away != recorded
    (out / "sweep.json").write_text(away, encoding="utf-8")
    (out / "results.csv").unlink()
    asyncio.run(score_sweep(out))
    assert {k: v for k, v in snapshot(out).items() if k != "sweep.json"} == {
        k: v for k, v in finished[2].items() if k != "sweep.json"}


def test_line_progress_reports_rate_and_eta(finished: tuple[Path, list[str], dict[str, bytes]]) -> None:
    import io

    now = [0.0]
    stream = io.StringIO()
    p = LineProgress(stream, clock=lambda: now[0])
    base = read_results(finished[0] / "results.jsonl")[0]
    p.start(4, [base])
    now[0] = 30.0
    p.advance(base.model_copy(update={"verdict": "fail", "run_id": "r2"}))
    out = stream.getvalue().splitlines()
    assert out == ["sweep: 4 runs, 1 already done", "[2/4] r2: fail (pass rate 0.50, ETA 1:00)"]


def _app() -> typer.Typer:
    from storyteller.orchestrator.cli.app import register_plugins

    app = typer.Typer(no_args_is_help=True)

    @app.command("noop")
    def _noop() -> None:  # a second command, so typer keeps subcommand names
        """Nothing."""

    names = register_plugins(app, [
        EntryPoint(name="bench", value="storyteller.benchmark.sweep.cli:register", group="storyteller.commands"),
        EntryPoint(name="gone", value="storyteller.benchmark.no_such_module:register", group="storyteller.commands"),
        EntryPoint(name="bench", value="storyteller.benchmark.sweep.cli:register", group="storyteller.commands"),
        EntryPoint(name="old", value="benchmark.sweep.cli:register", group="storyteller.commands"),  # stale egg-info
    ])
    assert names == ["bench"]
    return app


def test_a_plugin_from_stale_install_metadata_is_skipped_with_a_warning(capsys: pytest.CaptureFixture[str]) -> None:
    from storyteller.orchestrator.cli.app import register_plugins

    app = typer.Typer()
    names = register_plugins(app, [
        EntryPoint(name="bench", value="benchmark.sweep.cli:register", group="storyteller.commands"),
        EntryPoint(name="bench", value="storyteller.benchmark.sweep.cli:register", group="storyteller.commands"),
        EntryPoint(name="bench", value="storyteller.benchmark.sweep.cli:register", group="storyteller.commands"),
    ])
    assert names == ["bench"]
    err = capsys.readouterr().err
    assert "stale install metadata" in err and "pip install -e ." in err


@pytest.mark.slow
def test_bench_is_a_command_plugin_whose_commands_run(finished: tuple[Path, list[str], dict[str, bytes]], tmp_path: Path) -> None:
    import shutil

    out = tmp_path / "cli"
    shutil.copytree(finished[0], out)
    app = _app()
    runner = CliRunner()
    res = runner.invoke(app, ["bench", "score", str(out)])
    assert res.exit_code == 0, res.output
    assert "6 runs re-scored, 6 passed" in res.output
    assert snapshot(out) == finished[2]
    res = runner.invoke(app, ["bench", "report", str(out)])
    assert res.exit_code == 0 and snapshot(out) == finished[2]
    res = runner.invoke(app, ["bench", "run", "--out", str(tmp_path / "x"), "--method", "nope", "--model", "m"])
    assert res.exit_code == 2 and "--method 'nope': expected one of ours, wo-event" in res.output
    res = runner.invoke(app, ["bench", "score", str(tmp_path)])
    assert res.exit_code == 2 and "not a sweep folder" in res.output
    res = runner.invoke(app, ["bench", "run", "--out", str(out), "--case-id", "0", "--case-id", "20",
                              "--case-id", "60", "--method", "ours", "--method", "object-list", "--model", "m"])
    assert res.exit_code == 2 and "holds a sweep with other arguments" in res.output


def test_the_plugin_module_imports_only_typer() -> None:
    import subprocess
    import sys

    code = ("import sys, storyteller.benchmark.sweep.cli; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('litellm', 'langgraph', 'matplotlib') "
            "or m.startswith('storyteller.orchestrator')))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"


@pytest.mark.slow
def test_ray_executor_gives_the_same_files(finished: tuple[Path, list[str], dict[str, bytes]], tmp_path: Path) -> None:
    ray = pytest.importorskip("ray", reason="the optional [ray] extra is not installed")
    from storyteller.benchmark.sweep.ray_executor import ray_executor

    out = tmp_path / "ray"
    here = Path(__file__).resolve().parents[2]  # workers unpickle the scripted port (tests.support) and answer (this module)
    try:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
                 runtime_env={"env_vars": {"PYTHONPATH": f"{here.parent}:{here}"}})
        calls: list[str] = []  # calls made in the workers do not come back here: count the traces instead
        asyncio.run(run_sweep(spec(), out, factory=scripted(calls), executor=ray_executor(2, factory=scripted([]))))
    finally:
        ray.shutdown()
    assert calls == ["describer"]  # the description is made by the driver, the runs by the tasks
    assert len(list((out / "traces" / "runs").glob("*.jsonl"))) == 6
    assert snapshot(out) == finished[2]


def test_case_sets_by_name_or_folder(tmp_path: Path) -> None:
    from storyteller.benchmark.reference_cases import load_cases
    from storyteller.benchmark.sweep.grid import case_set_for

    ours = Path(__file__).resolve().parents[3] / "benchmark" / "cases" / "ours"
    reference = locate_reference()
    pi = case_set_for(str(REFERENCE / "benchmark" / "test_cases" / "6_PI"), reference, ours)
    assert (pi.name, pi.scenes_root) == ("6_PI", str(REFERENCE))
    assert [c.id for c in load_cases(pi.path)] == list(range(60, 70))  # one <tags> folder is a case set
    assert case_set_for(str(REFERENCE), reference, ours).name == "reference"
    assert case_set_for("reference", reference, ours).scenes_root == str(REFERENCE)
    assert case_set_for(str(ours), reference, ours) == case_set_for("ours", reference, ours)
    assert case_set_for("ours", reference, ours).scenes_root is None  # bundled scenes only
    with pytest.raises(SweepSpecError, match="not a folder"):
        case_set_for(str(tmp_path / "none"), reference, ours)


def test_runs_of_one_scene_and_tags_run_together_and_results_stay_in_grid_order(tmp_path: Path) -> None:
    """Cases 0 and 4 are House OA, 1 is Office OA: 4 runs right after 0 (its prompts open as 0's
    did, so the embedded model's cache is warm), yet ``results.jsonl`` lists them in grid order."""
    from storyteller.benchmark.sweep.execute import SweepWorkspace
    from storyteller.benchmark.sweep.runner import local_executor, shared_prompt_order

    s = spec(case_ids=(0, 1, 4), methods=("ours", "object-list"))
    ws = SweepWorkspace(s, tmp_path / "ws")
    grid_keys = [RunKey(case_set="reference", case=c, level=2, repeat=0, method=m, model="scripted")
                 for c in (0, 1, 4) for m in ("ours", "object-list")]
    assert [(k.case, k.method) for k in shared_prompt_order(ws, grid_keys)] == [
        (0, "ours"), (4, "ours"), (0, "object-list"), (4, "object-list"), (1, "ours"), (1, "object-list")]

    def waits(request: LLMRequest) -> str:  # every run waits: the order is what is checked here
        return "{}" if request.node == "describer" else json.dumps(
            {"reasoning": "nothing yet", "event": {"characters": [], "activity": ""}})

    ran: list[tuple[int, str]] = []
    inner = local_executor(1, scripted_port([], waits), fresh=True)

    async def recording(ws: Any, keys: list[RunKey], descriptions: Any, done: Any) -> None:
        ran.extend((k.case, k.method) for k in keys)
        await inner(ws, keys, descriptions, done)

    out = tmp_path / "sweep"
    asyncio.run(run_sweep(s, out, factory=scripted_port([], waits), executor=recording))
    assert ran[:2] == [(0, "ours"), (4, "ours")] and ran[-2:] == [(1, "ours"), (1, "object-list")]
    assert [(r.case, r.method) for r in read_results(out / "results.jsonl")] == [
        (c, m) for c in (0, 1, 4) for m in ("ours", "object-list")]

"""Names from outside reach the terminal escaped (issue 22): commands run on a run folder, a
scene path and scene objects whose names hold ESC[31m, BEL, U+202E (RLO) and U+2028 (line
separator) print none of them raw on stdout or stderr, and show each as its escape.

CliRunner runs with ``color=True``: otherwise click strips ``ESC[...m`` from what it echoes to
a stream that is not a terminal, and the test would pass on text a terminal receives raw.
``scene inspect --png`` runs as a process through the console entry point (``main()``), which
says Python warnings: matplotlib warns, quoting it, of every glyph of a name its font lacks.
Before ``storyteller.orchestrator.terminal.say`` these failed: bench report's folder line, the usage error
of an option named with the characters, and the glyph warnings.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner, Result

from storyteller.benchmark.sweep.grid import CaseSetSpec, ModelSpec, SweepSpec, model_specs
from storyteller.orchestrator.cli.app import _EscapedUsageErrors, app
from storyteller.sim.scene.bundled import load_bundled_scene
from tests.support.hostile_files import unsafe_characters

ROOT = Path(__file__).resolve().parents[3]
HOSTILE = "x\x1b[31my\x07z\u202ew\u2028v"
SHOWN = "x\\x1b[31my\\x07z\\u202ew\\u2028v"
SHOWN_IN_AN_ERROR = "x\\x1b[31my\\x07z\\u202ew v"  # an error line is one line: U+2028 joins as a space
SOURCE = HOSTILE.encode("unicode_escape").decode()  # the same, as a Python string literal's text


def _printed(stdout: str, stderr: str, *, shows: int = 1, shown: str = SHOWN) -> str:
    """stdout and stderr hold no unsafe character, and the name is shown escaped (``shown``)
    ``shows`` times at least: the test saw it printed."""
    both = stdout + stderr
    assert unsafe_characters(both) == [], both
    assert both.count(shown) >= shows, both
    return both


def _invoke(args: list[str]) -> Result:
    return CliRunner().invoke(app, args, color=True)


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    path = tmp_path / f"runs {HOSTILE}"
    path.mkdir()
    return path


@pytest.fixture
def scene_file(folder: Path) -> Path:
    """The home scene named with the characters, and its first object (the fridge) too."""
    data = json.loads(load_bundled_scene("home").model_dump_json())
    data["name"] = f"home{HOSTILE}"
    data["objects"][0].update(name=f"fridge{HOSTILE}_1", label=f"fridge{HOSTILE}")
    path = folder / "scene.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    return path


def test_scene_inspect_tables_and_json(scene_file: Path) -> None:
    tables = _invoke(["scene", "inspect", str(scene_file)])
    assert tables.exit_code == 0, tables.output
    _printed(tables.stdout, tables.stderr, shows=3)  # the scene's name, the fridge's name and label
    as_json = _invoke(["scene", "inspect", str(scene_file), "--json"])
    assert as_json.exit_code == 0 and json.loads(as_json.stdout)["scene"] == f"home{HOSTILE}"
    assert unsafe_characters(as_json.stdout + as_json.stderr) == []


@pytest.mark.slow
def test_scene_inspect_png_draws_the_names_escaped_and_says_everything_escaped(scene_file: Path, folder: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONWARNINGS", "STORYTELLER_CONFIG")}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    png = folder / f"top{HOSTILE}.png"
    proc = subprocess.run(
        [sys.executable, "-c", "from storyteller.orchestrator.cli.app import main; main()", "scene", "inspect", str(scene_file),
         "--png", str(png)],
        capture_output=True, text=True, errors="surrogateescape", cwd=folder.parent, env=env, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert png.is_file()
    _printed(proc.stdout, proc.stderr, shows=4)  # the tables and the 'wrote' line
    # the picture draws names through plain (82602dd), so no control character reaches the font:
    # matplotlib has no missing glyph to warn about (it warned "Glyph 27 (\x1b) missing" before)
    assert "Glyph 27" not in proc.stderr


def test_a_missing_scene_in_the_folder_is_one_escaped_line(folder: Path) -> None:
    result = _invoke(["scene", "inspect", str(folder / "none.json")])
    assert result.exit_code == 2
    assert _printed(result.stdout, result.stderr, shown=SHOWN_IN_AN_ERROR).startswith("error: ")


def test_event_program_table_and_error(scene_file: Path, folder: Path) -> None:
    program = folder / f"program{HOSTILE}.py"
    program.write_text(f'def parse_event():\n    c = get_character("Ava")\n    c.set_target_action("open")\n'
                       f'    c.set_position(get_area_close_to("fridge{SOURCE}_1"))\n', encoding="utf-8")
    table = _invoke(["event-program", str(scene_file), "--program", str(program)])
    assert table.exit_code == 0, table.output
    _printed(table.stdout, table.stderr, shows=1)  # the table's title: the scene's name
    program.write_text(f'def parse_event():\n    get_area_close_to("nothing{SOURCE}_1")\n', encoding="utf-8")
    error = _invoke(["event-program", str(scene_file), "--program", str(program)])
    assert error.exit_code == 1
    _printed(error.stdout, error.stderr, shows=2)  # the unknown name and the fridge it suggests


def test_bench_report_of_a_sweep_folder(folder: Path) -> None:
    ours = ROOT / "benchmark" / "cases" / "ours"
    spec = SweepSpec(case_sets=(CaseSetSpec(name="ours", path=str(ours)),), case_ids=(100,), levels=(2,),
                     methods=("ours",),
                     models=(ModelSpec(label="scripted", config=model_specs(["openai/scripted"], [])[0].config),))
    (folder / "sweep.json").write_text(spec.model_dump_json(indent=1) + "\n", encoding="utf-8")
    result = _invoke(["bench", "report", str(folder)])
    assert result.exit_code == 0, result.output
    assert _printed(result.stdout, result.stderr).startswith("report of 0 runs: ")


def test_model_info_of_a_config_in_the_folder(folder: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    config = folder / "storyteller.toml"
    config.write_text("", encoding="utf-8")
    monkeypatch.setenv("STORYTELLER_CONFIG", str(config))
    monkeypatch.delenv("STORYTELLER_MODEL", raising=False)
    result = _invoke(["model", "info"])
    assert result.exit_code == 0, result.output
    assert _printed(result.stdout, result.stderr).startswith("config: ")


def test_a_usage_error_quoting_what_was_typed() -> None:
    for args in (["scene", "inspect", "home", f"--{HOSTILE}"], [f"scene{HOSTILE}"], ["plan", "home", "-n", HOSTILE]):
        result = _invoke(args)
        assert result.exit_code == 2
        assert unsafe_characters(result.stdout + result.stderr) == [], result.stderr
    assert "--x\\x1b[31my" in _invoke(["scene", "inspect", "home", f"--{HOSTILE}"]).stderr


def test_a_usage_error_shows_a_typed_newline_and_tab_as_escapes() -> None:
    """What was typed is one line in the error: its newline and tab are shown, not obeyed. typer
    escapes C0 controls in the messages it writes; a parameter's own ``BadParameter`` quoting
    the value is escaped by the root group (:class:`_EscapedUsageErrors`, here on a small app)."""
    result = _invoke(["scene", "inspect", "home", "--one\ntwo\tthree"])
    assert result.exit_code == 2
    assert "--one\\x0atwo\\x09three" in result.stderr, result.stderr

    def refuse(value: str) -> str:
        raise typer.BadParameter(f"{value} is not a scene of this version")

    small = typer.Typer(cls=_EscapedUsageErrors)

    @small.command()
    def one(name: str = typer.Option("", callback=refuse)) -> None: ...

    @small.command()
    def two() -> None: ...

    result = CliRunner().invoke(small, ["one", "--name", f"one\ntwo\tthree{HOSTILE}"], color=True)
    assert result.exit_code == 2
    assert unsafe_characters(result.stderr) == [], result.stderr
    assert f"one\\x0atwo\\x09three{SHOWN}" in result.stderr, result.stderr


@pytest.mark.slow
def test_replay_view_export_and_resume_of_a_run_folder(finished_run: Path, folder: Path) -> None:
    """A run folder named with the characters, replayed into another, exported to HTML and
    resumed (from its last checkpoint; it prints where its files are)."""
    run = folder / f"run{HOSTILE}"
    shutil.copytree(finished_run, run)
    replayed = _invoke(["replay", str(run), "--out", str(folder / f"again{HOSTILE}")])
    assert replayed.exit_code == 0, replayed.output
    _printed(replayed.stdout, replayed.stderr)  # '... events completed -> <out>'
    exported = _invoke(["view", str(run), "--export", str(folder / f"page{HOSTILE}.html")])
    assert exported.exit_code == 0, exported.output
    assert "wrote " in _printed(exported.stdout, exported.stderr)  # (viser prints '(viser) Server stopped')
    resumed = _invoke(["resume", str(run), "--no-interactive"])
    assert resumed.exit_code == 0, resumed.output
    _printed(resumed.stdout, resumed.stderr)

"""Files read back from a run folder (``run.json``, ``story.json``, ``trace.jsonl``) and the
instruction script a run starts from: bounded, validated, one line and exit 2 when bad.

Each case is one a shared or hand-edited folder can hold: a file that is a link to
``/dev/zero``, a sparse file of gigabytes, JSON nested a hundred thousand deep, a 5,000-digit
integer, a number that overflows to infinity. Nothing may end in a traceback, a MemoryError or
a run.json that ``resume`` would then refuse; a replay that cannot apply a recorded step says so.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from orchestrator.cli.app import app
from orchestrator.session.instruction_script import InstructionScriptError, parse_instruction_script
from tests.support.finished_run import make_finished_run, one_error_line


@pytest.mark.parametrize(
    ("time", "needle"),
    [
        ("9" * 400, "is too long"),  # float() of it is infinity
        ("1" + "0" * 5000 + ":00:00", "is too long"),  # int() of it exceeds the interpreter's digit limit
        ("0:" + "9" * 40, "is too long"),
    ],
    ids=["400-nines", "5000-digit-hours", "long-seconds"],
)
def test_an_instruction_time_out_of_range_is_one_clear_error(time: str, needle: str) -> None:
    with pytest.raises(InstructionScriptError) as exc:
        parse_instruction_script(f"00:10 Ava sits\n{time} Ben waves\n", "script.txt")
    assert str(exc.value).startswith("script.txt: line 2: time ") and needle in str(exc.value)
    assert "\n" not in str(exc.value)


def test_a_run_with_an_infinite_instruction_time_is_refused_before_it_writes_anything(tmp_path: Path) -> None:
    script = tmp_path / "script.txt"
    script.write_text("00:01 Ava sits down\n" + "9" * 400 + " Ben waves\n", encoding="utf-8")
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["run", "home", "-d", "2", "--instructions", str(script), "--out", str(out),
                                      "--no-interactive", "--no-live"])
    one_error_line(result, str(script), "line 2")
    assert not (out / "run.json").exists()


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_finished_run(tmp_path_factory.mktemp("finished"))


@pytest.fixture
def run_dir(finished_run: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(finished_run, tmp_path / "run", symlinks=True))


def _dev_zero(path: Path) -> None:
    path.unlink()
    path.symlink_to("/dev/zero")


def _sparse_5_gb(path: Path) -> None:
    with path.open("r+b") as f:
        f.truncate(5 << 30)  # a hole: no disk used, but read_bytes() would ask for 5 GB


def _deep(path: Path) -> None:
    path.write_text('{"scene": ' + "[" * 100_000 + "]" * 100_000 + "}", encoding="utf-8")


def _digits(path: Path) -> None:
    text = path.read_text(encoding="utf-8")
    path.write_text(text.replace('"fps": 30', '"fps": ' + "9" * 5001, 1), encoding="utf-8")


def _infinite(path: Path) -> None:
    text = path.read_text(encoding="utf-8")
    path.write_text(text.replace('"fps": 30', '"fps": 1e400', 1), encoding="utf-8")


HOSTILE = {
    "dev-zero": (_dev_zero, "not a regular file"),
    "5-gb": (_sparse_5_gb, "more than the"),
    "deep": (_deep, "nested more than"),
    "5000-digits": (_digits, "5001 digits"),
    "infinite": (_infinite, "too large (numbers must be finite)"),
}


@pytest.mark.parametrize("case", list(HOSTILE))
def test_a_hostile_story_json_is_one_line_in_the_viewer(run_dir: Path, case: str) -> None:
    from orchestrator.viewer.run_folder import RunFolderError, load_run

    damage, needle = HOSTILE[case]
    damage(run_dir / "story.json")
    with pytest.raises(RunFolderError) as exc:
        load_run(run_dir)
    text = str(exc.value)
    assert text.startswith(str(run_dir / "story.json")) and needle in text and "\n" not in text, text


def test_a_story_json_with_a_field_of_the_wrong_type_is_refused(run_dir: Path) -> None:
    from orchestrator.viewer.run_folder import RunFolderError, load_run

    path = run_dir / "story.json"
    data = json.loads(path.read_text(encoding="utf-8"))
    assert load_run(run_dir).events  # the untouched folder reads
    data["characters"] = [{"name": "Zoe"}]
    path.write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(RunFolderError, match=r"story.json: field 'characters' \(0\): Input should be a valid string"):
        load_run(run_dir)

"""Files read back from a run folder (``run.json``, ``story.json``, ``trace.jsonl``) and the
instruction script a run starts from: bounded, validated, one line and exit 2 when bad.

Each case is one a shared or hand-edited folder can hold: a file that is a link to
``/dev/zero``, a sparse file of gigabytes, JSON nested a hundred thousand deep, a 5,000-digit
integer, a number that overflows to infinity. Nothing may end in a traceback, a MemoryError or
a run.json that ``resume`` would then refuse; a replay that cannot apply a recorded step says so.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from orchestrator.cli.app import app
from orchestrator.session.instruction_script import InstructionScriptError, parse_instruction_script
from tests.support.finished_run import one_error_line


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

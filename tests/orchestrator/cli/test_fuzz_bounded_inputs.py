"""Adversarial fuzzing of the files a user hands the product, one target per kind: scene JSON,
config TOML, instruction scripts and benchmark case files. A valid file gets hostile pieces
spliced in (anywhere, or in place of its values so they reach validation) (deep nesting, 5,000-digit and 400-nine numbers, NaN / Infinity, long names and
lines, bytes that are not UTF-8, control characters), and the command that reads it must
succeed or print one line and exit with code 2: never a traceback, never another exit code.

Bounded for CI: ``derandomize=True`` (the same examples every run), a few examples per target,
no deadline (tests never assert time; the inputs are kilobytes, and every limit they meet is
checked before the work it bounds).
"""

from __future__ import annotations

import json
import re
import tempfile
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner, Result

from storyteller.orchestrator.cli.app import app
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.files import save_scene_json

ROOT = Path(__file__).resolve().parents[3]
FUZZ = settings(max_examples=15, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

HOSTILE: list[bytes] = [
    b"[" * 3_000 + b"]" * 3_000,
    b"{" * 50 + b"}" * 50,
    b"9" * 5_000,
    b"9" * 400,
    b"1e999",
    b"-1e309",
    b"NaN",
    b"Infinity",
    b"nan",
    b"inf",
    b'"' + b"a" * 20_000 + b'"',
    b"\xff\xfe\x80",
    "\x00\x1b[31m\u202e\u2028".encode(),
    b"\n" * 3,
    b"a" * 3_000,
    b"\r",
    b"1:" + b"9" * 50 + b":00",
]


@st.composite
def spliced(draw: st.DrawFn, valid: bytes) -> bytes:
    """``valid`` with one to three hostile pieces put in place of a slice of it."""
    data = valid
    for _ in range(draw(st.integers(1, 3))):
        start = draw(st.integers(0, len(data)))
        end = draw(st.integers(start, min(len(data), start + 40)))
        data = data[:start] + draw(st.sampled_from(HOSTILE)) + data[end:]
    return data


_VALUE = re.compile(rb'-?[0-9][0-9.e+-]*|"[^"\n]*"')


@st.composite
def value_spliced(draw: st.DrawFn, valid: bytes) -> bytes:
    """``valid`` with one to three of its numbers or strings replaced by hostile pieces (the
    syntax around them kept, so the values reach validation)."""
    data = valid
    for _ in range(draw(st.integers(1, 3))):
        spans = [m.span() for m in _VALUE.finditer(data)]
        start, end = draw(st.sampled_from(spans))
        data = data[:start] + draw(st.sampled_from(HOSTILE)) + data[end:]
    return data


def hostile(valid: bytes) -> st.SearchStrategy[bytes]:
    return st.one_of(spliced(valid), value_spliced(valid))


def succeeded_or_one_line(result: Result) -> None:
    assert result.exit_code in (0, 2), (result.exit_code, result.output[-2000:])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.output, result.output[-2000:]
    if result.exit_code == 2:
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        assert len(lines) == 1, result.stderr[-2000:]


def _scene_bytes() -> bytes:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.json"
        save_scene_json(load_bundled_scene("home"), path)
        doc = json.loads(path.read_text(encoding="utf-8"))
    doc["objects"] = doc["objects"][:4]
    return json.dumps(doc).encode()


SCENE = _scene_bytes()
CONFIG = (b'[llm]\nmodel = "openai/gpt-4o-mini"\ntemperature = 0.0\ntimeout_s = 30.0\n'
          b"[llm.retry]\nmax_attempts = 2\nbackoff_base_s = 0.5\nbackoff_max_s = 4.0\nseed = 3\n")
SCRIPT = b"00:05 Ava sits down\n# a comment\n01:10 Ben makes coffee\n0:02:00.5 Ava waves at Ben\n"
CASE_FILE = sorted((ROOT / "benchmark" / "cases" / "ours").rglob("testcase_*.json"))[0]
CASE = CASE_FILE.read_bytes()


@FUZZ
@given(data=hostile(SCENE))
def test_fuzzed_scene_files_through_scene_inspect(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.json"
        path.write_bytes(data)
        succeeded_or_one_line(CliRunner().invoke(app, ["scene", "inspect", str(path), "--json"]))


@FUZZ
@given(data=hostile(CONFIG))
def test_fuzzed_configs_through_model_info(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "storyteller.toml"
        path.write_bytes(data)
        succeeded_or_one_line(CliRunner().invoke(app, ["model", "info", "--config", str(path)]))


@FUZZ
@given(data=hostile(SCRIPT))
def test_fuzzed_instruction_scripts_through_run(data: bytes) -> None:
    from storyteller.orchestrator.session.instruction_script import (
        InstructionScriptError,
        read_instruction_script,
    )

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "script.txt"
        path.write_bytes(data)
        try:
            read_instruction_script(path)
        except InstructionScriptError:
            pass
        else:
            return  # a script that reads would start a story (a model): only refused ones go on
        result = CliRunner().invoke(app, ["run", "home", "--instructions", str(path), "--out", str(Path(tmp) / "o")])
        succeeded_or_one_line(result)
        assert result.exit_code == 2


@FUZZ
@given(data=hostile(CASE), name=st.sampled_from(["testcase_7.json", "testcase_seven.json", "testcase_0000000007.json"]))
def test_fuzzed_case_files_through_bench_run(data: bytes, name: str) -> None:
    from storyteller.benchmark.reference_cases import BenchmarkCaseError, case_files, load_case

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "cases" / "0_OA"
        folder.mkdir(parents=True)
        (folder / name).write_bytes(data)
        try:
            [load_case(p) for p in case_files(folder.parent)]
        except BenchmarkCaseError:
            pass
        else:
            return  # cases that load would start a sweep (a model): only refused ones go on
        result = CliRunner().invoke(app, ["bench", "run", "--cases", str(folder.parent), "--out",
                                          str(Path(tmp) / "sweep"), "--method", "ours", "--model", "local/x"])
        succeeded_or_one_line(result)
        assert result.exit_code == 2

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

from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.session.instruction_script import InstructionScriptError, parse_instruction_script
from tests.support.finished_run import one_error_line, replay, resume


@pytest.mark.parametrize(
    "time",
    [
        "9" * 400,  # float() of it is infinity
        "1" + "0" * 5000 + ":00:00",  # int() of it exceeds the interpreter's digit limit
        "0:" + "9" * 40,
    ],
    ids=["400-nines", "5000-digit-hours", "long-seconds"],
)
def test_an_instruction_time_out_of_range_is_one_clear_error(time: str) -> None:
    with pytest.raises(InstructionScriptError) as exc:
        parse_instruction_script(f"00:10 Ava sits\n{time} Ben waves\n", "script.txt")
    assert str(exc.value).startswith("script.txt: line 2: time ") and "\n" not in str(exc.value)


def test_a_run_with_an_infinite_instruction_time_is_refused_before_it_writes_anything(tmp_path: Path) -> None:
    script = tmp_path / "script.txt"
    script.write_text("00:01 Ava sits down\n" + "9" * 400 + " Ben waves\n", encoding="utf-8")
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["run", "home", "-d", "2", "--instructions", str(script), "--out", str(out),
                                      "--no-interactive", "--no-live"])
    one_error_line(result, str(script), "line 2")
    assert not (out / "run.json").exists()



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
    from storyteller.orchestrator.viewer.run_folder import RunFolderError, load_run

    damage, needle = HOSTILE[case]
    damage(run_dir / "story.json")
    with pytest.raises(RunFolderError) as exc:
        load_run(run_dir)
    text = str(exc.value)
    assert text.startswith(str(run_dir / "story.json")) and needle in text and "\n" not in text, text


def test_a_story_json_with_a_field_of_the_wrong_type_is_refused(run_dir: Path) -> None:
    from storyteller.orchestrator.viewer.run_folder import RunFolderError, load_run

    path = run_dir / "story.json"
    data = json.loads(path.read_text(encoding="utf-8"))
    assert load_run(run_dir).events  # the untouched folder reads
    data["characters"] = [{"name": "Zoe"}]
    path.write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(RunFolderError, match=r"story.json: field 'characters.0': Input should be a valid string"):
        load_run(run_dir)


@pytest.mark.parametrize("case", list(HOSTILE))
def test_a_hostile_run_json_is_one_line_on_resume_and_replay(run_dir: Path, tmp_path: Path, case: str) -> None:
    damage, needle = HOSTILE[case]
    path = run_dir / "run.json"
    if case in ("5000-digits", "infinite"):  # run.json has no fps: the seed is the number
        text = path.read_text(encoding="utf-8")
        number = "9" * 5001 if case == "5000-digits" else "1e400"
        path.write_text(text.replace('"seed": 0', f'"seed": {number}', 1), encoding="utf-8")
    else:
        damage(path)
    one_error_line(resume(run_dir), str(path), needle)
    one_error_line(replay(run_dir, tmp_path / "again"), str(path), needle)


def test_run_json_with_an_infinite_instruction_time_is_refused_on_resume(run_dir: Path) -> None:
    path = run_dir / "run.json"
    data = json.loads(path.read_text(encoding="utf-8"))
    data["arguments"]["instructions"] = [{"time_s": 1.0, "text": "Zoe sits"}]
    path.write_text(json.dumps(data).replace('"time_s": 1.0', '"time_s": ' + "9" * 400 + ".0"), encoding="utf-8")
    one_error_line(resume(run_dir), str(path), "too large (numbers must be finite)")


def _trace_dev_zero(path: Path) -> None:
    _dev_zero(path)


def _trace_deep_line(path: Path) -> None:
    lines = path.read_bytes().splitlines(keepends=True)
    lines.insert(1, b'{"kind": "run", "run_id": "x", "seq": 999, "time_unix": 0, "meta": {"a": '
                 + b"[" * 100_000 + b"]" * 100_000 + b"}}\n")
    path.write_bytes(b"".join(lines))


def _trace_digits(path: Path) -> None:
    lines = path.read_bytes().splitlines(keepends=True)
    lines.insert(1, b'{"kind": "run", "run_id": "x", "seq": ' + b"9" * 5000 + b', "time_unix": 0, "meta": {}}\n')
    path.write_bytes(b"".join(lines))


def _trace_sparse(path: Path) -> None:
    with path.open("r+b") as f:
        f.truncate(1 << 30)  # 1 GiB of zeros, over the 256 MiB a trace may have


TRACES = {
    "dev-zero": (_trace_dev_zero, "not a regular file"),
    "1-gib": (_trace_sparse, "more than the"),
    "deep": (_trace_deep_line, "line 2"),
    "5000-digits": (_trace_digits, "line 2"),
}


@pytest.mark.parametrize("case", list(TRACES))
def test_a_hostile_trace_is_one_line_on_resume_and_replay(run_dir: Path, tmp_path: Path, case: str) -> None:
    damage, needle = TRACES[case]
    trace = run_dir / "trace.jsonl"
    damage(trace)
    one_error_line(replay(run_dir, tmp_path / "again"), str(trace), needle)
    # resume: the same line, or (a link) the refusal of a run folder with a planted link
    one_error_line(resume(run_dir), str(run_dir), *(() if case == "dev-zero" else (str(trace), needle)))


def test_a_crafted_snapshot_is_one_line_on_resume_and_its_code_never_runs(run_dir: Path, tmp_path: Path) -> None:
    import hashlib
    import os
    import pickle

    marker = tmp_path / "PWNED"

    class Evil:
        def __reduce__(self) -> tuple[object, tuple[str]]:
            return os.system, (f"touch {marker}",)

    payload = pickle.dumps(Evil())
    digest = hashlib.sha256(payload).hexdigest().encode()
    (run_dir / "session.snapshot").write_bytes(b"storyteller-snapshot 6 sha256=" + digest + b"\n" + payload)
    one_error_line(resume(run_dir), str(run_dir / "session.snapshot"), "posix.system, which a checkpoint may not hold")
    assert not marker.exists()


def _applied_lines(trace: Path) -> list[int]:
    lines = trace.read_bytes().splitlines()
    return [i for i, line in enumerate(lines) if json.loads(line)["kind"] == "applied"]


def test_a_replay_that_cannot_apply_a_recorded_step_says_so(run_dir: Path, tmp_path: Path) -> None:
    trace = run_dir / "trace.jsonl"
    lines = trace.read_bytes().splitlines(keepends=True)
    at = _applied_lines(trace)[-1]
    record = json.loads(lines[at])
    record["sim_frame"] = 1_000_000  # after the run's last frame
    lines[at] = (json.dumps(record) + "\n").encode()
    trace.write_bytes(b"".join(lines))
    one_error_line(replay(run_dir, tmp_path / "again"), str(trace), f"step {record['step']} was applied at frame 1000000",
                   "could not apply it")


def test_a_replay_that_applies_fewer_steps_than_recorded_says_so(run_dir: Path, tmp_path: Path) -> None:
    path = run_dir / "run.json"
    data = json.loads(path.read_text(encoding="utf-8"))
    steps = len(_applied_lines(run_dir / "trace.jsonl"))
    assert steps >= 2
    data["arguments"]["max_events"] = 1  # the recorded run applied more
    path.write_text(json.dumps(data), encoding="utf-8")
    one_error_line(replay(run_dir, tmp_path / "again"), "the replay did not apply", "it is not the recorded story")


def test_a_faithful_replay_still_succeeds(run_dir: Path, tmp_path: Path) -> None:
    result = replay(run_dir, tmp_path / "again")
    assert result.exit_code == 0, result.stderr


def test_a_run_with_an_infinite_duration_is_refused_before_it_writes_anything(tmp_path: Path) -> None:
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["run", "home", "-d", "inf", "--out", str(out), "--no-interactive", "--no-live"])
    one_error_line(result, "--duration must be a finite number")
    assert not out.exists()


def test_a_run_whose_arguments_run_json_could_not_hold_is_refused_before_run_json(tmp_path: Path) -> None:
    from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
    from tests.support.story_planner import RUN, Planner, write_config

    out = tmp_path / "run"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FAKE_PROVIDER_KEY", "sk-test-123")
        for var in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL"):
            mp.delenv(var, raising=False)
        with FakeOpenAI(responder=Planner()) as fake:
            cfg = write_config(tmp_path, fake.base)
            result = CliRunner().invoke(app, [*RUN, "-d", "2", "--seed", "9" * 70, "--config", str(cfg),
                                              "--out", str(out)])
    one_error_line(result, "the run's arguments: field 'seed'", "less than 18446744073709551616")
    assert not (out / "run.json").exists()


@pytest.mark.parametrize(
    ("change", "field"),
    [({"fps": 5e-324}, "fps"), ({"frames": 10**60}, "frames"),
     ({"characters": [f"C{i}" for i in range(30_000)]}, "characters"),
     ({"steps": [{"index": 0, "applied_frame": 10**60, "kind": "wait"}]}, "steps.0.applied_frame"),
     ({"events": [{"event_id": "event-0000", "index": 0, "characters": ["Zoe"], "activity": "sits",
                   "requested_frame": 1, "applied_frame": 80, "state": "completed", "finished_frame": 30,
                   "failure": None}]}, "events.0")],
)
def test_a_story_no_run_could_write_is_refused(tmp_path: Path, change: dict[str, object], field: str) -> None:
    """Found by the second hostile corpus: a story.json of fps 5e-324 and 10**60 frames, of
    steps at frame 10**60 and 30,000 characters, or of an event finished before it was applied, was exported (exit 0) as a page of a timeline no
    run has. Frames, frame rates and casts are now held to what a run can write, in story.json
    and in story.jsonl alike."""
    from storyteller.orchestrator.session.story_stream import StoryStreamError, read_story_stream
    from storyteller.orchestrator.viewer.run_folder import RunFolderError, read_story_file

    path = tmp_path / "story.json"
    path.write_text(json.dumps({"scene": "home", "characters": ["Zoe"], "fps": 30, "frames": 90, **change}),
                    encoding="utf-8")
    with pytest.raises(RunFolderError) as info:
        read_story_file(path)
    assert f"field '{field}'" in str(info.value) and "\n" not in str(info.value)
    stream = tmp_path / "story.jsonl"
    start = {"kind": "start", "scene": "home", "characters": ["Zoe"], "instruction": "", "fps": 5e-324, "frame": 0}
    stream.write_text(json.dumps(start) + "\n", encoding="utf-8")
    with pytest.raises(StoryStreamError, match="fps"):
        read_story_stream(stream)

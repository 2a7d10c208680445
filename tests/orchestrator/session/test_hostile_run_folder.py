"""What ``benchmark/hostile_inputs.py`` found in run folders, kept as plain tests (issue 22).

- A trace whose recorded reply was changed (a code fence and 150,000 spaces) made ``replay``
  ask what was never recorded: exit 1 and a 12-line diff on stderr. A replay that cannot apply
  a recorded step is a bad file: one ``error:`` line, exit 2 (the diff is an info log record).
- A refused ``resume`` (a crafted snapshot) had already appended a ``run`` record to the
  folder's trace: the trace is now opened after the folder's files are read and checked, so a
  refused resume leaves the folder as it was.
- ``run.json`` with a key given twice (``"seed": 0, "seed": 7``) replayed with the second
  seed, exit 0: every bounded JSON reader now refuses a key given twice.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from storyteller.sim.bounded_files import MAX_OBJECT_KEYS, BoundedFileError, load_bounded_json
from tests.support.finished_run import one_error_line, replay, resume


def _folder(run: Path) -> dict[str, str]:
    return {str(p.relative_to(run)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(run.rglob("*"))
            if p.is_file()}


@pytest.mark.slow
def test_a_replay_that_cannot_apply_a_recorded_reply_is_one_line_exit_2(run_dir: Path, tmp_path: Path) -> None:
    trace = run_dir / "trace.jsonl"
    records = [json.loads(line) for line in trace.read_text(encoding="utf-8").splitlines()]
    for record in records:
        if record["kind"] == "attempt":
            record["response_text"] = "```" + " " * 150_000 + "x"
    trace.write_text("".join(json.dumps(r) + "\n" for r in records), encoding="utf-8")
    line = one_error_line(replay(run_dir, tmp_path / "out"), "cannot replay", "the recorded step does not apply")
    assert "---" not in line and len(line) < 1000


@pytest.mark.slow
def test_a_refused_resume_leaves_the_folder_as_it_was(run_dir: Path) -> None:
    snapshot = run_dir / "session.snapshot"
    payload = b"\x80\x04\x95\x00cos\nsystem\n(S'true'\ntR."
    snapshot.write_bytes(b"storyteller-snapshot 6 sha256=" + hashlib.sha256(payload).hexdigest().encode() + b"\n"
                         + payload)
    before = _folder(run_dir)
    one_error_line(resume(run_dir), "session.snapshot")
    assert _folder(run_dir) == before


def test_a_key_given_twice_is_refused(run_dir: Path, tmp_path: Path) -> None:
    manifest = run_dir / "run.json"
    manifest.write_text(manifest.read_text(encoding="utf-8").replace('"seed": 0,', '"seed": 0, "seed": 7,', 1),
                        encoding="utf-8")
    one_error_line(replay(run_dir, tmp_path / "out"), "run.json", "key 'seed' given twice")
    with pytest.raises(BoundedFileError, match="given twice"):
        load_bounded_json(b'{"a": {"b": 1, "b": 1}}', 8, "x.json")
    many = "{" + ",".join(f'"k{i}": 0' for i in range(MAX_OBJECT_KEYS - 1)) + ', "k0": 1}'  # found in one pass
    with pytest.raises(BoundedFileError, match="'k0' given twice"):
        load_bounded_json(many, 8, "x.json")


def test_temporaries_of_a_killed_writer_are_removed_on_resume(run_dir: Path, tmp_path: Path) -> None:
    """``kill -9`` during ``write_file`` leaves ``.<name>.<12 hex>.tmp<suffix>``; a resumed run
    removes them (a link of such a name goes, its target stays) and nothing else."""
    victim = tmp_path / "victim.txt"
    victim.write_text("victim\n", encoding="utf-8")
    (run_dir / ".story.md.0123456789ab.tmp.md").write_text("half a story", encoding="utf-8")
    (run_dir / "motion" / ".Zoe.chunks.0123456789ab.tmp.chunks").write_bytes(b"\0" * 10)
    (run_dir / ".live.json.abcdefabcdef.tmp.json").symlink_to(victim)
    (run_dir / "notes.tmp").write_text("mine\n", encoding="utf-8")
    result = resume(run_dir)
    assert result.exit_code == 0, result.stderr
    left = sorted(p.name for p in run_dir.rglob("*") if ".tmp" in p.name)
    assert left == ["notes.tmp"] and victim.read_text(encoding="utf-8") == "victim\n"


def test_a_run_never_writes_more_motion_than_resume_reads_back(tmp_path: Path) -> None:
    """``-d 1e308`` wrote ``run.json`` and then stopped with OverflowError; a run of more than
    2.5 h (or 10 character-hours) writes chunk files larger than ``resume`` and ``view`` take."""
    from typer.testing import CliRunner

    from storyteller.orchestrator.cli.app import app
    from storyteller.orchestrator.session.run_manifest import (
        ManifestError,
        RunArguments,
        RunManifest,
        parse_manifest,
    )

    for argv in (["-d", "1e308"], ["-d", "9001"], ["-n", "24", "-d", "1501"],
                 ["-d", "60", "--pace", "offline", "--offline-latency", "1e300"]):
        out = tmp_path / "out"
        one_error_line(CliRunner().invoke(app, ["run", "home", *argv, "--out", str(out), "--no-interactive",
                                                "--no-live"]), "the run's arguments")
        assert not out.exists()
    ok = RunManifest(thread_id="t", scene_name="home", seed=0, config=None,
                     arguments=RunArguments(scene="home", names=("Zoe",), duration=9000.0))
    text = ok.model_dump_json().replace('"duration":9000.0', '"duration":9000.5')
    with pytest.raises(ManifestError, match="longer than the 9000 s"):
        parse_manifest(text.encode(), "run.json")


@pytest.mark.parametrize(
    ("change", "field"),
    [({"seed": -1}, "seed"), ({"speed": 5e-324, "pace": "realtime"}, "speed"), ({"speed": 1e6}, "speed"),
     ({"names": [f"C{i}" for i in range(25)]}, "names"), ({"max_retries": 10**18}, "max_retries"),
     ({"max_events": 0}, "max_events")],
)
def test_run_json_numbers_no_run_could_hold_are_refused(change: dict[str, object], field: str) -> None:
    """Found by the second hostile corpus: a run.json seed of -1 stopped a replay with
    ``ValueError: expected non-negative integer`` (exit 1), and a realtime speed of 5e-324 made a
    3 s replay run forever. The run's arguments now hold what ``run`` itself accepts."""
    from storyteller.orchestrator.session.run_manifest import (
        ManifestError,
        RunArguments,
        RunManifest,
        parse_manifest,
    )

    ok = RunManifest(thread_id="t", scene_name="home", seed=0, config=None,
                     arguments=RunArguments(scene="home", names=("Zoe",), duration=3.0))
    value = json.loads(ok.model_dump_json())
    value["arguments"].update(change)
    with pytest.raises(ManifestError) as info:
        parse_manifest(json.dumps(value).encode(), "run.json")
    assert f"'arguments.{field}'" in str(info.value) and "\n" not in str(info.value)
    value = json.loads(ok.model_dump_json())
    value["seed"] = -1
    with pytest.raises(ManifestError, match="'seed'"):
        parse_manifest(json.dumps(value).encode(), "run.json")


@pytest.mark.slow
def test_a_run_folder_named_with_escapes_is_printed_escaped(run_dir: Path) -> None:
    """Found by the second hostile corpus: ``resume`` printed its folder's name raw in the last
    line (a newline, an OSC title escape, BEL and RLO reached the terminal)."""
    named = run_dir.rename(run_dir.with_name("run\n\x1b]0;owned\x07\u202e"))
    result = resume(named)
    assert result.exit_code == 0, result.stderr
    assert "\x1b" not in result.output and "\x07" not in result.output and "\u202e" not in result.output
    assert "\\x1b]0;owned\\x07\\u202e" in result.stdout


@pytest.mark.slow
def test_a_resume_refused_for_its_chunk_files_leaves_the_folder_as_it_was(run_dir: Path) -> None:
    """Found by the second hostile corpus: a sparse 3 GB ``motion/Zoe.chunks`` was refused, but
    only after the resume had appended its ``run`` record to the trace. The chunk files are now
    checked, read only, with the other files before anything is written."""
    with open(run_dir / "motion" / "Zoe.chunks", "r+b") as f:
        f.truncate(3 << 30)
    trace = (run_dir / "trace.jsonl").read_bytes()
    max_chunks = (run_dir / "motion" / "Max.chunks").read_bytes()
    one_error_line(resume(run_dir), "Zoe.chunks", "a chunk file may hold")
    assert (run_dir / "trace.jsonl").read_bytes() == trace
    assert (run_dir / "motion" / "Max.chunks").read_bytes() == max_chunks

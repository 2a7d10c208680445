"""A story survives faults injected while ``storyteller run`` runs.

- The provider fails for a stretch of calls (HTTP 500, a reply that never comes before the
  timeout): the lockstep story waits for the planner and goes on; the trace records every
  failed attempt; the story ends with all its events.
- SIGTERM (to the process, as ``kill`` sends it) or SIGINT (to its process group, as Ctrl-C
  on a terminal does, so the event-program worker gets it too) to a running ``storyteller
  run`` (a real child process): it stops at a frame boundary with exit code 128 + the signal (143, 130) and one line on stderr, having
  written the story so far, its motion, the trace, ``run.json`` and its checkpoint at that
  frame; ``storyteller resume RUN_DIR`` goes on from that very frame to the end, asking only
  the cut call again, and the resulting trace replays the same story and motion.
- A full disk: the trace (an ``os.write`` failing with ENOSPC mid-line) or the story folder
  (a child whose ``RLIMIT_FSIZE`` is exhausted, as an unprivileged CI container allows; the
  limit makes ``write`` fail with EFBIG once ``SIGXFSZ`` is ignored): one ``error:`` line naming
  the file, exit code 1, no traceback, and every line written before still parses.

The LLM is the fake OpenAI server on 127.0.0.1 (``benchmark/support/fake_openai_server.py``),
answering the unified planner by request content (the first free character uses its
appliance), so a stopped and resumed run gets the same answers as an uninterrupted one.
"""

from __future__ import annotations

import errno
import json
import os
import re
import resource
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.llm.traces import AppliedRecord, read_trace
from tests.support.story_planner import RUN, Planner, write_config

ROOT = Path(__file__).resolve().parents[3]
FPS = 30


@pytest.fixture
def env(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, str]]:
    monkeypatch.setenv("FAKE_PROVIDER_KEY", "sk-test-123")
    for var in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL"):
        monkeypatch.delenv(var, raising=False)
    yield {**os.environ, "PYTHONPATH": str(ROOT)}


def cli(*args: str) -> list[str]:
    return [sys.executable, "-c", "from storyteller.orchestrator.cli.app import main; main()", *args]


def applied_steps(trace: Path) -> list[int | None]:
    return [r.step for r in read_trace(trace).records if isinstance(r, AppliedRecord)]


def track_frames(path: Path) -> int:
    with np.load(path) as npz:
        return int(npz["root_positions"].shape[0])


def assert_one_error_line(stderr: str, *needles: str) -> str:
    """The ``error:`` line of ``stderr`` (exactly one, containing every needle); no traceback."""
    assert "Traceback" not in stderr, stderr
    errors = [line for line in stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, stderr
    for needle in needles:
        assert needle in errors[0], errors[0]
    return errors[0]


# ----- the provider fails for a while ---------------------------------------------------------
@pytest.mark.slow
def test_errors_and_timeouts_for_a_stretch_of_calls_delay_the_story_but_it_completes(
    env: dict[str, str], tmp_path: Path
) -> None:
    # request 1 answers; 2 and 3 are server errors, 4 never answers before the 1 s timeout, 5 answers
    planner = Planner(faults={2: ("status", 500), 3: ("status", 503), 4: ("sleep", 4.0)})
    out = tmp_path / "out"
    with FakeOpenAI(responder=planner) as fake:
        cfg = write_config(tmp_path, fake.base, attempts=4, timeout_s=1.0)
        result = CliRunner().invoke(app, [*RUN, "-d", "4", "--max-events", "2", "--config", str(cfg),
                                          "--out", str(out)])
        assert result.exit_code == 0, result.stderr
        assert len(fake.requests) == 5
    trace = read_trace(out / "trace.jsonl")
    attempts = list(trace.attempts())
    assert [a.attempt for a in attempts] == [1, 1, 2, 3, 4]
    assert [a.error_class for a in attempts] == [None, "transient", "transient", "transient", None]
    assert "Timeout" in (attempts[3].error_type or ""), attempts[3]
    assert [a.final for a in attempts] == [True, False, False, False, True]
    # lockstep: the story waited for the planner; the second step took effect where it was asked
    applied = [r for r in trace.records if isinstance(r, AppliedRecord)]
    assert [r.step for r in applied] == [0, 1] and applied[1].sim_frame == applied[1].requested_frame
    assert applied[1].ref_seqs == (attempts[-1].seq,)
    story = json.loads((out / "story.json").read_text(encoding="utf-8"))
    assert story["frames"] == 4 * FPS and [s["kind"] for s in story["steps"]] == ["event", "event"]
    assert [e["characters"] for e in story["events"]] == [["Zoe"], ["Max"]]
    metrics = json.loads((out / "metrics.json").read_text(encoding="utf-8"))
    assert metrics["llm"]["retries"] == 3 and metrics["llm"]["roles"]["planner"]["failed_calls"] == 0


@pytest.mark.slow
def test_a_call_that_fails_outright_is_a_failed_step_and_the_story_goes_on(env: dict[str, str], tmp_path: Path) -> None:
    planner = Planner(faults={2: ("status", 500), 3: ("sleep", 4.0)})  # both attempts of step 1
    out = tmp_path / "out"
    with FakeOpenAI(responder=planner) as fake:
        cfg = write_config(tmp_path, fake.base, attempts=2, timeout_s=1.0)
        result = CliRunner().invoke(app, [*RUN, "-d", "5", "--max-events", "3", "--config", str(cfg),
                                          "--out", str(out)])
        assert result.exit_code == 0, result.stderr
    story = json.loads((out / "story.json").read_text(encoding="utf-8"))
    assert [s["kind"] for s in story["steps"]] == ["event", "failed", "event"]
    assert [e["characters"] for e in story["events"]] == [["Zoe"], ["Max"]]  # asked again, later
    failed = [a for a in read_trace(out / "trace.jsonl").attempts() if not a.ok]
    assert [a.error_class for a in failed] == ["transient", "transient"]
    assert "step 1" in (out / "story.md").read_text(encoding="utf-8")


# ----- SIGTERM / SIGINT, then resume ----------------------------------------------------------
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
@pytest.mark.slow
def test_a_signal_stops_the_run_cleanly_and_resume_goes_on_from_there(
    env: dict[str, str], tmp_path: Path, signum: signal.Signals
) -> None:
    run_dir = tmp_path / "run"
    seconds = 12  # the third request comes when Zoe finishes her coffee, at 9.2 s
    planner = Planner(block_at=3)  # Zoe and Max got their events; the third request hangs
    with FakeOpenAI(responder=planner) as fake:
        cfg = write_config(tmp_path, fake.base)
        log, errors = tmp_path / "run.log", tmp_path / "run.err"
        with log.open("wb") as sink, errors.open("wb") as err_sink:
            child = subprocess.Popen(cli(*RUN, "-d", str(seconds), "--max-events", "3", "--config", str(cfg),
                                         "--out", str(run_dir)), cwd=tmp_path, env=env, stdout=sink, stderr=err_sink,
                                     start_new_session=True)
        try:
            while not planner.arrived.wait(0.2):
                assert child.poll() is None, log.read_text(encoding="utf-8") + errors.read_text(encoding="utf-8")
            if signum == signal.SIGINT:  # as Ctrl-C on a terminal: to the whole process group (the
                os.killpg(child.pid, signum)  # event-program worker too)
            else:  # as `kill PID` or a container stop: to the process
                child.send_signal(signum)
            child.wait(60)
        finally:
            planner.release.set()
            if child.poll() is None:
                child.kill()
                child.wait()
        stderr = errors.read_text(encoding="utf-8")
        assert child.returncode == 128 + signum, stderr
        assert "Traceback" not in stderr, stderr
        stopped = [line for line in stderr.splitlines() if line.startswith("stopped by")]
        assert len(stopped) == 1 and signum.name in stopped[0], stderr
        assert f"storyteller resume {run_dir}" in stopped[0]
        found = re.search(r"at frame (\d+)", stopped[0])
        assert found is not None
        stop_frame = int(found.group(1))
        assert 0 < stop_frame < seconds * FPS

        # what it had is written: the story so far, its motion, the trace, run.json, the checkpoint
        story = json.loads((run_dir / "story.json").read_text(encoding="utf-8"))
        assert story["frames"] == stop_frame and len(story["events"]) == 2
        assert "Zoe" in (run_dir / "story.md").read_text(encoding="utf-8")
        assert track_frames(run_dir / "Zoe.track.npz") == stop_frame  # one pose per simulated frame
        assert applied_steps(run_dir / "trace.jsonl") == [0, 1]
        assert read_trace(run_dir / "trace.jsonl").torn_tail is None
        assert json.loads((run_dir / "run.json").read_text(encoding="utf-8"))["arguments"]["names"] == ["Zoe", "Max"]
        assert (run_dir / "session.snapshot").is_file() and not (run_dir / "session.snapshot.tmp").exists()
        asked = len(fake.requests)

        resumed = subprocess.run(cli("resume", str(run_dir)), cwd=tmp_path, env=env, capture_output=True, text=True,
                                 timeout=300, check=False)
        assert resumed.returncode == 0, resumed.stderr
        new_requests = len(fake.requests) - asked
    assert f"resuming at frame {stop_frame} " in resumed.stderr  # from the frame it stopped at
    assert new_requests == 1  # only the call cut by the signal is asked again
    assert applied_steps(run_dir / "trace.jsonl") == [0, 1, 2]  # each step applied (and traced) once
    story = json.loads((run_dir / "story.json").read_text(encoding="utf-8"))
    assert story["frames"] == seconds * FPS
    assert [e["event_id"] for e in story["events"]] == ["event-0000", "event-0001", "event-0002"]
    assert track_frames(run_dir / "Zoe.track.npz") == seconds * FPS
    # the trace of the stopped and resumed run (the cut call is in it, as cancelled) replays the same story
    again = CliRunner().invoke(app, ["replay", str(run_dir), "--out", str(tmp_path / "again")])
    assert again.exit_code == 0, again.stderr
    for name in ("story.json", "Zoe.track.npz", "Max.track.npz"):
        assert (tmp_path / "again" / name).read_bytes() == (run_dir / name).read_bytes(), name


# ----- a full disk --------------------------------------------------------------------------
def test_a_full_disk_under_the_trace_is_one_error_line_and_the_trace_stays_whole(
    env: dict[str, str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The trace's ``os.write`` writes half a line and then fails with ENOSPC, from its 4th record on."""
    real_write = os.write
    records = {"n": 0}

    def full_disk_write(fd: int, data: Any) -> int:
        if not os.readlink(f"/proc/self/fd/{fd}").endswith("trace.jsonl"):  # story.jsonl writes with os.write too
            return real_write(fd, data)
        records["n"] += 1
        if records["n"] < 4:
            return real_write(fd, data)
        if records["n"] == 4:
            return real_write(fd, bytes(data[: len(data) // 2]))  # the disk fills up mid-line
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr("storyteller.orchestrator.llm.trace_writer.os.write", full_disk_write)  # only the trace file's writes fail
    out = tmp_path / "out"
    with FakeOpenAI(responder=Planner()) as fake:
        cfg = write_config(tmp_path, fake.base)
        result = CliRunner().invoke(app, [*RUN, "-d", "4", "--max-events", "3", "--config", str(cfg),
                                          "--out", str(out)])
    assert result.exit_code == 1, result.stderr
    line = assert_one_error_line(result.stderr, f"cannot write {out / 'trace.jsonl'}", "No space left on device",
                                 f"storyteller resume {out}")
    assert line == result.stderr.strip().splitlines()[-1]
    contents = read_trace(out / "trace.jsonl")  # every line before the failed one parses
    assert contents.torn_tail is None and [r.kind for r in contents.records] == ["run", "attempt", "parsed"]
    assert json.loads((out / "run.json").read_text(encoding="utf-8"))["thread_id"]


def _limit_file_size(limit: int) -> Callable[[], None]:
    def preexec() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return preexec


@pytest.mark.slow
def test_a_full_story_folder_is_one_error_line_and_what_was_written_stays_readable(
    env: dict[str, str], tmp_path: Path
) -> None:
    """No file of the child may grow past 40 kB: run.json fits, the checkpoints and outputs do not."""
    from storyteller.orchestrator.cache_paths import motion_cache_dir
    from storyteller.sim.motion.database import load_databases

    load_databases(cache_dir=motion_cache_dir())  # a fresh machine builds its motion cache here, unlimited
    out = tmp_path / "out"
    with FakeOpenAI(responder=Planner()) as fake:
        cfg = write_config(tmp_path, fake.base)
        result = subprocess.run(cli(*RUN, "-d", "4", "--max-events", "2", "--config", str(cfg), "--out", str(out)),
                                cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300, check=False,
                                preexec_fn=_limit_file_size(40_000))
    assert result.returncode == 1, result.stderr
    # the first file to reach the limit is named (today runs.sqlite, as the planner checkpoints)
    assert_one_error_line(result.stderr, f"cannot write {out}{os.sep}", f"storyteller resume {out}")
    assert read_trace(out / "trace.jsonl").torn_tail is None  # and every line of it parses
    assert json.loads((out / "run.json").read_text(encoding="utf-8"))["arguments"]["duration"] == 4
    assert not (out / "session.snapshot.tmp").exists()
    for name in ("story.json", "metrics.json"):  # written whole, or not at all
        if (out / name).exists():
            json.loads((out / name).read_text(encoding="utf-8"))


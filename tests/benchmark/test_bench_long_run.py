"""benchmark/bench_long_run.py runs a short story end to end and reports memory.

Only that it completes, streams its motion and prints its report: the memory figures
themselves are the benchmark's to measure (no thresholds on a shared machine in a test).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from storyteller.benchmark.bench_long_run import main
from storyteller.sim.world.track_chunks import scan


@pytest.mark.slow
def test_a_short_long_run_completes_streams_its_motion_and_reports_peak_rss(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    # offline pace: events land at their calls' latency in simulated time, so a loaded machine
    # (fast pace outruns a slow provider) cannot leave the short story without events
    assert main(["--minutes", "0.5", "--every", "0.2", "--out", str(out), "--pace", "offline"]) == 0
    text = capsys.readouterr().out
    marks = re.findall(r"^\s*([\d.]+) m\s+(\d+)\s+[\d.]+\s+([\d.]+)\s+([\d.]+)", text, flags=re.MULTILINE)
    # at the first event after every 0.2 simulated minutes (events come every few seconds once the
    # provider answers), then at the end
    assert marks and marks[-1][0] == "0.5", text
    assert all(round(float(m[0]) / 0.2, 6).is_integer() for m in marks[:-1]), text
    assert "(end of story)" in text and re.search(r"peak RSS [\d.]+ MiB", text), text
    assert int(marks[-1][1]) >= 1  # events were planned and applied
    assert "900 frames" in text
    for name in ("Zoe", "Max", "Ivy", "Leo"):
        assert scan(out / "motion" / f"{name}.chunks").frames == 900  # the whole story streamed

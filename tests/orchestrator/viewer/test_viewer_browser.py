"""``storyteller view`` end to end in headless Chromium (Debian ``chromium``; CI installs it).

A small run is recorded once per module with ``storyteller run`` against the scripted
OpenAI-compatible server (two planning steps: Ava makes coffee, Ben uses the microwave).
The live test starts ``storyteller view`` in its own process, opens it in Chromium over the
DevTools protocol, checks the event list, plays two seconds and compares screenshots; the
export test writes ``--export story.html``, stops everything and opens the file from disk.
Screenshots are written for a person to look at (the paths are printed) to
``$STORYTELLER_TEST_OUTPUT/viewer/`` when that variable is set (CI keeps them), otherwise to
the test's temporary folder.
"""

from __future__ import annotations

import io
import json
import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np
import pytest
from typer.testing import CliRunner

from storyteller.benchmark.support.headless_chromium import Chromium, chromium_binary
from storyteller.orchestrator.cli.app import app
from tests.support.story_planner import interact_program, recorded_home_run

pytestmark = pytest.mark.skipif(chromium_binary() is None, reason="chromium not installed (apt-get install chromium)")

COFFEE = interact_program("Ava", "coffee_maker_1", "use_coffee_maker")
MICROWAVE = interact_program("Ben", "microwave_1", "use_microwave", var="b")
AVA_RGB = np.array([217, 84, 64])  # orchestrator.viewer.scene_view.CHARACTER_RGB[0]
MIN_STD = 10.0  # grey-level standard deviation of a picture that shows something
MIN_SHIFT_PX = 8.0  # how far Ava's pixels must move in two seconds of walking


@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An 8-second run of two characters in ``home`` with two planned events."""
    tmp = tmp_path_factory.mktemp("viewer")
    return recorded_home_run(tmp, [COFFEE, MICROWAVE], seconds=8, max_events=2)


@pytest.fixture
def shots(tmp_path: Path) -> Path:
    """Where the screenshots go."""
    folder = Path(os.environ.get("STORYTELLER_TEST_OUTPUT", tmp_path)) / "viewer"
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@pytest.fixture
def browser(tmp_path: Path) -> Iterator[Chromium]:
    (tmp_path / "profile").mkdir()
    with Chromium(tmp_path / "profile") as chromium:
        yield chromium


def _picture(png: bytes) -> np.ndarray:
    return iio.imread(io.BytesIO(png))[..., :3].astype(np.float64)


def _ava_centroid(rgb: np.ndarray) -> np.ndarray:
    """Centre (row, col) of the pixels close to Ava's colour (her figure, shaded, and her path)."""
    mask = np.abs(rgb - AVA_RGB).max(axis=-1) < 60
    assert mask.sum() > 50, "Ava is not in the picture"
    centre: np.ndarray = np.argwhere(mask).mean(axis=0)
    return centre


def _first_event(run: Path) -> dict[str, Any]:
    events: list[dict[str, Any]] = json.loads((run / "story.json").read_text(encoding="utf-8"))["events"]
    assert events, "the recorded run has no event"
    return events[0]


@pytest.mark.slow
def test_view_shows_the_story_plays_it_and_lists_its_events(recorded_run: Path, browser: Chromium, tmp_path: Path, shots: Path) -> None:
    log = tmp_path / "view.log"
    with log.open("w") as sink:
        proc = subprocess.Popen(
            [sys.executable, "-c", "from storyteller.orchestrator.cli.app import app; app()", "view", str(recorded_run), "--port", "0"],
            stdout=sink, stderr=subprocess.STDOUT,
        )  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not (m := re.search(r"viewing .* at (http://127\.0\.0\.1:\d+)", log.read_text())):
            assert proc.poll() is None and time.monotonic() < deadline, f"storyteller view printed no URL: {log.read_text()}"
            time.sleep(0.2)
        url = m.group(1)
        first = _first_event(recorded_run)
        browser.navigate(url)
        browser.wait_for(f"document.body.innerText.includes({json.dumps(first['text'])})")  # the plan sentence
        browser.wait_for("document.body.innerText.includes('Play')")
        time.sleep(2.0)  # let the scene arrive and render
        before = _picture(browser.screenshot(shots / "view-0s.png"))
        browser.evaluate("[...document.querySelectorAll('button')].find(b => b.innerText.trim() === 'Play').click()")
        time.sleep(2.0)
        after = _picture(browser.screenshot(shots / "view-2s.png"))
        print(f"screenshots: {shots / 'view-0s.png'} {shots / 'view-2s.png'}")
        assert after.mean(axis=-1).std() > MIN_STD, "the picture is blank"
        shift = np.linalg.norm(_ava_centroid(after) - _ava_centroid(before))
        assert shift > MIN_SHIFT_PX, f"Ava moved {shift:.1f} px in two seconds of playing"
        clock = browser.evaluate("document.body.innerText.match(/(\\d+\\.\\d) s \\/ /)[1]")
        assert float(clock) >= 1.0, f"the clock shows {clock} s after two seconds of playing"
        # clicking an event jumps to its start frame
        browser.evaluate("[...document.querySelectorAll('button')].find(b => b.innerText.trim() === 'Pause').click()")
        browser.evaluate(f"[...document.querySelectorAll('button')].find(b => b.innerText.includes({json.dumps(first['text'])})).click()")
        start = f"{first['applied_frame'] / 30:.1f} s / "
        browser.wait_for(f"document.body.innerText.includes({json.dumps(start)})", timeout_s=20)
    finally:
        proc.terminate()
        proc.wait(timeout=20)


@pytest.mark.slow
def test_export_plays_from_disk_with_no_server(recorded_run: Path, browser: Chromium, tmp_path: Path, shots: Path) -> None:
    out = tmp_path / "story.html"
    result = CliRunner().invoke(app, ["view", str(recorded_run), "--export", str(out)], catch_exceptions=False)
    assert result.exit_code == 0, result.stderr
    assert "viewing" not in result.stdout  # nothing left serving
    browser.navigate(out.as_uri())
    browser.wait_for("document.querySelector('canvas') !== null")
    time.sleep(6.0)  # past the client's fade-in; the recording plays in wall time
    first = _picture(browser.screenshot(shots / "export-a.png"))
    time.sleep(1.5)
    second = _picture(browser.screenshot(shots / "export-b.png"))
    print(f"screenshots: {shots / 'export-a.png'} {shots / 'export-b.png'}")
    assert first.mean(axis=-1).std() > MIN_STD, "the exported story shows a blank picture"
    assert np.abs(first - second).mean() > 0.05, "the exported story does not play"

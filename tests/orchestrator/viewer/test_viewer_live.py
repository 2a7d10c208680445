"""Watching a run in progress: ``story.jsonl``, the live run folder and the viewer following it.

The unit tests write a run folder the way a running ``storyteller run`` does (``scene.json``,
``story.jsonl`` through :class:`~storyteller.orchestrator.session.story_stream.StoryStream`, chunk records
through :class:`~storyteller.sim.world.track_chunks.ChunkStore`) and drive :class:`ViewerApp` by hand
(``reload_if_changed``), so every step is deterministic. The end-to-end test starts a real
``storyteller run`` against the scripted OpenAI-compatible server at ``--pace realtime`` (so it
runs for a while), starts ``storyteller view`` on its folder at once, and watches the page in
headless Chromium: the story's length grows while the panel says the run is live, the first
event is listed before the run ends, and the finished run is shown when it does.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.benchmark.support.headless_chromium import Chromium, chromium_binary
from storyteller.orchestrator.session.story_stream import (
    STREAM_FILE,
    StoryStream,
    StoryStreamError,
    StreamStart,
    read_story_stream,
)
from storyteller.orchestrator.viewer.figures import bone_poses
from storyteller.orchestrator.viewer.run_folder import RunFolderError, is_ready, load_run
from storyteller.orchestrator.viewer.server import ViewerApp
from storyteller.sim.body.skeleton import NUM_JOINTS, heading_to_root
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.files import save_scene_json
from storyteller.sim.world.track_chunks import MOTION_FOLDER, ChunkStore
from tests.support.story_event_stub import Event
from tests.support.story_planner import interact_program

NAMES = ("Ava", "Ben")
WINDOW = 30  # frames per chunk record in the unit tests




def _start(frame: int = 0) -> StreamStart:
    return StreamStart(scene="home", characters=NAMES, instruction="make *coffee*", fps=30, frame=frame)


def _append(store: ChunkStore, frames: int) -> None:
    """``frames`` more frames of every character: upright, gliding along +x (1 m/s), own lane."""
    t = store.frames + np.arange(frames)
    pelvis = np.stack([np.column_stack([1.0 + t / 30.0, np.full(frames, 1.0 + k), np.full(frames, 0.92)])
                       for k in range(len(NAMES))], axis=1)  # fmt: skip
    rot = np.broadcast_to(np.eye(3), (frames, len(NAMES), NUM_JOINTS, 3, 3)).copy()
    rot[:, :, 0] = heading_to_root(0.0)
    contacts = np.ones((frames, len(NAMES), 2), bool)
    labels = [["walk"] * frames for _ in NAMES]
    events = [[""] * frames for _ in NAMES]
    store.append(store.frames, pelvis, rot.astype(np.float32), contacts, labels, events)


def _live_folder(tmp_path: Path) -> tuple[Path, ChunkStore, StoryStream]:
    folder = tmp_path / "run"
    folder.mkdir()
    save_scene_json(load_bundled_scene("home"), folder / "scene.json")
    store = ChunkStore.open(folder / MOTION_FOLDER, NAMES)
    stream = StoryStream(folder)
    stream.start(_start())
    return folder, store, stream


# ----- story.jsonl -------------------------------------------------------------------------------
def test_the_stream_keeps_each_events_last_state_and_escapes_text_as_data(tmp_path: Path) -> None:
    stream = StoryStream(tmp_path)
    stream.start(_start())
    tricky = "Ava says \"hi\"\nthen\x1b[31m waves \u202e"
    stream.event(Event(0, "event-0000", ("Ava",), tricky, 3, 5))
    stream.event(Event(1, "event-0001", ("Ben",), "Ben sits", 40, 41))
    stream.event(Event(0, "event-0000", ("Ava",), tricky, 3, 5, state="completed", finished_frame=90))
    stream.close()
    raw = (tmp_path / STREAM_FILE).read_bytes()
    assert raw.count(b"\n") == 4 and raw.isascii() and b"\x1b" not in raw  # one line per record, escaped
    start, events = read_story_stream(tmp_path / STREAM_FILE)
    assert start == _start()
    assert [(e.event_id, e.state, e.finished_frame) for e in events] == [
        ("event-0000", "completed", 90), ("event-0001", "ongoing", None),
    ]  # fmt: skip
    assert events[0].activity == tricky  # the text comes back as it was


def test_a_resume_starts_the_story_again_and_a_torn_last_line_is_not_read(tmp_path: Path) -> None:
    stream = StoryStream(tmp_path)
    stream.start(_start())
    stream.event(Event(0, "event-0000", ("Ava",), "Ava cooks", 3, 5))
    stream.event(Event(1, "event-0001", ("Ben",), "Ben sits", 400, 401))  # after the checkpoint: lost
    stream.close()
    again = StoryStream(tmp_path)  # a resume from the checkpoint at frame 300
    again.start(_start(frame=300), [Event(0, "event-0000", ("Ava",), "Ava cooks", 3, 5, "completed", 200)])
    again.close()
    with (tmp_path / STREAM_FILE).open("a", encoding="ascii") as fh:
        fh.write('{"kind": "event", "event": {"event_id": "event-00')  # a write in progress
    start, events = read_story_stream(tmp_path / STREAM_FILE)
    assert start is not None and start.frame == 300
    assert [(e.event_id, e.state) for e in events] == [("event-0000", "completed")]


def test_a_malformed_stream_line_is_named_by_file_and_line(tmp_path: Path) -> None:
    (tmp_path / STREAM_FILE).write_text(_start().model_dump_json() + '\n{"kind": "event", "event": {}}\n')
    with pytest.raises(StoryStreamError, match=r"story\.jsonl: line 2: "):
        read_story_stream(tmp_path / STREAM_FILE)
    with pytest.raises(RunFolderError, match=r"story\.jsonl: line 2: "):
        load_run(tmp_path)


# ----- the live run folder -----------------------------------------------------------------------
def test_a_live_folder_is_ready_at_its_first_chunk_record_and_reads_as_it_grows(tmp_path: Path) -> None:
    folder, store, stream = _live_folder(tmp_path)
    assert not is_ready(folder)  # the stream, no frame yet
    _append(store, WINDOW)
    assert is_ready(folder)
    run = load_run(folder)
    assert run.live and [t.name for t in run.tracks] == list(NAMES) and run.num_frames == WINDOW
    assert run.scene is not None and run.scene.name == "home" and run.instruction == "make *coffee*"
    assert run.events == ()
    stream.event(Event(0, "event-0000", ("Ava",), "walk", 0, 2, text="Ava walks"))
    _append(store, WINDOW)
    grown = load_run(folder)
    assert grown.num_frames == 2 * WINDOW and [e.text for e in grown.events] == ["Ava walks"]
    np.testing.assert_array_equal(grown.tracks[0].root_positions[:WINDOW], run.tracks[0].root_positions)
    stream.close()
    store.close()



def test_the_viewer_follows_a_growing_run_then_shows_the_finished_one(tmp_path: Path, viewer: ViewerApp) -> None:
    assert not viewer.reload_if_changed() and viewer.run is None  # no folder yet: waiting
    folder, store, stream = _live_folder(tmp_path)
    assert not viewer.reload_if_changed() and "waiting" in viewer.status.content
    _append(store, WINDOW)
    assert viewer.reload_if_changed()
    view = viewer.view
    assert viewer.run is not None and viewer.run.live and viewer.slider.max == WINDOW - 1
    assert "live" in viewer.status.content and r"make \*coffee\*" in viewer.status.content  # markdown-escaped
    viewer.toggle()  # Play
    viewer.advance(10.0)
    assert viewer.playing and viewer.frame == WINDOW - 1  # a live run holds at its last frame while playing

    stream.event(Event(0, "event-0000", ("Ava",), "walk", 0, 2, text="Ava walks"))
    _append(store, WINDOW)
    assert viewer.reload_if_changed()
    assert viewer.view is view  # the scene grew; it was not rebuilt
    assert viewer.slider.max == 2 * WINDOW - 1 and viewer.frame == WINDOW - 1
    assert [b.label for b in viewer._event_buttons] == ["  0.1 s  Ava walks"]
    whole = bone_poses(viewer.run.tracks[0])
    np.testing.assert_allclose(view.poses["Ava"].positions, whole.positions, atol=1e-12)
    np.testing.assert_allclose(view.poses["Ava"].wxyz, whole.wxyz, atol=1e-12)
    viewer.advance(0.5)
    assert viewer.frame == WINDOW - 1 + 15  # and goes on as frames arrive

    assert viewer._event_buttons[0].color == "green"  # on at the frame shown
    stream.event(Event(0, "event-0000", ("Ava",), "walk", 0, 2, "completed", 40, text="Ava walks"))
    assert viewer.reload_if_changed()
    assert [b.label for b in viewer._event_buttons] == ["  0.1 s  Ava walks (done)"]
    assert viewer._event_buttons[0].color is None  # over by the frame shown (44)

    # the run ends: story.json (here with the chunk files as the motion, as after a kill)
    story = {"scene": "home", "characters": list(NAMES), "instruction": "x", "fps": 30, "frames": 2 * WINDOW,
             "events": [json.loads(e.model_dump_json()) for e in load_run(folder).events]}  # fmt: skip
    (folder / "story.json").write_text(json.dumps(story), encoding="utf-8")
    assert viewer.reload_if_changed()
    assert not viewer.run.live and "live" not in viewer.status.content and viewer.slider.max == 2 * WINDOW - 1
    viewer.advance(10.0)
    assert not viewer.playing and viewer.frame == 2 * WINDOW - 1  # a finished run stops at its end
    stream.close()
    store.close()


# ----- end to end: storyteller run, and storyteller view on it while it runs ---------------------
COFFEE = interact_program("Ava", "coffee_maker_1", "use_coffee_maker")
MICROWAVE = interact_program("Ben", "microwave_1", "use_microwave", var="b")
DURATION_S = 60  # simulated; at --speed 3 about 20 wall seconds, a chunk record every 3.3 s
TOTAL = re.compile(r"\d+\.\d s / (\d+\.\d) s")


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-c", "from storyteller.orchestrator.cli.app import app; app()", *args]


@pytest.mark.skipif(chromium_binary() is None, reason="chromium not installed (apt-get install chromium)")
@pytest.mark.slow
def test_view_follows_a_run_in_progress_in_the_browser(tmp_path: Path) -> None:
    out = tmp_path / "run"
    run_log, view_log = tmp_path / "run.log", tmp_path / "view.log"
    with FakeOpenAI(default='{"error": "no script"}') as fake:
        cfg = tmp_path / "fake.toml"
        cfg.write_text(
            f'[llm]\napi_base = "{fake.base}"\napi_key_env = "FAKE_PROVIDER_KEY"\ntimeout_s = 10.0\n'
            '[llm.retry]\nmax_attempts = 1\n[nodes.planner]\nmodel = "openai/fake-planner"\n',
            encoding="utf-8",
        )
        fake.script["fake-planner"] = [COFFEE, MICROWAVE]
        env = {k: v for k, v in os.environ.items()
               if k not in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL", "STORYTELLER_PLANNER_MODEL")}  # fmt: skip
        env.update(FAKE_PROVIDER_KEY="sk-test-123", STORYTELLER_CACHE_DIR=str(tmp_path / "cache"))
        run_args = ["run", "home", "-n", "2", "-d", str(DURATION_S), "--max-events", "2", "--planner", "unified",
                    "--description", "object-list", "--config", str(cfg), "--out", str(out),
                    "--pace", "realtime", "--speed", "3", "--no-interactive"]  # fmt: skip
        with run_log.open("w") as run_sink, view_log.open("w") as view_sink:
            run = subprocess.Popen(_cli(*run_args), env=env, stdout=run_sink, stderr=subprocess.STDOUT)
            view = subprocess.Popen(_cli("view", str(out), "--port", "0"), env=env, stdout=view_sink,
                                    stderr=subprocess.STDOUT)  # fmt: skip
        (tmp_path / "profile").mkdir()
        try:
            with Chromium(tmp_path / "profile") as browser:
                deadline = time.monotonic() + 120
                while not (m := re.search(r"viewing .* at (http://127\.0\.0\.1:\d+)", view_log.read_text())):
                    assert view.poll() is None and time.monotonic() < deadline, f"no URL: {view_log.read_text()}"
                    time.sleep(0.2)
                browser.navigate(m.group(1))
                live_totals: list[float] = []  # the story's length the page shows while the run is live
                first_event_live = False
                final_total = None
                expected_total = (DURATION_S * 30 - 1) / 30
                deadline = time.monotonic() + 300
                settle_deadline = float("inf")  # once the run ends, the page gets 30 s to show the finished story
                while final_total is None or (final_total != pytest.approx(expected_total, abs=0.05)
                                              and time.monotonic() < settle_deadline):  # fmt: skip
                    assert time.monotonic() < deadline, f"the run did not end: {run_log.read_text()[-2000:]}"
                    text = browser.evaluate("document.body ? document.body.innerText : ''") or ""
                    total = TOTAL.search(text)
                    if total and "the run is still going" in text:
                        live_totals.append(float(total.group(1)))
                        _, events = read_story_stream(out / STREAM_FILE)
                        first_event_live |= bool(events) and bool(events[0].text) and events[0].text in text and run.poll() is None
                    elif total and (out / "story.json").is_file() and "live" not in text:
                        # the page may still show the last live chunk for a moment after the run ended
                        final_total = float(total.group(1))
                        settle_deadline = min(settle_deadline, time.monotonic() + 30)
                    time.sleep(0.3)
                assert run.wait(timeout=120) == 0, run_log.read_text()
        finally:
            for proc in (view, run):
                if proc.poll() is None:
                    proc.terminate()
                    proc.wait(timeout=30)
    print(f"story lengths shown live: {sorted(set(live_totals))} s; finished: {final_total} s")
    assert len(set(live_totals)) >= 2 and live_totals == sorted(live_totals), f"live lengths seen: {live_totals}"
    assert first_event_live, "the first event was not listed while the run was live"
    assert final_total == pytest.approx(expected_total, abs=0.05)
    assert min(live_totals) < final_total  # live, the page showed a part of the story first

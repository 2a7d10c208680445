"""The viewer's pure parts: reading a run folder, the timeline, the posed stand-in figure, and
the command's user errors. The browser tests are in ``tests/orchestrator/viewer/test_viewer_browser.py``."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.viewer.figures import bone_poses, figure_points, standin_rig
from storyteller.orchestrator.viewer.run_folder import (
    RunFolderError,
    StoryEventRecord,
    folder_stamp,
    is_ready,
    load_run,
)
from storyteller.orchestrator.viewer.timeline import (
    MAX_EVENT_TEXT_CHARS,
    action_at,
    active_events,
    event_line,
    event_span,
    event_text,
)
from storyteller.sim.body.skeleton import NUM_JOINTS, forward_kinematics, heading_to_root
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.files import save_scene_json
from storyteller.sim.world.character_track import CharacterTrack


def _event(i: int, start: int, end: int | None, state: str = "completed") -> dict[str, object]:
    return {
        "event_id": f"event-{i:04d}", "index": i, "characters": ["Ava"], "activity": f"act {i}", "text": f"Ava: act {i}",
        "requested_frame": start, "applied_frame": start, "state": state, "finished_frame": end, "failure": None,
    }  # fmt: skip


def _walk(name: str, frames: int = 40) -> CharacterTrack:
    """A figure gliding along +x at 1 m/s, facing +x, upright; labels idle then walk."""
    rot = np.broadcast_to(np.eye(3), (frames, NUM_JOINTS, 3, 3)).copy()
    rot[:, 0] = heading_to_root(0.0)
    root = np.column_stack([1.0 + np.arange(frames) / 30.0, np.full(frames, 2.0), np.full(frames, 0.92)])
    labels = tuple("idle" if k < 10 else "walk" for k in range(frames))
    return CharacterTrack(name=name, root_positions=root, local_rotations=rot, action_labels=labels)


def _run_folder(tmp_path: Path, *, scene_file: bool = True, scene_name: str = "home") -> Path:
    folder = tmp_path / "run"
    folder.mkdir(parents=True)
    story = {"scene": scene_name, "characters": ["Ben", "Ava"], "instruction": "x", "fps": 30, "frames": 40,
             "steps": [], "events": [_event(0, 1, 20), _event(1, 15, None, "ongoing")]}  # fmt: skip
    (folder / "story.json").write_text(json.dumps(story), encoding="utf-8")
    for name in ("Ava", "Ben"):
        _walk(name).save(folder / f"{name}.track.npz")
    if scene_file:
        save_scene_json(load_bundled_scene("home"), folder / "scene.json")
    return folder


def test_load_run_reads_story_tracks_and_scene_in_story_order(tmp_path: Path) -> None:
    run = load_run(_run_folder(tmp_path))
    assert [t.name for t in run.tracks] == ["Ben", "Ava"]  # story.json's order, not the files'
    assert run.scene is not None and run.scene.name == "home" and run.scene_note is None
    assert run.num_frames == 40 and run.fps == 30.0
    assert [e.event_id for e in run.events] == ["event-0000", "event-0001"]


def test_an_old_run_folder_falls_back_to_the_bundled_scene_or_to_no_objects(tmp_path: Path) -> None:
    run = load_run(_run_folder(tmp_path / "a", scene_file=False))
    assert run.scene is not None and run.scene.name == "home"
    gone = load_run(_run_folder(tmp_path / "b", scene_file=False, scene_name="/nowhere/scene.json"))
    assert gone.scene is None and gone.scene_note is not None and "not a bundled scene" in gone.scene_note


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda f: (f / "story.json").unlink(), "story.json: not found"),
        (lambda f: (f / "story.json").write_text("{", encoding="utf-8"), "story.json: not readable as JSON"),
        (lambda f: (f / "story.json").write_text('{"events": [{"index": 0}]}', encoding="utf-8"), "story.json: field 'events.0.event_id': required field is missing"),
        (lambda f: (f / "Ava.track.npz").write_bytes(b"junk"), "Ava.track.npz"),
    ],
)
def test_a_broken_run_folder_is_one_sentence_naming_the_file(tmp_path: Path, damage: Callable[[Path], object], message: str) -> None:
    folder = _run_folder(tmp_path)
    damage(folder)
    with pytest.raises(RunFolderError, match=message.replace("(", r"\(")):
        load_run(folder)


def test_folder_stamp_changes_when_a_shown_file_changes_only(tmp_path: Path) -> None:
    folder = tmp_path / "run"
    assert folder_stamp(folder) == () and not is_ready(folder)
    folder = _run_folder(tmp_path)
    stamp = folder_stamp(folder)
    (folder / "topdown.png").write_bytes(b"png")  # not read by the viewer
    assert folder_stamp(folder) == stamp
    _walk("Ava", frames=41).save(folder / "Ava.track.npz")
    assert folder_stamp(folder) != stamp and is_ready(folder)


def test_events_are_on_from_their_applied_frame_to_their_finish_or_the_end() -> None:
    done = StoryEventRecord.model_validate(_event(0, 1, 20))
    ongoing = StoryEventRecord.model_validate(_event(1, 15, None, "ongoing"))
    assert event_span(done, 39) == (1, 20) and event_span(ongoing, 39) == (15, 39)
    assert [active_events([done, ongoing], f, 39) for f in (0, 1, 16, 21, 39)] == [[], [0], [0, 1], [1], [1]]
    assert event_line(done, 30.0) == "  0.0 s  Ava: act 0 (done)"


def test_an_event_text_is_shown_cut_to_its_limit() -> None:
    """A story file's 40 MB event text was captioned whole at every frame the export drew (2.5 GB)."""
    long = StoryEventRecord.model_validate({**_event(0, 1, 20), "text": "b" * 40_000_000 + "\x1b"})
    assert event_text(long) == "b" * (MAX_EVENT_TEXT_CHARS - 1) + "\u2026"
    assert event_line(long, 30.0) == f"  0.0 s  {'b' * (MAX_EVENT_TEXT_CHARS - 1)}\u2026 (done)"
    edge = StoryEventRecord.model_validate({**_event(0, 1, 20), "text": "\x1b" * MAX_EVENT_TEXT_CHARS})
    assert event_text(edge) == "\\x1b" * MAX_EVENT_TEXT_CHARS  # at the limit: whole, escaped


def test_action_at_holds_the_last_label_past_the_end() -> None:
    track = _walk("Ava")
    assert [action_at(track, f) for f in (0, 9, 10, 500)] == ["idle", "idle", "walk", "walk"]


def test_the_posed_figure_follows_the_track_joints() -> None:
    rig = standin_rig()
    track = _walk("Ava")
    poses = bone_poses(track)
    joints, _ = forward_kinematics(track.local_rotations, track.root_positions)
    assert np.allclose(np.linalg.norm(poses.wxyz, axis=-1), 1.0)
    assert np.allclose(poses.positions, joints)
    for frame in (0, 39):
        pts = figure_points(rig, poses, frame)
        bone = rig.skin_weights.argmax(axis=1)
        # every box stays within its bone's reach of its joint, and the figure stands upright
        reach = np.linalg.norm(rig.vertices - rig.bind_positions[bone], axis=1)
        assert np.allclose(np.linalg.norm(pts - joints[frame][bone], axis=1), reach)
        assert pts[:, 2].min() < 0.1 and pts[:, 2].max() > 1.5
        assert abs(pts[:, 0].mean() - track.root_positions[frame, 0]) < 0.15


def test_view_of_a_missing_folder_is_a_user_error(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["view", str(tmp_path / "nope"), "--export", str(tmp_path / "s.html")])
    assert result.exit_code == 2
    assert "nope: not a folder" in result.stderr and not (tmp_path / "s.html").exists()


def test_export_writes_one_self_contained_html_file(tmp_path: Path) -> None:
    folder = _run_folder(tmp_path)
    out = tmp_path / "story.html"
    before = sorted(p.name for p in folder.iterdir())
    result = CliRunner().invoke(app, ["view", str(folder), "--export", str(out)])
    assert result.exit_code == 0, result.stderr
    html = out.read_text(encoding="utf-8")
    assert "window.__VISER_EMBED_DATA__=" in html  # the recording, inlined
    assert not re.search(r"<script[^>]*\ssrc=|<link[^>]*stylesheet", html)  # no file fetched
    assert sorted(p.name for p in folder.iterdir()) == before  # the viewer never writes the run folder


def test_a_story_of_too_many_events_is_refused_and_a_caption_lists_a_runs_worth(tmp_path: Path) -> None:
    """Found by the hostile corpus: 120,000 steps took view --export past 20 s, and 9,000
    overlapping events of 2,000 characters to 1.3 GB in its captions."""
    from types import SimpleNamespace
    from typing import cast

    from storyteller.orchestrator.viewer.run_folder import MAX_STORY_ITEMS
    from storyteller.orchestrator.viewer.scene_view import MAX_CAPTION_EVENTS, SceneView

    folder = _run_folder(tmp_path)
    story = json.loads((folder / "story.json").read_text(encoding="utf-8"))
    story["events"] = [_event(i, 1, None, "ongoing") for i in range(MAX_STORY_ITEMS + 1)]
    (folder / "story.json").write_text(json.dumps(story), encoding="utf-8")
    with pytest.raises(RunFolderError, match=f"'events': {MAX_STORY_ITEMS + 1} items, at most"):
        load_run(folder)
    events = tuple(StoryEventRecord.model_validate(_event(i, 1, None, "ongoing")) for i in range(MAX_CAPTION_EVENTS + 6))
    view = SimpleNamespace(run=SimpleNamespace(events=events, fps=30.0), last_frame=39)
    lines = SceneView.caption_text(cast(SceneView, view), 5).split("\n")  # only .run and .last_frame are read
    assert len(lines) == 1 + MAX_CAPTION_EVENTS + 1 and lines[-1] == "(and 6 more)"

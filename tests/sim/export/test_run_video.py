"""Pictures of a run (storyteller.sim.export.video): final-state PNG and animated GIF."""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from storyteller.sim.body.skeleton import NUM_JOINTS, REST_OFFSETS, heading_to_root
from storyteller.sim.export.video import (
    RunRecording,
    RunVideoError,
    animation_frames,
    mp4_available,
    recording_from_world,
    run_frame_rgb,
    save_run_animation,
    save_run_png,
)
from storyteller.sim.motion.matching import MotionQuery, Pose
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.world.character_track import CharacterTrack
from storyteller.sim.world.events import AssignEvent, Assignment
from storyteller.sim.world.step import World, run


class StandInMotion:
    """Test placeholder: rest pose on the world's root."""

    def initial_state(self, label: str, root_xy: object, heading: float, seated: bool = False) -> int:
        return 0

    def step(self, state: int, query: MotionQuery, dt: float) -> tuple[int, Pose]:
        rot = np.tile(np.eye(3), (NUM_JOINTS, 1, 1))
        rot[0] = heading_to_root(float(query.heading or 0.0))
        root = np.asarray(query.root_xy, dtype=float)
        return state, Pose(np.array([*root, REST_OFFSETS[0, 1]]), rot, root, float(query.heading or 0.0), np.zeros(2, bool))


def _scene() -> Scene:
    table = SceneObject(name="table_1", label="table", idx=1, center=(2.0, 2.0, 0.375), size=(1.0, 0.8, 0.75))
    return Scene(name="room", bounds_min=(0.0, 0.0), bounds_max=(4.0, 4.0), objects=(table,))


@pytest.fixture(scope="module")
def world() -> World:
    w = World(_scene(), {"ann": ((0.45, 0.45), 0.0), "bob": ((3.55, 3.55), np.pi)}, StandInMotion())
    ev = AssignEvent(event_id="meet", assignments=(
        Assignment(character="ann", action="chat", target_xy=(0.45, 3.25), facing_xy=(1.0, 0.0), partners=("bob",)),
        Assignment(character="bob", action="chat", target_xy=(1.35, 3.25), facing_xy=(-1.0, 0.0), partners=("ann",)),
    ))
    run(w, 150, {0: [ev]})
    return w


def _coloured(img: np.ndarray, rgb: tuple[int, int, int], tol: int = 12) -> int:
    return int(np.sum(np.all(np.abs(img.astype(int) - np.array(rgb)) <= tol, axis=-1)))


TAB10_BLUE = (31, 119, 180)  # first character's colour in topdown_plot
TAB10_ORANGE = (255, 127, 14)


def test_final_png_shows_both_characters(world: World, tmp_path: Path) -> None:
    rec = recording_from_world(world)
    assert rec.num_frames == 150 and rec.events is not None and rec.events["ann"][-1] == "meet"
    path = save_run_png(tmp_path / "final.png", rec, size_px=400)
    img = iio.imread(path)
    assert img.ndim == 3 and img.shape[1] == 400
    assert _coloured(img, TAB10_BLUE) > 50 and _coloured(img, TAB10_ORANGE) > 50
    # the same frame twice gives the same picture; another frame a different one
    assert np.array_equal(run_frame_rgb(rec, -1, size_px=400), img[..., :3])
    assert not np.array_equal(run_frame_rgb(rec, 0, size_px=400), img[..., :3])


def test_gif_has_one_picture_per_stride_and_real_time_timing(world: World, tmp_path: Path) -> None:
    rec = recording_from_world(world)
    path = save_run_animation(tmp_path / "run.gif", rec, stride=50, size_px=240)
    frames = iio.imread(path, index=None)
    assert frames.shape[0] == 4  # frames 0, 50, 100 and the last (149)
    meta = iio.immeta(path, index=0)
    assert meta["duration"] == pytest.approx(1000 * 50 / 30, abs=20)  # ms per picture
    assert frames.shape[1:3] == animation_frames(rec, stride=200, size_px=240)[0].shape[:2]


def test_bad_requests_raise_typed_errors(world: World, tmp_path: Path) -> None:
    rec = recording_from_world(world)
    with pytest.raises(RunVideoError, match="outside"):
        run_frame_rgb(rec, 150)
    with pytest.raises(RunVideoError, match="stride"):
        animation_frames(rec, stride=0)
    with pytest.raises(RunVideoError, match=r"\.gif or \.mp4"):
        save_run_animation(tmp_path / "run.avi", rec)
    if not mp4_available():
        with pytest.raises(RunVideoError, match="imageio-ffmpeg"):
            save_run_animation(tmp_path / "run.mp4", rec)
    t = world.tracks()["ann"]
    short = CharacterTrack(name="x", root_positions=t.root_positions[:3], local_rotations=t.local_rotations[:3])
    with pytest.raises(RunVideoError, match="different frame counts"):
        RunRecording(rec.scene, {"ann": t, "x": short})
    with pytest.raises(RunVideoError, match="at least one"):
        RunRecording(rec.scene, {})

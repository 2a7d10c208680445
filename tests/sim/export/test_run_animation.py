"""The animation (static scene drawn once, moving layers per picture) shows the same pictures
as the renderer that drew every picture from scratch (frozen in
``storyteller.benchmark.support.picture_reference``), and writes MP4 when imageio-ffmpeg is installed."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from storyteller.benchmark.support.picture_reference import reference_frame_rgb
from storyteller.benchmark.support.random_tracks import wandering_story
from storyteller.sim.export.topdown import CharacterMarker, TopdownAnimation, render_topdown_rgb
from storyteller.sim.export.video import (
    RunRecording,
    animation_frames,
    animation_suffix,
    mp4_available,
    run_frame_rgb,
    save_run_animation,
)
from storyteller.sim.paths.nav_grid import build_nav_grid
from storyteller.sim.scene.bundled import load_bundled_scene

# Per channel, out of 255: anti-aliased edges may differ a little, nothing a person would see.
PIXEL_TOLERANCE = 24
# Share of pixels allowed beyond the tolerance.
AREA_TOLERANCE = 0.001


@pytest.fixture(scope="module")
def story() -> RunRecording:
    scene = load_bundled_scene("office")
    return wandering_story(scene, build_nav_grid(scene), characters=4, seconds=12.0, seed=3)


def _assert_looks_the_same(new: np.ndarray, old: np.ndarray) -> None:
    assert new.shape == old.shape and new.dtype == old.dtype == np.uint8
    far = np.abs(new.astype(np.int16) - old).max(axis=-1) > PIXEL_TOLERANCE
    assert far.mean() <= AREA_TOLERANCE, f"{int(far.sum())} pixels differ by more than {PIXEL_TOLERANCE}"


@pytest.mark.slow
def test_animation_frames_match_the_frozen_renderer(story: RunRecording) -> None:
    stride = 45
    frames = animation_frames(story, stride=stride, size_px=600)
    picks = [*range(0, story.num_frames, stride), story.num_frames - 1]
    assert len(frames) == len(picks)
    for picture, f in zip(frames, picks, strict=True):
        _assert_looks_the_same(picture, reference_frame_rgb(story, f, size_px=600))
        _assert_looks_the_same(picture, run_frame_rgb(story, f, size_px=600))
    # the pictures move: consecutive ones are not the same picture
    assert not np.array_equal(frames[0], frames[1])


def test_a_frame_does_not_keep_the_previous_frames_layers(story: RunRecording) -> None:
    """A frame after another cast (fewer characters, no captions) shows only its own layers."""
    scene = story.scene
    animation = TopdownAnimation(scene, size_px=500)
    many = [CharacterMarker(f"P{k}", (2.0 + k, 3.0), (1.0, 0.0), "walk") for k in range(4)]
    trails = {m.name: np.array([[m.position[0], 2.0], list(m.position)]) for m in many}
    animation.frame(characters=many, paths=trails, captions=["t = 0.00 s"])
    one = [CharacterMarker("P0", (5.0, 5.0), None, None)]
    got = animation.frame(characters=one, paths=[np.array([[4.0, 4.0], [5.0, 5.0]])])
    want = render_topdown_rgb(scene, characters=one, paths=[np.array([[4.0, 4.0], [5.0, 5.0]])], size_px=500)
    _assert_looks_the_same(got, want)
    # back to the first cast: the artists are made again and match a whole drawing
    got = animation.frame(characters=many, paths=trails, captions=["t = 1.00 s"])
    want = render_topdown_rgb(scene, characters=many, paths=trails, captions=["t = 1.00 s"], size_px=500)
    _assert_looks_the_same(got, want)


def _decode_mp4(path: Path, height: int, width: int) -> np.ndarray:
    """(N, H, W, 3) uint8 pictures of an MP4, decoded by the ffmpeg that imageio-ffmpeg ships."""
    import imageio_ffmpeg

    raw = subprocess.run(
        [imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-i", str(path), "-f", "rawvideo", "-pix_fmt", "rgb24", "-"],
        capture_output=True, check=True, timeout=120,
    ).stdout
    return np.frombuffer(raw, np.uint8).reshape(-1, height, width, 3)


def test_the_default_animation_is_mp4_when_the_encoder_is_installed(story: RunRecording, tmp_path: Path) -> None:
    assert animation_suffix() == (".mp4" if mp4_available() else ".gif")
    if not mp4_available():
        pytest.skip("imageio-ffmpeg is not installed (a dependency of the package)")
    path = save_run_animation(tmp_path / "story.mp4", story, stride=30, speed=4.0, size_px=400)
    first = animation_frames(story, stride=story.num_frames, size_px=400)[0]
    frames = _decode_mp4(path, *first.shape[:2])
    assert frames.shape[0] == len(range(0, story.num_frames, 30)) + 1
    # H.264 is lossy: the decoded picture is close to the drawn one on average
    assert np.abs(frames[0].astype(np.int16) - first).mean() < 6.0

"""Animation time of a story: the animation (static scene drawn once, moving layers per
picture) against the frozen renderer that drew every picture from scratch, in the same run.

The story is ``storyteller.benchmark.support.random_tracks.wandering_story``: ``--characters`` people walking
between random free cells of the bundled Office for ``--seconds`` seconds at 30 fps, pausing
with actions and events, drawn as ``storyteller run --video/--gif`` does (every 10th frame,
900 px wide). Printed, wall clock (a busy machine slows both sides alike): the pictures alone
(new vs old, ratio), and whole files: ``story.mp4`` and ``story.gif`` from the new animation,
``story.gif`` from the old renderer (its pictures plus the same GIF encoding). The largest
per-pixel difference between the two renderers over the compared pictures is printed too.
Target (issue 14): the 60 s, 4-character story animates in <= 5 s, or >= 10x faster than the
old renderer.

``--old-every K`` draws only every K-th picture with the old renderer and scales its time by
the number of pictures (for a quick look; the default, 1, draws them all).

Figures (2026-12-03, ``--old-every 5``, the 2-core machine otherwise quiet but for a ``bench
score`` replay in the second run): pictures 4.43 s new vs 53.0 s old (12.0x; 24.5 ms a picture);
``story.mp4`` 7.31 s with x264's default preset (9.3x the old ``story.gif``, 68.0 s: short of
the target), so the writer now uses the ``veryfast`` preset: ``story.mp4`` 5.36 s against the
old GIF's 76.4 s in that run, 14.3x (target met); the new ``story.gif`` 13.7-13.8 s (5.0-5.5x);
largest pixel difference new vs old: 0.

Usage: ``python -m storyteller.benchmark.bench_pictures [--seconds 60] [--characters 4] [--old-every 1]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from storyteller.benchmark.support.picture_reference import reference_frame_rgb
from storyteller.benchmark.support.random_tracks import wandering_story
from storyteller.sim.export.video import animation_frames, mp4_available, save_run_animation
from storyteller.sim.paths.nav_grid import build_nav_grid
from storyteller.sim.scene.bundled import load_bundled_scene

STRIDE = 10  # as orchestrator.session.run_outputs.write_outputs
SPEED = 4.0


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="Story length (simulated seconds).")
    ap.add_argument("--characters", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--old-every", type=int, default=1, help="Old renderer draws every K-th picture only.")
    args = ap.parse_args(argv)

    scene = load_bundled_scene("office")
    rec = wandering_story(scene, build_nav_grid(scene), args.characters, args.seconds, args.seed)

    t0 = time.perf_counter()
    new = animation_frames(rec, stride=STRIDE)
    new_frames_s = time.perf_counter() - t0
    picks = [*range(0, rec.num_frames, STRIDE)]
    if picks[-1] != rec.num_frames - 1:
        picks.append(rec.num_frames - 1)
    assert len(picks) == len(new)

    sample = picks[:: args.old_every]
    t0 = time.perf_counter()
    old = [reference_frame_rgb(rec, f) for f in sample]
    old_frames_s = (time.perf_counter() - t0) * len(picks) / len(sample)
    diff = max(int(np.abs(o.astype(np.int16) - new[picks.index(f)]).max()) for o, f in zip(old, sample, strict=True))

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        iio.imwrite(Path(tmp) / "enc.gif", np.stack(new), extension=".gif", duration=1000 * STRIDE / 30 / SPEED, loop=0)
        gif_encode_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        save_run_animation(Path(tmp) / "story.gif", rec, stride=STRIDE, speed=SPEED)
        new_gif_s = time.perf_counter() - t0
        new_mp4_s = float("nan")
        if mp4_available():
            t0 = time.perf_counter()
            save_run_animation(Path(tmp) / "story.mp4", rec, stride=STRIDE, speed=SPEED)
            new_mp4_s = time.perf_counter() - t0
            mp4_kb = (Path(tmp) / "story.mp4").stat().st_size / 1024
        gif_kb = (Path(tmp) / "story.gif").stat().st_size / 1024
    old_gif_s = old_frames_s + gif_encode_s

    print(
        f"story: {args.seconds:.0f} s, {args.characters} characters, {rec.num_frames} frames, "
        f"{len(picks)} pictures of {new[0].shape[1]}x{new[0].shape[0]} px"
        + (f" (old renderer timed on {len(sample)}, scaled)" if args.old_every > 1 else "")
    )
    print(f"{'':34s} {'seconds':>8s} {'per picture ms':>15s}")
    rows = [
        ("pictures, old (whole figure each)", old_frames_s),
        ("pictures, new (static drawn once)", new_frames_s),
        ("story.gif, old", old_gif_s),
        ("story.gif, new", new_gif_s),
        ("story.mp4, new", new_mp4_s),
    ]
    for label, seconds in rows:
        print(f"{label:34s} {seconds:8.2f} {1000 * seconds / len(picks):15.1f}")
    print(f"\npictures: new is {old_frames_s / new_frames_s:.1f}x faster than old")
    print(f"story.gif: new is {old_gif_s / new_gif_s:.1f}x faster than old ({gif_kb:.0f} KB)")
    if mp4_available():
        best = new_mp4_s
        print(f"story.mp4 (the default with imageio-ffmpeg): {old_gif_s / new_mp4_s:.1f}x faster than the old story.gif ({mp4_kb:.0f} KB)")
    else:
        best = new_gif_s
        print("story.mp4: imageio-ffmpeg is not installed")
    verdict = "met" if best <= 5.0 or old_gif_s / best >= 10.0 else "NOT met"
    print(f"target (<= 5 s or >= 10x): {verdict}; largest pixel difference new vs old: {diff} (of 255)")


if __name__ == "__main__":
    main()

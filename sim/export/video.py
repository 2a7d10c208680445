"""Pictures of a run: a top-down PNG of one frame and an animated MP4 (or GIF) of the whole run.

A ``RunRecording`` is what a picture needs from a run: the scene, one ``CharacterTrack`` per
character (pelvis positions and root rotations at ``fps``), and optionally the event id each
character belonged to at every frame (``World.event_ids()``). ``recording_from_world`` builds
one from a ``storyteller.sim.world.step.World``.

Every picture shows the layers of ``storyteller.sim.export.topdown``: furniture, characters as discs with
heading arrows and their current action / event under their names, the cells a body cannot
stand on (shaded, when the recording has the grid), the last ``trail_s`` seconds of each
character's path as a trail, and the events under way as captions. A single frame is drawn
whole (``render_topdown_rgb``); an animation draws the static scene once and only the moving
layers per picture (``TopdownAnimation``), the same picture as a whole frame up to
anti-aliasing, so a 60 s story animates in seconds rather than minutes.

Animations are MP4 (H.264, through ``imageio-ffmpeg``, a dependency that ships its own ffmpeg)
or GIF (Pillow's GIF encoder, written one picture at a time), chosen by the path's extension;
both stream: the pictures are drawn and written one at a time, never all held in memory; ``animation_suffix()`` is
``.mp4`` when the encoder is installed and ``.gif`` otherwise. ``save_run_animation`` raises
``RunVideoError`` for a ``.mp4`` path when no encoder is installed. Every file is written under a
fresh temporary name and renamed over its own (``storyteller.sim.no_follow_writes``): a symbolic link at the
path is replaced, never written through.
"""
from __future__ import annotations

import importlib.util
import io
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict, Unpack

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.export.topdown import CharacterMarker, TopdownAnimation, render_topdown_rgb
from storyteller.sim.no_follow_writes import replacing, write_file
from storyteller.sim.paths.nav_grid import NavGrid
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.character_track import CharacterTrack
from storyteller.sim.world.motion_layer import root_yaw
from storyteller.sim.world.step import World


class RunVideoError(ValueError):
    """A picture that cannot be made (empty run, bad frame index, no encoder for the format)."""


@dataclass(frozen=True)
class RunRecording:
    """scene; tracks: name -> CharacterTrack (same frame count and fps); events: name -> event
    id per frame ("" outside events), optional; grid: the navigation grid, whose blocked cells
    (walls and doors of reference scenes included) are shaded, optional."""

    scene: Scene
    tracks: Mapping[str, CharacterTrack]
    events: Mapping[str, Sequence[str]] | None = None
    grid: NavGrid | None = None

    def __post_init__(self) -> None:
        if not self.tracks:
            raise RunVideoError("a run picture needs at least one character track")
        counts = {t.num_frames for t in self.tracks.values()}
        if len(counts) != 1:
            raise RunVideoError(f"tracks have different frame counts: {sorted(counts)}")
        if self.events is not None:
            for name, ids in self.events.items():
                if name not in self.tracks or len(ids) != self.num_frames:
                    raise RunVideoError(f"events of {name!r} must name a track and give one id per frame")

    @property
    def num_frames(self) -> int:
        return next(iter(self.tracks.values())).num_frames

    @property
    def fps(self) -> float:
        return next(iter(self.tracks.values())).fps


def recording_from_world(world: World) -> RunRecording:
    """The recording of a world's run so far."""
    return RunRecording(world.scene, world.tracks(), world.event_ids(), world.grid)


def _frame_index(rec: RunRecording, frame: int) -> int:
    n = rec.num_frames
    f = frame + n if frame < 0 else frame
    if not 0 <= f < n:
        raise RunVideoError(f"frame {frame} is outside the run's {n} frames")
    return f


def _moving_layers(rec: RunRecording, f: int, trail_s: float) -> dict[str, Any]:
    """The layers of frame ``f`` that move: characters, their trails, the caption."""
    lo = max(0, f - round(trail_s * rec.fps))
    markers, trails, under_way = [], {}, []
    for name, t in rec.tracks.items():
        xy = t.root_positions[f, :2]
        yaw = float(root_yaw(t.local_rotations[f, 0]))
        action = t.action_labels[f] if t.action_labels is not None else None
        event = rec.events[name][f] if rec.events is not None else ""
        label = " / ".join(s for s in (action, event) if s) or None
        markers.append(CharacterMarker(name, (float(xy[0]), float(xy[1])), (np.cos(yaw), np.sin(yaw)), label))
        trails[name] = t.root_positions[lo : f + 1, :2]
        if event and event not in under_way:
            under_way.append(event)
    caption = [f"t = {f / rec.fps:6.2f} s   frame {f}"]
    if under_way:
        caption.append("events: " + ", ".join(under_way))
    return {"characters": markers, "paths": trails, "captions": caption}


def _grid_layers(rec: RunRecording, show_grid: bool) -> dict[str, Any]:
    if show_grid and rec.grid is not None:
        return {"nav_free": rec.grid.free, "nav_origin": rec.grid.origin, "nav_cell_size": rec.grid.cell_size}
    return {}


class FrameStyle(TypedDict, total=False):
    """The keyword arguments of :func:`run_frame_rgb` after the frame."""

    trail_s: float
    size_px: int
    title: str | None
    show_names: bool
    show_grid: bool


def run_frame_rgb(
    rec: RunRecording, frame: int = -1, *, trail_s: float = 3.0, size_px: int = 900, title: str | None = None,
    show_names: bool = True, show_grid: bool = True,
) -> NDArray[np.uint8]:
    """One frame of the run as an (H, W, 3) uint8 picture (``frame`` may be negative)."""
    f = _frame_index(rec, frame)
    return render_topdown_rgb(
        rec.scene, **_moving_layers(rec, f, trail_s), title=title, show_names=show_names, size_px=size_px,
        **_grid_layers(rec, show_grid),
    )


def save_run_png(path: Path | str, rec: RunRecording, frame: int = -1, **kw: Unpack[FrameStyle]) -> Path:
    """Write one frame (default: the last, the run's final state) as a PNG; returns the path.

    Pillow's PNG encoder with its defaults, called directly: the bytes ``imageio.v3.imwrite``
    gave, without it loading every Pillow format plugin first."""
    from PIL import Image

    path = Path(path)
    buffer = io.BytesIO()
    Image.fromarray(run_frame_rgb(rec, frame, **kw), mode="RGB").save(buffer, format="PNG")
    return write_file(path, buffer.getbuffer())


def mp4_available() -> bool:
    """Whether imageio can encode MP4 here (needs the ``imageio_ffmpeg`` package)."""
    return importlib.util.find_spec("imageio_ffmpeg") is not None


def animation_suffix() -> str:
    """``.mp4`` when an MP4 encoder is installed here, ``.gif`` otherwise."""
    return ".mp4" if mp4_available() else ".gif"


def _picks(rec: RunRecording, stride: int, start: int, stop: int | None) -> list[int]:
    if stride < 1:
        raise RunVideoError(f"stride must be >= 1 frame, got {stride}")
    end = rec.num_frames if stop is None else min(stop, rec.num_frames)
    picks = list(range(max(0, start), end, stride))
    if not picks:
        raise RunVideoError(f"no frame in [{start}, {end})")
    if picks[-1] != end - 1:
        picks.append(end - 1)
    return picks


def iter_animation_frames(
    rec: RunRecording, *, stride: int = 6, start: int = 0, stop: int | None = None, trail_s: float = 3.0,
    size_px: int = 900, title: str | None = None, show_names: bool = True, show_grid: bool = True,
) -> Iterator[NDArray[np.uint8]]:
    """Pictures of every ``stride``-th frame in [start, stop) (the last frame always included),
    one at a time; the static scene is drawn once. Bad arguments raise before the first picture."""
    picks = _picks(rec, stride, start, stop)
    animation = TopdownAnimation(
        rec.scene, title=title, show_names=show_names, size_px=size_px, **_grid_layers(rec, show_grid)
    )
    return (animation.frame(**_moving_layers(rec, f, trail_s)) for f in picks)


def animation_frames(
    rec: RunRecording, *, stride: int = 6, start: int = 0, stop: int | None = None, **kw: Unpack[FrameStyle]
) -> list[NDArray[np.uint8]]:
    """The pictures of ``iter_animation_frames`` as a list."""
    return list(iter_animation_frames(rec, stride=stride, start=start, stop=stop, **kw))


def save_run_animation(
    path: Path | str, rec: RunRecording, *, stride: int = 6, speed: float = 1.0, start: int = 0,
    stop: int | None = None, **kw: Unpack[FrameStyle],
) -> Path:
    """Write an animated MP4 (for a ``.mp4`` path, when an encoder is installed) or GIF.

    ``stride``: frames of the run per picture; ``speed``: playback speed (1.0 = real time).
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in (".gif", ".mp4"):
        raise RunVideoError(f"{path}: animations are written as .gif or .mp4, not {ext or 'no extension'!r}")
    if ext == ".mp4" and not mp4_available():
        raise RunVideoError(f"{path}: no MP4 encoder here (imageio-ffmpeg is not installed); write a .gif")
    if not speed > 0:
        raise RunVideoError(f"speed must be > 0, got {speed}")
    frames = iter_animation_frames(rec, stride=stride, start=start, stop=stop, **kw)
    seconds_per_picture = stride / rec.fps / speed
    with replacing(path) as fresh:  # a link planted at ``path`` is replaced, never written through
        if ext == ".gif":
            _write_gif(fresh, frames, duration_ms=1000.0 * seconds_per_picture)
        else:
            _write_mp4(fresh, frames, fps=1.0 / seconds_per_picture)
    return path


def _write_gif(path: Path, frames: Iterator[NDArray[np.uint8]], duration_ms: float) -> None:
    """An animated GIF (looping), one picture at a time: each picture is quantized to its own
    adaptive palette (as Pillow's GIF writer does) and written whole with it as a local colour
    table, so only the picture being encoded is in memory, however long the run."""
    from PIL import GifImagePlugin, Image

    with path.open("wb") as fh:
        first = True
        for picture in frames:
            im = Image.fromarray(np.ascontiguousarray(picture), mode="RGB").convert("P", palette=Image.Palette.ADAPTIVE)
            if first:
                header, _ = GifImagePlugin.getheader(im, info={"loop": 0, "duration": duration_ms})
                fh.write(b"".join(header))
                first = False
            for part in GifImagePlugin.getdata(im, duration=duration_ms, include_color_table=True):
                fh.write(part)
        fh.write(b";")  # trailer


def _write_mp4(path: Path, frames: Iterator[NDArray[np.uint8]], fps: float) -> None:
    """H.264 in yuv420p (plays everywhere), one picture at a time; sides are even already.
    x264's ``veryfast`` preset: on a 60 s story's 181 pictures it encodes in about 1 s instead of
    3.7 s (the default ``medium``), for a file about 8% larger and the same picture error."""
    import imageio.v2 as iio2

    with iio2.get_writer(
        path, format="FFMPEG", mode="I", fps=fps, codec="libx264", pixelformat="yuv420p", quality=8,
        macro_block_size=2, ffmpeg_log_level="error", ffmpeg_params=["-preset", "veryfast"],
    ) as writer:
        for picture in frames:
            writer.append_data(picture)  # type: ignore[attr-defined]  # the FFMPEG writer has it; the stub's base class does not

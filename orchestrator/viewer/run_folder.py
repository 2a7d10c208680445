"""Read a run folder written by ``storyteller run`` into what the viewer shows.

A finished run folder holds ``story.json`` (events with their frames), one
``<slug>.track.npz`` per character and ``scene.json`` (the scene as it was run). Older folders
have no ``scene.json``: the scene is then the bundled scene that ``story.json`` names, and a
run on a scene file that is gone is shown without its objects (:attr:`RunData.scene_note`
says so). A character without a ``.track.npz`` (a run stopped before its exports, e.g. by a
kill) is read from the motion the run streamed, ``motion/<slug>.chunks`` (whole records only).
Every file is read within limits and validated; a character's name is shown with control, bidi
and surrogate characters as escapes. A file that does not fit is one :class:`RunFolderError`.

A run still in progress has no ``story.json`` yet (a run removes an earlier one when it
starts): it is read *live* (:attr:`RunData.live`) from what the run writes as it goes,
``story.jsonl`` (the characters, fps and the events so far, ``storyteller.orchestrator.session.story_stream``),
``scene.json`` and the chunk files, which grow by one record per 10 simulated seconds.
:func:`is_ready` says when there is something to show: ``story.json``, or ``story.jsonl``
and a first chunk record.

:func:`folder_stamp` is a cheap fingerprint (names, sizes and modification times of the files
the viewer reads): a viewer polls it to reload a run that is still being written.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from storyteller.agents.messages import PlannedCharacter
from storyteller.orchestrator.safe_text import plain
from storyteller.orchestrator.session.story_stream import (
    STREAM_FILE,
    Characters,
    Fps,
    Frame,
    StoryEventRecord,
    StoryStreamError,
    read_story_stream,
)
from storyteller.sim.bounded_files import BoundedFileError, load_bounded_json, read_bounded_bytes
from storyteller.sim.scene.model import Scene
from storyteller.sim.validation_text import user_error
from storyteller.sim.world.character_track import CharacterTrack, CharacterTrackError
from storyteller.sim.world.track_chunks import (
    CHUNK_SUFFIX,
    HEADER_BYTES,
    MOTION_FOLDER,
    ChunkError,
    check_chunk_total,
    chunk_path,
    chunked_track,
)

STORY_FILE = "story.json"
SCENE_FILE = "scene.json"
TRACK_SUFFIX = ".track.npz"
MAX_STORY_BYTES = 24 << 20
"""Bytes of the largest ``story.json`` read (about a kilobyte per step and per event: room for
:data:`MAX_STORY_ITEMS` of each)."""
MAX_STORY_ITEMS = 10_000
"""Steps, and events, of the largest ``story.json`` shown: the longest run allowed (2.5 h, 24
characters; ``storyteller.orchestrator.session.run_manifest``) makes about 7,000 events, and each costs the
export's captions and the page a line (120,000 steps and 60,000 events took ``view --export``
past 20 s; 10,000 of each about 2 s more than a small story)."""
MAX_STORY_DEPTH = 16
"""JSON nesting of ``story.json`` at most (it has 5: a plan's position in a step in ``steps``)."""


class RunFolderError(Exception):
    """A run folder the viewer cannot show (the message names the file and what is wrong)."""


class _StoryModel(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


class StoryStep(_StoryModel):
    """One planning step of ``story.json``'s ``steps`` (as ``run_outputs.story_json`` writes it)."""

    index: int = Field(ge=0)
    applied_frame: Frame | None = None
    kind: Literal["wait", "failed", "event"]
    node: str | None = None
    feedback: str | None = None
    characters: Characters = ()
    activity: str = ""
    plans: tuple[PlannedCharacter, ...] = ()
    text: str = ""
    """What the step tells a person (every kind has one since the story text is built from plans)."""


class StoryInstruction(_StoryModel):
    """One instruction of ``story.json``'s ``instructions``."""

    frame: Frame
    time_s: float = Field(ge=0)
    source: str
    text: str


class StoryFile(_StoryModel):
    """``story.json``: what the viewer reads of a finished run (older files lack the later fields)."""

    scene: str | None = None
    characters: Characters = ()
    instruction: str = ""
    instructions: tuple[StoryInstruction, ...] = Field(default=(), max_length=MAX_STORY_ITEMS)
    fps: Fps = 30.0
    frames: Frame | None = None
    steps: tuple[StoryStep, ...] = Field(default=(), max_length=MAX_STORY_ITEMS)
    events: tuple[StoryEventRecord, ...] = Field(default=(), max_length=MAX_STORY_ITEMS)


@dataclass(frozen=True)
class RunData:
    """Everything the viewer shows of one run."""

    folder: Path
    scene: Scene | None
    scene_note: str | None
    """Why the scene's objects are missing, when they are (None when the scene was found)."""
    fps: float
    tracks: tuple[CharacterTrack, ...]
    events: tuple[StoryEventRecord, ...]
    instruction: str
    live: bool = False
    """Read from a run still in progress (``story.jsonl`` and the chunk files, no ``story.json``)."""

    @property
    def num_frames(self) -> int:
        """Frames of the longest track (at least 1)."""
        return max((t.num_frames for t in self.tracks), default=1)


def folder_stamp(folder: Path) -> tuple[tuple[str, int, int], ...]:
    """Names, sizes and mtimes (ns) of the files the viewer reads; changes when they change."""
    if not folder.is_dir():
        return ()
    stamp = []
    chunks = folder / MOTION_FOLDER
    streamed = sorted(chunks.glob(f"*{CHUNK_SUFFIX}")) if chunks.is_dir() else []
    for path in [*sorted(folder.iterdir()), *streamed]:
        if path.name in (STORY_FILE, STREAM_FILE, SCENE_FILE) or path.name.endswith((TRACK_SUFFIX, CHUNK_SUFFIX)):
            try:
                st = path.stat()
            except OSError:  # removed between listing and stat: the next poll sees it
                continue
            stamp.append((path.name, st.st_size, st.st_mtime_ns))
    return tuple(stamp)


def is_ready(folder: Path) -> bool:
    """Whether there is a run to show: its story log (a finished run), or the story stream and
    a first chunk record (a run in progress)."""
    if (folder / STORY_FILE).is_file():
        return True
    stream, motion = folder / STREAM_FILE, folder / MOTION_FOLDER
    if not (stream.is_file() and motion.is_dir()):
        return False
    return any(_size(p) >= HEADER_BYTES for p in motion.glob(f"*{CHUNK_SUFFIX}"))


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def load_run(folder: Path) -> RunData:
    """The run in ``folder``; :class:`RunFolderError` when a file is missing or malformed."""
    if not folder.is_dir():
        raise RunFolderError(f"{folder}: not a folder (expected the --out folder of `storyteller run`)")
    story_path = folder / STORY_FILE
    if not story_path.exists() and not story_path.is_symlink():  # a link or a device there is read, and refused
        return _live_run(folder)
    story = read_story_file(story_path)
    tracks = []
    for path in sorted(folder.glob(f"*{TRACK_SUFFIX}")):
        try:
            tracks.append(CharacterTrack.load(path))
        except CharacterTrackError as exc:  # names the file and the field
            raise RunFolderError(str(exc) if exc.path is not None else f"{path}: {exc}") from None
        except (OSError, ValueError) as exc:
            raise RunFolderError(f"{path}: {exc}") from None
    have = {t.name for t in tracks}
    tracks += _chunk_tracks(folder, [n for n in story.characters if n not in have], story.fps)
    order = {name: i for i, name in enumerate(story.characters)}
    tracks.sort(key=lambda t: (order.get(t.name, len(order)), t.name))
    scene, note = scene_of(folder, story.scene)
    return RunData(
        folder=folder,
        scene=scene,
        scene_note=note,
        fps=story.fps,
        tracks=shown_names(tracks),
        events=_with_texts(story.events, story.steps, scene),
        instruction=story.instruction,
    )


def read_story_file(path: Path) -> StoryFile:
    """``story.json`` read within :data:`MAX_STORY_BYTES` and :data:`MAX_STORY_DEPTH` and
    validated; :class:`RunFolderError` (one line naming the file and the field) otherwise."""
    try:
        raw = load_bounded_json(read_bounded_bytes(path, MAX_STORY_BYTES, str(path)), MAX_STORY_DEPTH, str(path))
    except BoundedFileError as exc:
        raise RunFolderError(f"{path}: not readable as JSON ({exc.problem})") from None
    if not isinstance(raw, dict):
        raise RunFolderError(f"{path}: expected a JSON object")
    for key in ("steps", "events"):  # counted before each item is validated
        items = raw.get(key)
        if isinstance(items, list) and len(items) > MAX_STORY_ITEMS:
            raise RunFolderError(f"{path}: field '{key}': {len(items)} items, at most {MAX_STORY_ITEMS} shown")
    try:
        return StoryFile.model_validate(raw)
    except ValidationError as exc:
        raise RunFolderError(user_error(path, exc)) from None


def _with_texts(
    events: tuple[StoryEventRecord, ...], steps: tuple[StoryStep, ...], scene: Scene | None
) -> tuple[StoryEventRecord, ...]:
    """The events of an older ``story.json`` (no ``text``) with their plan sentences, built from
    their steps' plans (``storyteller.agents.story_text``), never from the narrator's activity."""
    if all(e.text for e in events):
        return events
    from storyteller.agents.story_text import plan_text

    plans_of = {s.index: s.plans for s in steps if s.kind == "event"}
    out = []
    for e in events:
        if not e.text:
            e = e.model_copy(update={"text": plan_text(e.characters, list(plans_of.get(e.index, ())), scene)})
        out.append(e)
    return tuple(out)


def _live_run(folder: Path) -> RunData:
    """A run in progress, from ``story.jsonl``, ``scene.json`` and the chunk files."""
    stream = folder / STREAM_FILE
    try:
        start, events = read_story_stream(stream)
    except (StoryStreamError, OSError) as exc:
        raise RunFolderError(str(exc)) from None
    if start is None:
        raise RunFolderError(stream_not_started(folder))
    scene, note = scene_of(folder, start.scene)
    return RunData(
        folder=folder,
        scene=scene,
        scene_note=note,
        fps=start.fps,
        tracks=shown_names(_chunk_tracks(folder, list(start.characters), start.fps)),
        events=events,
        instruction=start.instruction,
        live=True,
    )


def stream_not_started(folder: Path) -> str:
    """The error of a live folder whose ``story.jsonl`` has no start line yet."""
    return f"{folder / STORY_FILE}: not found, and {folder / STREAM_FILE} has no start line yet (the run has not started)"


def _chunk_tracks(folder: Path, names: list[str], fps: float) -> list[CharacterTrack]:
    """The tracks of ``names`` in ``motion/`` (whole records; a file with none is left out),
    their files within ``MAX_RUN_CHUNK_BYTES`` together."""
    try:
        check_chunk_total([chunk_path(folder / MOTION_FOLDER, name) for name in names])
    except ChunkError as exc:
        raise RunFolderError(str(exc)) from None
    tracks = []
    for name in names:
        path = chunk_path(folder / MOTION_FOLDER, name)
        if not path.is_file():
            continue
        try:
            track = chunked_track(path, name, fps)
        except (ChunkError, CharacterTrackError, OSError) as exc:
            raise RunFolderError(f"{path}: {exc}") from None
        if track is not None:
            tracks.append(track)
    return tracks


def shown_names(tracks: list[CharacterTrack]) -> tuple[CharacterTrack, ...]:
    """``tracks`` with names fit to show and to name viewer nodes: a name from a file may hold
    control or bidi characters or a lone surrogate (a JSON ``\\ud800``), shown as escapes
    (:func:`storyteller.orchestrator.safe_text.plain`); two names that read alike then are refused."""
    out = tuple(t if plain(t.name) == t.name else dataclasses.replace(t, name=plain(t.name)) for t in tracks)
    if len({t.name for t in out}) != len(out):
        raise RunFolderError(f"two characters of the run have the same name: {sorted(t.name for t in out)[:8]}")
    return out


def scene_of(folder: Path, name: object) -> tuple[Scene | None, str | None]:
    """The scene of the run in ``folder``: its ``scene.json``, else the bundled scene ``name``,
    else None and why (:class:`RunFolderError` when ``scene.json`` is there and bad)."""
    from storyteller.sim.scene.bundled import bundled_scene_names, load_bundled_scene
    from storyteller.sim.scene.errors import SceneFileError
    from storyteller.sim.scene.files import load_scene_json

    path = folder / SCENE_FILE
    if path.is_file():
        try:
            return load_scene_json(path), None
        except SceneFileError as exc:
            raise RunFolderError(str(exc)) from None
    if isinstance(name, str) and name in bundled_scene_names():
        return load_bundled_scene(name), None
    return None, f"no {SCENE_FILE} in the run folder and {name!r} is not a bundled scene: objects not shown"


__all__ = [
    "SCENE_FILE", "STORY_FILE", "STREAM_FILE", "TRACK_SUFFIX", "RunData", "RunFolderError", "StoryEventRecord",
    "StoryFile", "folder_stamp", "is_ready", "load_run", "read_story_file", "scene_of", "shown_names",
    "stream_not_started",
]  # fmt: skip

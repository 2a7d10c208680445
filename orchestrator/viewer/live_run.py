"""A run folder read again and again by a viewer that polls it: a live run read incrementally.

:class:`RunReader.load` gives what :func:`~.run_folder.load_run` gives for the same folder (the
same tracks, bit for bit, and the same events), at the cost of what was appended since the last
call while the run is in progress: ``story.jsonl`` through
:class:`~storyteller.orchestrator.session.story_stream.StoryStreamReader` (whole lines appended since the last
read) and each character's ``motion/<slug>.chunks`` through :class:`~storyteller.sim.world.chunk_tail.ChunkTail`
(whole records appended since the last read; a torn last record waits for the next call). A
finished run (``story.json`` there, or anything in its place) is read whole by ``load_run``.

Something is read from its start again, and :attr:`RunReader.reread` says what and why, when a
file is another file (replaced), shorter than what was read (cut), gone, or its appended bytes
are not what follows (rewritten); and the motion of every character when ``story.jsonl`` gets a
new start line (a resume, which cuts the chunk files back to its checkpoint, or a new run in the
folder). The limits of a full read hold at every call: the chunk files' sizes, alone and together
(``check_chunk_total``), a regular file only, every record's size, CRC, frame order and name
table, each stream line's keys and fields; what a full read refuses is the same
:class:`~.run_folder.RunFolderError` here.
"""

from __future__ import annotations

import os
from pathlib import Path

from storyteller.orchestrator.session.story_stream import STREAM_FILE, StoryStreamError, StoryStreamReader
from storyteller.orchestrator.viewer.run_folder import (
    SCENE_FILE,
    STORY_FILE,
    RunData,
    RunFolderError,
    load_run,
    scene_of,
    shown_names,
    stream_not_started,
)
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.character_track import CharacterTrack, CharacterTrackError
from storyteller.sim.world.chunk_tail import ChunkTail
from storyteller.sim.world.track_chunks import MOTION_FOLDER, ChunkError, check_chunk_total, chunk_path


class RunReader:
    """Reads the run in ``folder`` at each :meth:`load`; :attr:`bytes_read` counts the bytes of
    ``story.jsonl`` and the chunk files read so far (the other files are small and read whole)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.reread: str | None = None
        """What the last :meth:`load` read from its start again, and why (None: appended bytes only)."""
        self._stream = StoryStreamReader(folder / STREAM_FILE)
        self._session = 0  # the line of story.jsonl whose session the motion held belongs to
        self._tails: dict[str, ChunkTail] = {}
        self._tracks: dict[str, CharacterTrack] = {}
        self._scene: tuple[object, tuple[Scene | None, str | None]] | None = None  # (scene.json stat, scene)
        self._done_bytes = 0  # bytes counted by readers dropped since

    @property
    def bytes_read(self) -> int:
        return self._done_bytes + self._stream.bytes_read + sum(t.bytes_read for t in self._tails.values())

    def load(self) -> RunData:
        """The run as it is now (:class:`~.run_folder.RunFolderError` as ``load_run`` raises it)."""
        story = self.folder / STORY_FILE
        if not self.folder.is_dir() or story.exists() or story.is_symlink():  # finished (or not a run folder)
            self._forget_motion()
            self.reread = None
            return load_run(self.folder)
        reasons: list[str] = []
        try:
            start, events = self._stream.read()
        except (StoryStreamError, OSError) as exc:
            raise RunFolderError(str(exc)) from None
        if self._stream.reread is not None:
            reasons.append(f"{self._stream.path}: {self._stream.reread}")
        if start is None:
            raise RunFolderError(stream_not_started(self.folder))
        if self._stream.start_line != self._session:
            if self._tracks:
                reasons.append(f"{self._stream.path}: a new session from frame {start.frame} (motion read again)")
            self._forget_motion()
            self._session = self._stream.start_line
        scene, note = self._scene_of(start.scene)
        tracks = self._chunk_tracks(list(start.characters), start.fps, reasons)
        self.reread = "; ".join(reasons) or None
        return RunData(folder=self.folder, scene=scene, scene_note=note, fps=start.fps, tracks=shown_names(tracks),
                       events=events, instruction=start.instruction, live=True)

    def _forget_motion(self) -> None:
        self._done_bytes += sum(t.bytes_read for t in self._tails.values())
        self._tails, self._tracks = {}, {}

    def _scene_of(self, name: str) -> tuple[Scene | None, str | None]:
        """``scene_of`` the folder, read again only when ``scene.json`` changed (or the name did)."""
        try:
            st = os.stat(self.folder / SCENE_FILE)
            key: object = (name, st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_mode)
        except OSError:
            key = (name, None)
        if self._scene is None or self._scene[0] != key:
            self._scene = (key, scene_of(self.folder, name))
        return self._scene[1]

    def _chunk_tracks(self, names: list[str], fps: float, reasons: list[str]) -> list[CharacterTrack]:
        """What ``run_folder``'s full read of the chunk files gives, from the records appended."""
        motion = self.folder / MOTION_FOLDER
        try:
            check_chunk_total([chunk_path(motion, name) for name in names])
        except ChunkError as exc:
            raise RunFolderError(str(exc)) from None
        tracks = []
        for name in names:
            path = chunk_path(motion, name)
            if not path.is_file():  # as the full read: a file that is not there (yet) is left out
                self._drop(name)
                continue
            tail = self._tails.setdefault(name, ChunkTail(path))
            try:
                got = tail.read()
                new = None if got.frames.count == 0 else CharacterTrack(
                    name=name, root_positions=got.frames.pelvis, local_rotations=got.frames.rotations.astype(float),
                    fps=fps, action_labels=got.frames.labels,
                )  # fmt: skip
            except (ChunkError, CharacterTrackError, OSError) as exc:
                self._drop(name)  # read whole next time
                raise RunFolderError(f"{path}: {exc}") from None
            held = self._tracks.get(name)
            if got.reread is not None:
                reasons.append(f"{path}: {got.reread}")
                held = None
            track = held if new is None else new if held is None else held.then(new)
            if track is None:
                self._tracks.pop(name, None)
                continue
            self._tracks[name] = track
            tracks.append(track)
        return tracks

    def _drop(self, name: str) -> None:
        tail = self._tails.pop(name, None)
        if tail is not None:
            self._done_bytes += tail.bytes_read
        self._tracks.pop(name, None)

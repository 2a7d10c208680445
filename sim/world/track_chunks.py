"""Motion frames on disk: one append-only chunk file per character, written as the story runs.

A world whose track buffers stream (``TrackBuffers.stream_to``) hands every full window of
frames to a :class:`ChunkStore`, which appends one *record* per character to
``<folder>/<slug>.chunks`` and forgets the frames; memory then holds at most one window.
Readers (:func:`read_frames`, the exporters through ``World.tracks()``, the viewer) get the
frames back exactly as the world produced them (same dtypes, same values).

A record is a fixed header, then its payload::

    magic b"STKC" | version u16 | reserved u16 | start frame u64 | frames u32 | names bytes u32
    | payload bytes u64 | crc32 of the payload u32              (little-endian, 36 bytes)
    payload: pelvis f8 (n, 3) | rotations f4 (n, 22, 3, 3) | contacts u1 (n, 2)
             | labels i4 (n,) | events i4 (n,) | names (JSON list of str, UTF-8)

``labels`` and ``events`` index the record's own ``names`` list, so each record reads on its
own. Records follow each other without gaps: record k starts at the frame record k-1 ended.

Durability under kill -9: a record is written with one ``write`` call on a file opened for
appending, so a record whose write returned is in the kernel and survives the process; the
header's length and CRC detect a torn last record (a crash in the middle of a write, or a
power loss before :meth:`ChunkStore.sync`), which :func:`scan` reports and
:meth:`ChunkStore.open` cuts off. ``sync`` fsyncs every file: a checkpoint that says "N frames
are durable" is written only after it. Plain file I/O: no clock, no logging.

A chunk file may come from someone else's run folder, so reading one is bounded: only a regular
file is read (a FIFO or a device is refused, never waited on), a record's payload is at most
:data:`MAX_RECORD_BYTES` (a header claiming more is refused before anything is read), a whole
file at most :data:`MAX_CHUNK_FILE_BYTES` (refused from its size, before a record is read) and
the chunk files a reader takes from one run folder at most :data:`MAX_RUN_CHUNK_BYTES` together
(:func:`check_chunk_total`), its name table is a JSON list of strings read within limits
(``storyteller.sim.bounded_files``), and every label and event index points into it. Anything else is one
:class:`ChunkError` naming the file.
"""

from __future__ import annotations

import io
import json
import os
import stat
import struct
import zlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from storyteller.sim.body.skeleton import NUM_JOINTS
from storyteller.sim.bounded_files import BoundedFileError, load_bounded_json
from storyteller.sim.no_follow_writes import make_folder, open_append
from storyteller.sim.run_folder_names import (  # the two names re-exported: readers import them from here
    CHUNK_SUFFIX as CHUNK_SUFFIX,
)
from storyteller.sim.run_folder_names import (
    MOTION_FOLDER as MOTION_FOLDER,
)
from storyteller.sim.run_folder_names import file_slug
from storyteller.sim.world.character_track import CharacterTrack

MAGIC = b"STKC"
VERSION = 1
_HEADER = struct.Struct("<4sHHQIIQI")
HEADER_BYTES = _HEADER.size
MAX_RECORD_BYTES = 64 << 20
"""Payload bytes of one record at most (a record holds one window, 300 frames: about 250 KB)."""
_FRAME_BYTES = 3 * 8 + NUM_JOINTS * 9 * 4 + 2 + 4 + 4  # payload bytes per frame, besides the names
MAX_CHUNK_FILE_BYTES = 256 << 20
"""Bytes of one chunk file at most: one character's motion of about 325,000 frames (826 bytes a
frame), 3.0 hours at 30 fps; as large as the ``.track.npz`` a reader takes
(``storyteller.sim.world.character_track.MAX_TRACK_FILE_BYTES``). Without it a file of many valid records
(mostly zeros: a sparse file costs no disk) had a reader check and decode all of them."""
MAX_RUN_CHUNK_BYTES = 1 << 30
"""Bytes of the chunk files of one run folder a reader takes together: about 12 character-hours
at 30 fps (a 50-walker crowd for 10 minutes is 0.74 GB)."""


class ChunkError(ValueError):
    """A chunk file that does not hold what it should (the message names the file and why)."""


def chunk_slug(name: str) -> str:
    """The file-name-safe form of a character name (``storyteller.sim.run_folder_names.file_slug``)."""
    return file_slug(name)


def chunk_path(folder: Path, name: str) -> Path:
    return folder / f"{chunk_slug(name)}{CHUNK_SUFFIX}"


@dataclass(frozen=True)
class Frames:
    """Consecutive frames of one character from ``start``: the track buffer's columns, with
    ``labels`` / ``events`` as strings (motion label and event id, "" outside events)."""

    start: int
    pelvis: np.ndarray  # (n, 3) float64
    rotations: np.ndarray  # (n, 22, 3, 3) float32
    contacts: np.ndarray  # (n, 2) bool
    labels: tuple[str, ...]
    events: tuple[str, ...]

    @property
    def count(self) -> int:
        return int(self.pelvis.shape[0])


def encode_record(start: int, pelvis: np.ndarray, rotations: np.ndarray, contacts: np.ndarray,
                  labels: Sequence[str], events: Sequence[str]) -> bytes:
    """One record (header and payload) of ``n`` frames from ``start``."""
    n = int(pelvis.shape[0])
    if rotations.shape != (n, NUM_JOINTS, 3, 3) or contacts.shape != (n, 2) or len(labels) != n or len(events) != n:
        raise ChunkError(f"a chunk of {n} frames needs {n} rows in every column")
    table: dict[str, int] = {}
    label_ids = np.array([table.setdefault(s, len(table)) for s in labels], dtype="<i4")
    event_ids = np.array([table.setdefault(s, len(table)) for s in events], dtype="<i4")
    names = json.dumps(list(table), ensure_ascii=False).encode("utf-8")
    payload = b"".join((
        np.ascontiguousarray(pelvis, dtype="<f8").tobytes(),
        np.ascontiguousarray(rotations, dtype="<f4").tobytes(),
        np.ascontiguousarray(contacts, dtype=np.uint8).tobytes(),
        label_ids.tobytes(),
        event_ids.tobytes(),
        names,
    ))
    header = _HEADER.pack(MAGIC, VERSION, 0, start, n, len(names), len(payload), zlib.crc32(payload))
    return header + payload


def decode_payload(start: int, n: int, names_len: int, payload: bytes, path: Path) -> Frames:
    sizes = (n * 3 * 8, n * NUM_JOINTS * 9 * 4, n * 2, n * 4, n * 4)
    if sum(sizes) + names_len != len(payload):
        raise ChunkError(f"{path}: record at frame {start} has {len(payload)} payload bytes, expected "
                         f"{sum(sizes) + names_len}")
    offs = np.cumsum((0, *sizes))
    pelvis = np.frombuffer(payload, "<f8", n * 3, int(offs[0])).reshape(n, 3).astype(np.float64)
    rotations = np.frombuffer(payload, "<f4", n * NUM_JOINTS * 9, int(offs[1])).reshape(n, NUM_JOINTS, 3, 3)
    contacts = np.frombuffer(payload, np.uint8, n * 2, int(offs[2])).reshape(n, 2).astype(bool)
    label_ids = np.frombuffer(payload, "<i4", n, int(offs[3]))
    event_ids = np.frombuffer(payload, "<i4", n, int(offs[4]))
    try:
        names = load_bounded_json(payload[int(offs[5]):], 2, f"{path}: record at frame {start}: name table")
    except BoundedFileError as exc:
        raise ChunkError(str(exc)) from None
    if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
        raise ChunkError(f"{path}: record at frame {start} has a bad name table (expected a JSON list of strings)")
    for ids in (label_ids, event_ids):
        if n and (int(ids.min()) < 0 or int(ids.max()) >= len(names)):
            raise ChunkError(f"{path}: record at frame {start} has a label or event index outside its name table")
    labels = tuple(names[i] for i in label_ids)
    events = tuple(names[i] for i in event_ids)
    return Frames(start, pelvis, rotations.astype(np.float32), contacts, labels, events)


@dataclass(frozen=True)
class Scan:
    """What :func:`scan` found in a chunk file: ``frames`` whole frames in records ending at byte
    ``good_bytes``; ``torn``: bytes after them that do not form a whole, valid record."""

    frames: int
    good_bytes: int
    torn: int
    records: tuple[tuple[int, int, int], ...]  # (byte offset, start frame, frames) of each record


def scan(path: Path) -> Scan:
    """The whole records of ``path`` (a missing file has none); a bad record that is not the
    last (frames out of order, a bad CRC followed by more data), a record larger than
    :data:`MAX_RECORD_BYTES` or a file that is not a regular file raises :class:`ChunkError`."""
    try:
        fh = open_chunk_file(path)
    except FileNotFoundError:
        return Scan(0, 0, 0, ())
    records: list[tuple[int, int, int]] = []
    offset = frames = 0
    with fh:
        data_size = os.fstat(fh.fileno()).st_size
        check_chunk_size(path, data_size)
        for record in whole_records(fh.read, path, 0, 0, data_size):
            records.append((record.offset, record.start, record.frames))
            frames, offset = record.start + record.frames, record.end
    return Scan(frames, offset, data_size - offset, tuple(records))


@dataclass(frozen=True)
class Record:
    """One whole, valid record of a chunk file as :func:`whole_records` read it."""

    offset: int
    """Byte of the file where its header starts."""
    end: int
    """Byte after its payload (where the next record starts)."""
    start: int
    frames: int
    names_len: int
    payload: bytes


def whole_records(read: Callable[[int], bytes], path: Path, offset: int, frames: int,
                  data_size: int) -> Iterator[Record]:
    """The whole records of a chunk file from byte ``offset`` (where ``read``, the file's
    ``read``, is positioned; the first record must start at frame ``frames``) to ``data_size``,
    its size when it was opened. Stops before a torn last record (too short, a bad magic, a bad
    CRC on the last one); raises :class:`ChunkError` on a record larger than
    :data:`MAX_RECORD_BYTES` (before its payload is read), a bad CRC followed by more data, or
    frames out of order. Every check of :func:`scan`, which reads a file with it from byte 0."""
    while offset < data_size:
        header = read(HEADER_BYTES)
        if len(header) < HEADER_BYTES:
            return
        magic, version, _, start, n, names_len, size, crc = _HEADER.unpack(header)
        if magic != MAGIC or version != VERSION:
            return
        end = offset + HEADER_BYTES + size
        if end > data_size:
            return
        if size > MAX_RECORD_BYTES or n * _FRAME_BYTES + names_len != size:
            raise ChunkError(f"{path}: record at byte {offset} claims {n} frames in {size} bytes (at most "
                             f"{MAX_RECORD_BYTES} bytes, {_FRAME_BYTES} a frame and its name table)")
        payload = read(size)
        if len(payload) < size:  # the file shrank since it was opened: read it again later
            return
        if zlib.crc32(payload) != crc:
            if end < data_size:
                raise ChunkError(f"{path}: record at byte {offset} fails its CRC and is not the last one")
            return
        if start != frames:
            raise ChunkError(f"{path}: record at byte {offset} starts at frame {start}, expected {frames}")
        yield Record(offset, end, start, n, names_len, payload)
        frames += n
        offset = end


def check_chunk_size(path: Path, size: int) -> None:
    """Raise :class:`ChunkError` when a chunk file of ``size`` bytes is over :data:`MAX_CHUNK_FILE_BYTES`."""
    if size > MAX_CHUNK_FILE_BYTES:
        raise _too_large(path, size)


def _too_large(path: Path, size: int) -> ChunkError:
    return ChunkError(f"{path}: {size} bytes, more than the {MAX_CHUNK_FILE_BYTES} a chunk file may hold "
                      "(about 3 hours of one character at 30 fps)")


def bytes_to_keep(path: Path, frames: int) -> int:
    """The bytes of the chunk file at ``path`` that hold its first ``frames`` frames, read only
    (a resume cuts the file there); :class:`ChunkError` when it holds fewer whole frames, no
    record ends at ``frames`` or it is not a chunk file within its limits."""
    found = scan(path)
    if found.frames < frames:
        raise ChunkError(f"{path}: holds {found.frames} whole frames, {frames} are needed")
    kept = [r for r in found.records if r[1] + r[2] <= frames]
    if sum(r[2] for r in kept) != frames:
        raise ChunkError(f"{path}: no record ends at frame {frames}")
    return found.records[len(kept)][0] if len(kept) < len(found.records) else found.good_bytes


def check_resumable(folder: Path, names: Sequence[str], frames: int) -> None:
    """Raise :class:`ChunkError` unless the chunk files of ``names`` in ``folder`` can be cut back to
    ``frames`` (what :meth:`ChunkStore.open` does on resume), without writing anything: a resume
    that would refuse them refuses before it touches the run folder."""
    paths = [chunk_path(folder, name) for name in names]
    check_chunk_total(paths)
    for path in paths:
        bytes_to_keep(path, frames)


def check_chunk_total(paths: Sequence[Path]) -> None:
    """Raise :class:`ChunkError` when one of the files at ``paths`` (one run folder's chunk
    files; a missing one counts nothing) is over :data:`MAX_CHUNK_FILE_BYTES` (naming it), or
    they hold more than :data:`MAX_RUN_CHUNK_BYTES` together."""
    total = 0
    for path in paths:
        try:
            size = os.stat(path).st_size  # a link is counted as what it names, as a reader opens it
        except OSError:
            continue  # missing or unreadable: its own read says so
        if size > MAX_CHUNK_FILE_BYTES:
            raise _too_large(path, size)
        total += size
        if total > MAX_RUN_CHUNK_BYTES:
            raise ChunkError(f"{path.parent}: the chunk files hold more than the {MAX_RUN_CHUNK_BYTES} bytes a "
                             "run folder's motion may hold together (about 12 character-hours at 30 fps)")


def open_chunk_file(path: Path) -> io.BufferedReader:
    """``path`` opened for reading when it is a regular file (without blocking on a FIFO);
    ``FileNotFoundError`` when there is none, :class:`ChunkError` when it is something else."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise ChunkError(f"{path}: cannot open ({exc.strerror or exc})") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise ChunkError(f"{path}: is not a regular file (a device, a FIFO, a socket or a folder)")
    return os.fdopen(fd, "rb")


def read_frames(path: Path, frames: int | None = None, *, start: int = 0) -> Frames:
    """Frames ``[start, start + frames)`` of ``path`` (``frames`` None: up to the last whole
    record; a torn tail is ignored). Raises :class:`ChunkError` when fewer are there."""
    found = scan(path)
    stop = found.frames if frames is None else start + frames
    if not 0 <= start <= stop <= found.frames:
        raise ChunkError(f"{path}: holds {found.frames} whole frames, asked for [{start}, {stop})")
    parts: list[Frames] = []
    if not found.records:
        return concat_frames(start, parts)
    with open_chunk_file(path) as fh:
        for offset, first, n in found.records:
            if first + n <= start or first >= stop:
                continue
            fh.seek(offset)
            _, _, _, _, _, names_len, size, _ = _HEADER.unpack(fh.read(HEADER_BYTES))
            part = decode_payload(first, n, names_len, fh.read(size), path)
            lo, hi = max(start, first) - first, min(stop, first + n) - first
            parts.append(Frames(first + lo, part.pelvis[lo:hi], part.rotations[lo:hi], part.contacts[lo:hi],
                                part.labels[lo:hi], part.events[lo:hi]))
    return concat_frames(start, parts)


def concat_frames(start: int, parts: Sequence[Frames]) -> Frames:
    """``parts`` (consecutive, from ``start``) as one :class:`Frames`."""
    if not parts:
        return Frames(start, np.zeros((0, 3)), np.zeros((0, NUM_JOINTS, 3, 3), np.float32),
                      np.zeros((0, 2), bool), (), ())
    if len(parts) == 1:
        return parts[0]
    return Frames(
        start,
        np.concatenate([p.pelvis for p in parts]),
        np.concatenate([p.rotations for p in parts]),
        np.concatenate([p.contacts for p in parts]),
        tuple(s for p in parts for s in p.labels),
        tuple(s for p in parts for s in p.events),
    )


class ChunkStore:
    """The chunk files of one world's characters in ``folder``: append, sync, cut back, read.

    Build with :meth:`open`, which cuts a torn last record off every file (and, given
    ``frames``, every record past that frame), so the files agree on one frame count.
    """

    def __init__(self, folder: Path, names: Sequence[str], frames: int) -> None:
        self.folder = folder
        self.names = tuple(names)
        self.frames = frames
        """Frames written (each file holds exactly this many)."""
        self._paths = {name: chunk_path(folder, name) for name in self.names}
        if len({p.name.lower() for p in self._paths.values()}) != len(self.names):
            raise ChunkError(f"character names {list(self.names)} collide as chunk file names")
        self._fds: dict[str, int] = {}

    @classmethod
    def open(cls, folder: Path, names: Sequence[str], frames: int | None = None) -> ChunkStore:
        """The store in ``folder`` (created if missing). ``frames`` None: a new store, every
        file emptied; otherwise keep the first ``frames`` frames of each file (a resume),
        raising :class:`ChunkError` when a file holds fewer whole frames. A symbolic link in
        place of the folder or of a file is refused (``storyteller.sim.no_follow_writes``: an ``OSError``
        naming it), never written, cut or emptied through."""
        make_folder(folder)
        store = cls(folder, names, 0)
        for name, path in store._paths.items():
            try:
                store._fds[name] = open_append(path)
            except OSError:
                store.close()
                raise
            if frames is None:
                os.ftruncate(store._fds[name], 0)
        store.frames = frames if frames is not None else 0
        if frames is not None:
            store.cut(frames, check=True)
        store.sync()
        return store

    def cut(self, frames: int, *, check: bool = False) -> None:
        """Keep only the first ``frames`` frames of every file (drops a torn last record, and
        the records of frames a restored world will simulate again). ``check``: scan every
        file even when ``frames`` is what this store wrote (on opening files of an earlier
        process)."""
        if not check and frames == self.frames:
            return
        keep = {name: bytes_to_keep(path, frames) for name, path in self._paths.items()}  # every file checked first
        for name, keep_bytes in keep.items():
            os.ftruncate(self._fds[name], keep_bytes)
        self.frames = frames

    def path(self, name: str) -> Path:
        return self._paths[name]

    def append(self, start: int, pelvis: np.ndarray, rotations: np.ndarray, contacts: np.ndarray,
               labels: Sequence[Sequence[str]], events: Sequence[Sequence[str]]) -> None:
        """Append frames ``[start, start + n)`` of every character: columns indexed (frame,
        character, ...) in ``names`` order; ``labels`` / ``events`` per character."""
        if start != self.frames:
            raise ChunkError(f"{self.folder}: chunk starts at frame {start}, the files end at {self.frames}")
        for k, name in enumerate(self.names):
            record = encode_record(start, pelvis[:, k], rotations[:, k], contacts[:, k], labels[k], events[k])
            view = memoryview(record)
            while view:
                view = view[os.write(self._fds[name], view):]
        self.frames = start + int(pelvis.shape[0])

    def sync(self) -> None:
        """Make every record written so far durable (fsync each file and the folder)."""
        for fd in self._fds.values():
            os.fsync(fd)
        dir_fd = os.open(self.folder, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)

    def read(self, name: str, frames: int | None = None, *, start: int = 0) -> Frames:
        """Frames ``[start, start + frames)`` of ``name`` (None: all written)."""
        return read_frames(self._paths[name], self.frames - start if frames is None else frames, start=start)

    def close(self) -> None:
        for fd in self._fds.values():
            os.close(fd)
        self._fds.clear()

    def __getstate__(self) -> None:
        raise TypeError("a ChunkStore holds open files; a snapshot records its frame count instead")


def chunked_track(path: Path, name: str, fps: float = 30.0) -> CharacterTrack | None:
    """The ``CharacterTrack`` of the whole records in ``path`` (a run still being written, or one
    stopped before its exports); None when there is no whole frame yet. The same track as
    ``World.track(name)`` gives for those frames."""
    frames = read_frames(path)
    if frames.count == 0:
        return None
    return CharacterTrack(name=name, root_positions=frames.pelvis, local_rotations=frames.rotations.astype(float),
                          fps=fps, action_labels=frames.labels)

"""One chunk file read as it grows: each read takes only the whole records appended since the last.

A live viewer polls a run's ``motion/<slug>.chunks`` once a second while the run appends a record
per window; reading the file from the start at every poll costs the whole run so far each time.
A :class:`ChunkTail` remembers the file (device and inode), the byte where its last whole record
ended and the frame count there, and on :meth:`ChunkTail.read` reads from that byte on. A torn
last record (a write in progress) is not taken and is read again at the next call.

It reads the file from the start again, and says why (:attr:`TailRead.reread`), when the file is
not the one it read (another inode: replaced), is shorter than what it took (cut, e.g. by a
resume), or the bytes at its offset are not the next record (no record header there, another
start frame, a bad CRC followed by more data: rewritten in place). Bytes before the offset that
were rewritten in place without any of these signs are not noticed: the tail holds what it read.

The limits are :func:`~storyteller.sim.world.track_chunks.scan`'s, checked at every read: a regular file only
(a FIFO or a device is refused, never waited on), at most
:data:`~storyteller.sim.world.track_chunks.MAX_CHUNK_FILE_BYTES` (from its size, before a byte is read), each
record's payload at most :data:`~storyteller.sim.world.track_chunks.MAX_RECORD_BYTES`, every record's CRC,
frame order and name table. A file a full read refuses raises the same :class:`ChunkError`.
Plain file I/O: no clock, no logging.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from storyteller.sim.world.track_chunks import (
    HEADER_BYTES,
    MAGIC,
    ChunkError,
    Frames,
    check_chunk_size,
    concat_frames,
    decode_payload,
    open_chunk_file,
    whole_records,
)


@dataclass(frozen=True)
class TailRead:
    """What one :meth:`ChunkTail.read` found: ``frames`` are new frames from ``frames.start``;
    ``reread`` says why the file was read from its start (then ``frames.start`` is 0 and every
    frame held before is to be dropped), None when only appended bytes were read."""

    frames: Frames
    reread: str | None


class ChunkTail:
    """The reader of one chunk file at ``path``; :attr:`bytes_read` counts every byte it read."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.bytes_read = 0
        self._identity: tuple[int, int] | None = None  # (st_dev, st_ino) of the file read so far
        self._offset = 0  # the byte after the last whole record taken
        self._frames = 0  # frames in the records taken

    @property
    def frames(self) -> int:
        """Frames taken so far."""
        return self._frames

    def read(self) -> TailRead:
        """The whole records appended since the last read (see the module docstring); a missing
        file has none (and, when one was read before, is a reread from nothing)."""
        try:
            fh = open_chunk_file(self.path)
        except FileNotFoundError:
            reason = None if self._identity is None else "the file is gone"
            self._identity, self._offset, self._frames = None, 0, 0
            return TailRead(concat_frames(0, []), reason)
        with fh:
            info = os.fstat(fh.fileno())
            check_chunk_size(self.path, info.st_size)
            identity = (info.st_dev, info.st_ino)
            reason = None
            if self._identity is not None and identity != self._identity:
                reason = "another file in its place (replaced)"
            elif info.st_size < self._offset:
                reason = f"{info.st_size} bytes, shorter than the {self._offset} already read (cut)"
            elif self._offset:
                try:
                    return TailRead(self._take(fh, info.st_size), None)
                except ChunkError as exc:
                    reason = f"the bytes after byte {self._offset} are not its next record ({exc})"
            self._identity, self._offset, self._frames = identity, 0, 0
            return TailRead(self._take(fh, info.st_size), reason)

    def _take(self, fh: BinaryIO, size: int) -> Frames:
        """Decode the whole records from the offset on. From an offset past 0, a whole record
        header there without the magic is a :class:`ChunkError` (the file was rewritten: a full
        read would stop elsewhere); a read from byte 0 stops there, as :func:`scan` does."""
        start_offset = self._offset
        fh.seek(start_offset)
        parts: list[Frames] = []
        offset, frames = start_offset, self._frames
        first_header = b""

        def read(n: int) -> bytes:
            nonlocal first_header
            at = fh.tell()
            data = fh.read(n)
            self.bytes_read += len(data)
            if at == start_offset and not parts:
                first_header = data
            return data

        for record in whole_records(read, self.path, offset, frames, size):
            parts.append(decode_payload(record.start, record.frames, record.names_len, record.payload, self.path))
            offset, frames = record.end, record.start + record.frames
        if start_offset and not parts and len(first_header) == HEADER_BYTES and not first_header.startswith(MAGIC):
            raise ChunkError(f"{self.path}: no record header at byte {start_offset}")
        self._offset, self._frames = offset, frames
        return concat_frames(frames - sum(p.count for p in parts), parts)

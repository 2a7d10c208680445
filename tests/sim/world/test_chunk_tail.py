"""A chunk file read as it grows (:class:`~storyteller.sim.world.chunk_tail.ChunkTail`), and a track joined
from its pieces (:meth:`~storyteller.sim.world.character_track.CharacterTrack.then`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from storyteller.sim.body.skeleton import NUM_JOINTS, heading_to_root
from storyteller.sim.world.character_track import CharacterTrack, CharacterTrackError
from storyteller.sim.world.chunk_tail import ChunkTail
from storyteller.sim.world.track_chunks import encode_record, read_frames


def _columns(start: int, n: int) -> tuple[np.ndarray, np.ndarray, list[str]]:
    t = start + np.arange(n)
    pelvis = np.column_stack([np.sin(t / 5.0), t / 30.0, np.full(n, 0.9)])
    rot = np.broadcast_to(np.eye(3), (n, NUM_JOINTS, 3, 3)).copy()
    for i, frame in enumerate(t):
        rot[i, 0] = heading_to_root(float(frame) / 9.0)
    return pelvis, rot, [f"label{int(f) // 7}" for f in t]


def _record(start: int, n: int) -> bytes:
    pelvis, rot, labels = _columns(start, n)
    return encode_record(start, pelvis, rot.astype(np.float32), np.zeros((n, 2), bool), labels, [""] * n)


def test_a_track_joined_from_pieces_is_the_track_built_whole() -> None:
    pelvis, rot, labels = _columns(0, 50)
    whole = CharacterTrack("Ava", pelvis, rot, action_labels=tuple(labels))
    joined = CharacterTrack("Ava", pelvis[:20], rot[:20], action_labels=tuple(labels[:20])).then(
        CharacterTrack("Ava", pelvis[20:], rot[20:], action_labels=tuple(labels[20:])))
    assert joined.root_positions.tobytes() == whole.root_positions.tobytes()
    assert joined.local_rotations.tobytes() == whole.local_rotations.tobytes()
    assert joined.action_labels == whole.action_labels and not joined.root_positions.flags.writeable
    with pytest.raises(CharacterTrackError, match="cannot follow"):
        joined.then(CharacterTrack("Ben", pelvis[:1], rot[:1], action_labels=tuple(labels[:1])))


def test_the_tail_takes_whole_records_as_they_come_and_counts_what_it_reads(tmp_path: Path) -> None:
    path = tmp_path / "Ava.chunks"
    first, second = _record(0, 30), _record(30, 12)
    path.write_bytes(first + second[:50])  # the second record torn
    tail = ChunkTail(path)
    got = tail.read()
    assert (got.frames.start, got.frames.count, got.reread, tail.frames) == (0, 30, None, 30)
    read_once = tail.bytes_read
    assert read_once == len(first) + 36  # the torn record's header was looked at, its payload not
    with path.open("ab") as fh:
        fh.write(second[50:])
    got = tail.read()
    assert (got.frames.start, got.frames.count, got.reread) == (30, 12, None)
    assert tail.bytes_read - read_once == len(second)  # from where the last whole record ended
    whole = read_frames(path)
    assert np.array_equal(got.frames.pelvis, whole.pelvis[30:]) and got.frames.labels == whole.labels[30:]
    assert tail.read().frames.count == 0

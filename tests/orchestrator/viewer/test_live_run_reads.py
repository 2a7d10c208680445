"""The viewer's incremental read of a live run (:class:`~storyteller.orchestrator.viewer.live_run.RunReader`).

A run folder is written here as a running ``storyteller run`` writes it (``scene.json``,
``story.jsonl`` through ``StoryStream``, chunk records appended to ``motion/<slug>.chunks``),
record by record and with torn writes, and after each change the incremental read is compared
with a full :func:`~storyteller.orchestrator.viewer.run_folder.load_run` of the same folder: the same tracks
bit for bit, the same events, and the same one-line refusal for a file a full read refuses.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from storyteller.orchestrator.session.story_stream import STREAM_FILE, StoryStream, StreamStart
from storyteller.orchestrator.viewer.live_run import RunReader
from storyteller.orchestrator.viewer.run_folder import RunData, RunFolderError, load_run
from storyteller.sim.body.skeleton import NUM_JOINTS, heading_to_root
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.files import save_scene_json
from storyteller.sim.world.track_chunks import MAX_RECORD_BYTES, MOTION_FOLDER, chunk_path, encode_record
from tests.support.story_event_stub import Event

NAMES = ("Ava", "Ben")
WINDOW = 30




def _record(k: int, start: int, frames: int) -> bytes:
    """Character ``k``'s record of frames ``[start, start + frames)``: a turning walk with
    fractional positions and labels that change, so every byte counts."""
    t = start + np.arange(frames)
    pelvis = np.column_stack([np.sin(t / 7.0) + k, np.cos(t / 11.0) / 3.0, 0.9 + t / 1e4])
    rot = np.broadcast_to(np.eye(3), (frames, NUM_JOINTS, 3, 3)).copy()
    for i, frame in enumerate(t):
        rot[i, 0] = heading_to_root(float(frame) / 13.0)
        rot[i, 5] = heading_to_root(float(frame) / 17.0 + k)
    labels = [("walk", "sit", "wave")[(int(f) // 20 + k) % 3] for f in t]
    events = ["" if f % 50 < 25 else f"event-{int(f) // 50:04d}" for f in t]
    return encode_record(start, pelvis, rot.astype(np.float32), np.ones((frames, 2), bool), labels, events)


class LiveFolder:
    """A run folder as a run in progress writes it."""

    def __init__(self, tmp_path: Path) -> None:
        self.folder = tmp_path / "run"
        (self.folder / MOTION_FOLDER).mkdir(parents=True)
        save_scene_json(load_bundled_scene("home"), self.folder / "scene.json")
        self.stream = StoryStream(self.folder)
        self.stream.start(StreamStart(scene="home", characters=NAMES, instruction="make coffee", fps=30, frame=0))
        self.frames = 0
        for name in NAMES:
            self.path(name).touch()

    def path(self, name: str) -> Path:
        return chunk_path(self.folder / MOTION_FOLDER, name)

    def append(self, frames: int = WINDOW, *, torn: int = 0) -> None:
        """A record of ``frames`` more frames for every character (``torn``: only that many bytes
        of Ava's; :meth:`finish` writes the rest)."""
        self._rest = b""
        for k, name in enumerate(NAMES):
            data = _record(k, self.frames, frames)
            if torn and name == "Ava":
                data, self._rest = data[:torn], data[torn:]
            with self.path(name).open("ab") as fh:
                fh.write(data)
        self.frames += frames

    def finish(self) -> None:
        with self.path("Ava").open("ab") as fh:
            fh.write(self._rest)

    def event(self, index: int, state: str = "ongoing", finished_frame: int | None = None) -> None:
        self.stream.event(Event(index, f"event-{index:04d}", ("Ava",), "walks", index * 10, index * 10 + 1,
                                state, finished_frame, text=f"Ava walks {index}"))

    def size(self) -> int:
        """Bytes of story.jsonl and the chunk files."""
        return (self.folder / STREAM_FILE).stat().st_size + sum(self.path(n).stat().st_size for n in NAMES)


@pytest.fixture
def live(tmp_path: Path) -> LiveFolder:
    return LiveFolder(tmp_path)


def _same(got: RunData, full: RunData) -> None:
    """``got`` is ``full``: tracks bit for bit, events, scene and the rest."""
    assert [t.name for t in got.tracks] == [t.name for t in full.tracks]
    for a, b in zip(got.tracks, full.tracks, strict=True):
        assert a.root_positions.dtype == b.root_positions.dtype and a.local_rotations.dtype == b.local_rotations.dtype
        assert a.root_positions.tobytes() == b.root_positions.tobytes()
        assert a.local_rotations.tobytes() == b.local_rotations.tobytes()
        assert a.action_labels == b.action_labels and a.fps == b.fps and a.betas.tobytes() == b.betas.tobytes()
    assert got.events == full.events
    assert (got.scene, got.scene_note, got.fps, got.instruction, got.live, got.folder) == (
        full.scene, full.scene_note, full.fps, full.instruction, full.live, full.folder)  # fmt: skip


def test_an_incremental_read_after_each_append_equals_a_full_read(live: LiveFolder) -> None:
    reader = RunReader(live.folder)
    for step in range(6):
        live.append(WINDOW + step)  # records of differing lengths
        if step % 2:
            live.event(step)
            live.event(step - 1, state="completed", finished_frame=live.frames)
        run = reader.load()
        _same(run, load_run(live.folder))
        assert reader.reread is None and run.num_frames == live.frames
    assert len(run.events) == 6 and run.tracks[0].num_frames == sum(WINDOW + s for s in range(6))


def test_a_torn_record_and_a_torn_line_wait_for_the_next_read(live: LiveFolder) -> None:
    reader = RunReader(live.folder)
    live.append()
    reader.load()
    live.append(torn=100)  # Ava's second record half written
    with (live.folder / STREAM_FILE).open("ab") as fh:
        fh.write(b'{"kind": "event", "event": {"event_id": "ev')  # a line half written
    run = reader.load()
    _same(run, load_run(live.folder))
    assert [t.num_frames for t in run.tracks] == [WINDOW, 2 * WINDOW]
    live.finish()
    run = reader.load()
    _same(run, load_run(live.folder))
    assert [t.num_frames for t in run.tracks] == [2 * WINDOW, 2 * WINDOW] and reader.reread is None


def test_the_second_read_reads_only_the_bytes_appended(live: LiveFolder) -> None:
    reader = RunReader(live.folder)
    for _ in range(4):
        live.append()
    live.event(0)
    reader.load()
    assert reader.bytes_read == live.size()  # the first read is a whole one
    before_bytes, before_size = reader.bytes_read, live.size()
    live.append()
    live.event(1)
    reader.load()
    appended = live.size() - before_size
    assert appended > 0 and reader.bytes_read - before_bytes == appended
    reader.load()  # nothing appended: nothing read
    assert reader.bytes_read - before_bytes == appended


def _cut(live: LiveFolder) -> str:
    for name in NAMES:
        with live.path(name).open("r+b") as fh:
            fh.truncate(len(_record(0, 0, WINDOW)))  # back to the first record
    live.frames = WINDOW
    return "shorter than"


def _replace_ava(live: LiveFolder) -> str:
    other = live.path("Ava").with_suffix(".new")
    other.write_bytes(b"".join(_record(1, f, WINDOW) for f in range(0, live.frames, WINDOW)))  # other motion
    os.replace(other, live.path("Ava"))
    return "replaced"


def _rewrite(live: LiveFolder) -> str:
    """Cut and written again past the old end between two reads (a resume from frame 0)."""
    live.frames += WINDOW
    for k, name in enumerate(NAMES):
        with live.path(name).open("r+b") as fh:
            fh.truncate(0)
            fh.write(b"".join(_record(1 - k, f, WINDOW // 2) for f in range(0, live.frames, WINDOW // 2)))
    return "not its next record"


def _replace_stream(live: LiveFolder) -> str:
    path = live.folder / STREAM_FILE
    data = path.read_bytes()
    path.unlink()
    path.write_bytes(data.replace(b"make coffee", b"make tea!!"))
    return "story.jsonl: another file in its place (replaced)"


def _new_session(live: LiveFolder) -> str:
    live.stream.start(StreamStart(scene="home", characters=NAMES, instruction="again", fps=30, frame=WINDOW))
    return "a new session from frame 30"


CHANGES = {"cut": _cut, "replaced": _replace_ava, "rewritten": _rewrite, "stream replaced": _replace_stream,
           "new session": _new_session}


@pytest.mark.parametrize("change", list(CHANGES))
def test_a_cut_or_replaced_file_is_read_again_and_says_why(live: LiveFolder, change: str) -> None:
    reader = RunReader(live.folder)
    for _ in range(3):
        live.append()
        reader.load()
    before = reader.bytes_read
    reason = CHANGES[change](live)
    run = reader.load()
    _same(run, load_run(live.folder))
    assert reader.reread is not None and reason in reader.reread, reader.reread
    assert reader.bytes_read > before
    live.append()  # and it goes on incrementally from there
    _same(reader.load(), load_run(live.folder))
    assert reader.reread is None


def _fifo_stream(live: LiveFolder) -> None:
    (live.folder / STREAM_FILE).unlink()
    os.mkfifo(live.folder / STREAM_FILE)


def _stream_dev_zero(live: LiveFolder) -> None:
    (live.folder / STREAM_FILE).unlink()
    (live.folder / STREAM_FILE).symlink_to("/dev/zero")


def _huge_chunks(live: LiveFolder) -> None:
    with live.path("Ava").open("r+b") as fh:
        fh.truncate(300 << 20)  # sparse: over the 256 MiB a chunk file may hold


def _record_claiming_too_much(live: LiveFolder) -> None:
    header = bytearray(_record(0, live.frames, 1)[:36])
    header[24:32] = (MAX_RECORD_BYTES + 1).to_bytes(8, "little")
    with live.path("Ava").open("ab") as fh:
        fh.write(bytes(header))
        fh.truncate(fh.tell() + MAX_RECORD_BYTES + 100)  # sparse: the bytes it claims are there


def _bad_middle_crc(live: LiveFolder) -> None:
    live.append()
    data = bytearray(live.path("Ben").read_bytes())
    data[-100] ^= 0xFF  # the last record Ben had when the reader last looked fails its CRC... after more records
    live.path("Ben").write_bytes(bytes(data))
    live.append()


def _bad_line(live: LiveFolder) -> None:
    with (live.folder / STREAM_FILE).open("ab") as fh:
        fh.write(b'{"kind": "event", "event": {}}\n')


HOSTILE = {"stream a FIFO": _fifo_stream, "stream -> /dev/zero": _stream_dev_zero, "chunks 300 MiB": _huge_chunks,
           "record over its cap": _record_claiming_too_much, "bad CRC, more after": _bad_middle_crc,
           "bad stream line": _bad_line}


@pytest.mark.parametrize("case", list(HOSTILE))
def test_a_file_a_full_read_refuses_is_refused_the_same_after_incremental_reads(live: LiveFolder, case: str) -> None:
    reader = RunReader(live.folder)
    for _ in range(2):
        live.append()
        reader.load()
    HOSTILE[case](live)
    with pytest.raises(RunFolderError) as full:
        load_run(live.folder)
    with pytest.raises(RunFolderError) as got:
        reader.load()
    assert str(got.value) == str(full.value) and "\n" not in str(got.value)
    with pytest.raises(RunFolderError) as again:  # and at every read after, until the file changes
        reader.load()
    assert str(again.value) == str(full.value)


def test_a_fifo_in_place_of_a_chunk_file_is_left_out_as_a_full_read_leaves_it(live: LiveFolder) -> None:
    reader = RunReader(live.folder)
    live.append()
    reader.load()
    live.path("Ava").unlink()
    os.mkfifo(live.path("Ava"))  # never opened: a reader would wait on it
    run = reader.load()
    _same(run, load_run(live.folder))
    assert [t.name for t in run.tracks] == ["Ben"]


def test_a_finished_run_is_read_whole(live: LiveFolder) -> None:
    reader = RunReader(live.folder)
    live.append()
    assert reader.load().live
    full = load_run(live.folder)
    story = {"scene": "home", "characters": list(NAMES), "fps": 30, "events": [], "instruction": "x"}
    (live.folder / "story.json").write_text(json.dumps(story), encoding="utf-8")
    run = reader.load()
    assert not run.live and run.instruction == "x"
    assert run.tracks[0].root_positions.tobytes() == full.tracks[0].root_positions.tobytes()

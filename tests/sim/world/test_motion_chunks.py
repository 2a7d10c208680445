"""Motion streamed to chunk files (sim/world/track_chunks.py): the same exports as the
all-in-memory world, a bounded in-memory window and snapshot, torn records dropped, and a
restored snapshot going on from its frame with the streamed frames kept.

The worlds run the real motion matcher in the bundled home scene (two characters walking to
targets and acting), so rotations, labels, contacts and event ids are the real thing.
"""

from __future__ import annotations

import pickle
from collections.abc import Iterator
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest

from storyteller.orchestrator.cache_paths import motion_cache_dir
from storyteller.orchestrator.session.roster import start_positions
from storyteller.sim.export.bundle import export_run
from storyteller.sim.motion.database import load_databases
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.events import AssignEvent, Assignment
from storyteller.sim.world.step import World, WorldConfig, WorldError, step
from storyteller.sim.world.track_chunks import (
    HEADER_BYTES,
    ChunkError,
    ChunkStore,
    check_resumable,
    read_frames,
    scan,
)

NAMES = ("Ava", "Ben")
WINDOW = 64


@pytest.fixture(scope="module")
def home() -> tuple[Scene, MotionMatcher]:
    return load_bundled_scene("home"), MotionMatcher(load_databases(cache_dir=motion_cache_dir()))


def _world(home: tuple[Scene, MotionMatcher]) -> World:
    scene, motion = home
    positions = start_positions(scene, len(NAMES), 0)
    return World(scene, {n: (p, 0.0) for n, p in zip(NAMES, positions, strict=True)}, motion, config=WorldConfig())


def _errands(world: World, index: int) -> list[AssignEvent]:
    """Send both characters to far free cells to act there (a new event every call)."""
    grid = world.grid
    cells = np.argwhere(grid.component == grid.main_component)
    out = []
    for k, name in enumerate(world.names):
        i, j = cells[(index * 97 + k * 211) % len(cells)]
        c = grid.center_of(int(i), int(j))
        action = ("drink", "idle")[k % 2]
        out.append(AssignEvent(event_id=f"e{index}-{name}", assignments=(
            Assignment(character=name, action=action, target_xy=(float(c[0]), float(c[1])), facing_xy=(1.0, 0.0)),)))
    return out


def _run(world: World, start: int, stop: int) -> None:
    """Frames [start, stop): new errands every 200 frames."""
    for f in range(start, stop):
        commands = _errands(world, f // 200) if f % 200 == 0 else []
        step(world, commands, world.dt)


def test_a_streaming_world_exports_the_same_files_and_holds_one_window(
    home: tuple[Scene, MotionMatcher], tmp_path: Path
) -> None:
    frames = 10 * WINDOW + 17
    whole = _world(home)
    _run(whole, 0, frames)
    streamed = _world(home)
    store = ChunkStore.open(tmp_path / "motion", NAMES)
    streamed.stream_tracks(store, WINDOW)
    capacity = streamed.buffers.capacity
    held = []
    for f in range(frames):
        _run(streamed, f, f + 1)
        held.append(streamed.buffers.held)
    assert max(held) == WINDOW and streamed.buffers.capacity == capacity  # never grew
    assert store.frames == streamed.buffers.base == frames - held[-1] > 0
    labels = {s for t in whole.tracks().values() for s in t.action_labels or ()}
    assert {"walk", "idle"} <= labels and any(e for ids in whole.event_ids().values() for e in ids)

    a = export_run(tmp_path / "memory", whole.scene, list(whole.tracks().values()))
    b = export_run(tmp_path / "chunks", streamed.scene, list(streamed.tracks().values()))
    for pa, pb in zip(a.all_paths(), b.all_paths(), strict=True):
        assert pa.name == pb.name and pa.read_bytes() == pb.read_bytes(), pa.name
    assert whole.event_ids() == streamed.event_ids()
    for name in NAMES:
        assert np.array_equal(whole.foot_contacts()[name], streamed.foot_contacts()[name])


def test_the_snapshot_holds_the_window_and_a_restore_goes_on_from_it(
    home: tuple[Scene, MotionMatcher], tmp_path: Path
) -> None:
    frames = 8 * WINDOW
    whole = _world(home)
    _run(whole, 0, frames)

    world = _world(home)
    store = ChunkStore.open(tmp_path / "motion", NAMES)
    world.stream_tracks(store, WINDOW)
    _run(world, 0, 3 * WINDOW + 5)
    early = world.snapshot()
    _run(world, 3 * WINDOW + 5, 5 * WINDOW + 5)
    snap = world.snapshot()
    assert snap.buffers.base == 5 * WINDOW and snap.buffers.held == 5
    # motion is not in the snapshot: its frames part does not grow with the story
    assert len(pickle.dumps(snap.buffers)) < len(pickle.dumps(early.buffers)) + 1024
    window_bytes = len(NAMES) * WINDOW * (3 * 8 + 22 * 9 * 4)
    assert len(pickle.dumps(snap)) - len(pickle.dumps(early)) < window_bytes
    with pytest.raises(TypeError):
        pickle.dumps(store)

    _run(world, 5 * WINDOW + 5, 7 * WINDOW)  # more frames streamed, then "killed": back to the snapshot
    assert store.frames > snap.buffers.base
    store.close()
    reopened = ChunkStore.open(tmp_path / "motion", NAMES, frames=snap.buffers.base)
    again = _world(home).restore(snap, store=reopened)
    assert again.frame == 5 * WINDOW + 5 and reopened.frames == 5 * WINDOW
    _run(again, again.frame, frames)
    for name in NAMES:
        t, u = whole.tracks()[name], again.tracks()[name]
        assert np.array_equal(t.root_positions, u.root_positions)
        assert np.array_equal(t.local_rotations, u.local_rotations)
        assert t.action_labels == u.action_labels

    with pytest.raises(WorldError, match="chunk files"):
        _world(home).restore(snap)  # the first frames are on disk, and this world has no store


def test_a_torn_last_record_is_dropped_and_a_bad_middle_one_refused(
    home: tuple[Scene, MotionMatcher], tmp_path: Path
) -> None:
    world = _world(home)
    store = ChunkStore.open(tmp_path / "motion", NAMES)
    world.stream_tracks(store, WINDOW)
    _run(world, 0, 3 * WINDOW + 1)  # three records per file
    store.close()
    path = store.path("Ava")
    whole = path.read_bytes()
    found = scan(path)
    assert found.frames == 3 * WINDOW and found.torn == 0 and len(found.records) == 3

    path.write_bytes(whole[: found.records[2][0] + HEADER_BYTES + 100])  # killed inside the third write
    torn = scan(path)
    assert torn.frames == 2 * WINDOW and torn.torn == HEADER_BYTES + 100
    assert read_frames(path).count == 2 * WINDOW  # readers ignore the torn tail
    with pytest.raises(ChunkError, match="holds 128 whole frames"):
        ChunkStore.open(tmp_path / "motion", NAMES, frames=3 * WINDOW)
    reopened = ChunkStore.open(tmp_path / "motion", NAMES, frames=2 * WINDOW)
    reopened.close()
    assert path.stat().st_size == found.records[2][0] and scan(store.path("Ben")).frames == 2 * WINDOW

    broken = bytearray(whole)
    broken[found.records[1][0] + HEADER_BYTES + 7] ^= 0xFF  # a flipped bit in the middle record
    path.write_bytes(bytes(broken))
    with pytest.raises(ChunkError, match="fails its CRC"):
        scan(path)


# ----- the GIF recorder streams ---------------------------------------------------------------
def test_the_gif_is_written_picture_by_picture_and_shows_the_same_pictures(tmp_path: Path) -> None:
    import imageio.v3 as iio

    from storyteller.benchmark.support.random_tracks import wandering_story
    from storyteller.sim.export.video import _write_gif, iter_animation_frames
    from storyteller.sim.paths.nav_grid import build_nav_grid

    scene = load_bundled_scene("office")
    rec = wandering_story(scene, build_nav_grid(scene), characters=3, seconds=4.0, seed=3)
    pictures = list(iter_animation_frames(rec, stride=10, size_px=240))
    path = tmp_path / "new.gif"
    sizes: list[int] = []

    def produced() -> Iterator[np.ndarray]:
        for picture in pictures:
            sizes.append(path.stat().st_size if path.exists() else 0)
            yield picture

    _write_gif(path, produced(), duration_ms=1000.0 / 3)
    assert all(b > a for a, b in pairwise(sizes))  # each picture on disk before the next
    iio.imwrite(tmp_path / "old.gif", np.stack(pictures), extension=".gif", duration=1000.0 / 3, loop=0)
    assert np.array_equal(iio.imread(path, index=None), iio.imread(tmp_path / "old.gif", index=None))


# ----- the viewer reads streamed motion --------------------------------------------------------
def test_the_viewer_shows_a_run_stopped_before_its_exports_from_its_chunks(
    home: tuple[Scene, MotionMatcher], tmp_path: Path
) -> None:
    import json

    from storyteller.orchestrator.viewer.run_folder import folder_stamp, load_run

    world = _world(home)
    store = ChunkStore.open(tmp_path / "motion", NAMES)
    world.stream_tracks(store, WINDOW)
    _run(world, 0, 2 * WINDOW + 3)
    story = {"scene": "home", "characters": list(NAMES), "fps": 30, "events": [], "instruction": ""}
    (tmp_path / "story.json").write_text(json.dumps(story), encoding="utf-8")
    before = folder_stamp(tmp_path)
    run = load_run(tmp_path)
    assert [t.name for t in run.tracks] == list(NAMES)
    for t in run.tracks:  # the whole records: the frames still in memory are not on disk yet
        assert np.array_equal(t.local_rotations, world.track(t.name).local_rotations[: 2 * WINDOW])
    _run(world, 2 * WINDOW + 3, 3 * WINDOW + 1)
    assert folder_stamp(tmp_path) != before  # a watching viewer reloads as the chunks grow


def test_a_resume_cuts_no_chunk_file_when_one_of_them_is_refused(
    home: tuple[Scene, MotionMatcher], tmp_path: Path
) -> None:
    """Every file is checked before any is cut (the second hostile corpus: a refused resume had
    changed the run folder); :func:`check_resumable` is that check, writing nothing."""
    world = _world(home)
    store = ChunkStore.open(tmp_path / "motion", NAMES)
    world.stream_tracks(store, WINDOW)
    _run(world, 0, 3 * WINDOW + 1)
    store.close()
    ava, ben = store.path("Ava"), store.path("Ben")
    whole = ava.read_bytes()
    broken = bytearray(ben.read_bytes())
    broken[scan(ben).records[1][0] + HEADER_BYTES + 7] ^= 0xFF  # Ben's middle record fails its CRC
    ben.write_bytes(bytes(broken))
    with pytest.raises(ChunkError, match="fails its CRC"):
        check_resumable(tmp_path / "motion", NAMES, 2 * WINDOW)
    with pytest.raises(ChunkError, match="fails its CRC"):
        ChunkStore.open(tmp_path / "motion", NAMES, frames=2 * WINDOW)
    assert ava.read_bytes() == whole  # Ava's third record was not cut for a resume that was refused

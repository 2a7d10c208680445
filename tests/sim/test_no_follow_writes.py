"""The writers of a run folder never write through a symbolic link (``storyteller.sim.no_follow_writes``).

A file written whole replaces a link at its name (the link's target untouched) and leaves no
temporary file; an append-only file (trace, story stream, chunk file) that is a link, a FIFO or
a hard-linked file is refused with an ``OSError`` naming it, before anything is read, cut or
written; a sub-folder that is a link is refused. Each exporter a run uses is checked with a
link planted at its file.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from storyteller.benchmark.support.random_tracks import random_track
from storyteller.orchestrator.llm.trace_writer import TraceWriter
from storyteller.orchestrator.session.run_manifest import RunArguments, RunManifest, write_manifest
from storyteller.orchestrator.session.story_stream import StoryStream
from storyteller.sim.export.bundle import export_run
from storyteller.sim.export.video import RunRecording, save_run_animation, save_run_png
from storyteller.sim.no_follow_writes import make_folder, open_append, replacing, write_file
from storyteller.sim.scene.bundled import resolve_scene
from storyteller.sim.world.track_chunks import ChunkStore

PRECIOUS = b"precious: not ours to write\n"


@pytest.fixture
def victim(tmp_path: Path) -> Path:
    path = tmp_path / "elsewhere" / "victim.txt"
    path.parent.mkdir()
    path.write_bytes(PRECIOUS)
    return path


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    path = tmp_path / "run"
    path.mkdir()
    return path


def link(path: Path, target: Path) -> Path:
    path.symlink_to(target)
    return path


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_write_file_replaces_a_link_not_its_target(folder: Path, victim: Path) -> None:
    path = link(folder / "story.md", victim)
    write_file(path, b"the story\n")
    assert victim.read_bytes() == PRECIOUS
    assert not path.is_symlink() and path.read_bytes() == b"the story\n"
    assert leftovers(folder) == []


def test_write_file_over_a_folder_fails_naming_the_file_and_leaves_nothing(folder: Path) -> None:
    (folder / "story.md").mkdir()
    with pytest.raises(OSError) as caught:
        write_file(folder / "story.md", b"x", durable=True)
    assert caught.value.filename == str(folder / "story.md")
    assert leftovers(folder) == []


def test_a_link_planted_at_a_temporary_name_is_never_written(folder: Path, victim: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    tokens = iter(["aaaaaaaaaaaa", "bbbbbbbbbbbb"])
    monkeypatch.setattr("storyteller.sim.no_follow_writes.secrets.token_hex", lambda _n: next(tokens))
    link(folder / ".run.json.aaaaaaaaaaaa.tmp.json", victim)  # the first name tried is taken by a link
    write_file(folder / "run.json", b"{}\n")
    assert victim.read_bytes() == PRECIOUS and (folder / "run.json").read_bytes() == b"{}\n"


def test_replacing_keeps_the_suffix_and_cleans_up_after_an_error(folder: Path, victim: Path) -> None:
    path = link(folder / "story.mp4", victim)
    with replacing(path) as fresh:
        assert fresh.parent == folder and fresh.suffix == ".mp4" and fresh.is_file() and not fresh.is_symlink()
        fresh.write_bytes(b"video")
    assert victim.read_bytes() == PRECIOUS and path.read_bytes() == b"video"
    with pytest.raises(RuntimeError), replacing(folder / "story.gif"):
        raise RuntimeError("the encoder failed")
    assert not (folder / "story.gif").exists() and leftovers(folder) == []


def test_open_append_refuses_a_link(folder: Path, victim: Path) -> None:
    path = link(folder / "trace.jsonl", victim)
    with pytest.raises(OSError, match="symbolic link") as caught:
        open_append(path)
    assert caught.value.errno == errno.ELOOP and caught.value.filename == str(path)
    assert victim.read_bytes() == PRECIOUS


def test_open_append_refuses_a_fifo_without_hanging(folder: Path) -> None:
    os.mkfifo(folder / "story.jsonl")
    with pytest.raises(OSError, match="not a regular file"):
        open_append(folder / "story.jsonl")


def test_open_append_refuses_a_hard_linked_file(folder: Path, victim: Path) -> None:
    os.link(victim, folder / "trace.jsonl")
    with pytest.raises(OSError, match="2 hard links"):
        open_append(folder / "trace.jsonl")
    assert victim.read_bytes() == PRECIOUS


def test_open_append_appends_to_a_regular_file(folder: Path) -> None:
    (folder / "trace.jsonl").write_bytes(b"one\n")
    fd = open_append(folder / "trace.jsonl")
    try:
        assert os.get_blocking(fd)
        os.write(fd, b"two\n")
    finally:
        os.close(fd)
    assert (folder / "trace.jsonl").read_bytes() == b"one\ntwo\n"


def test_make_folder_refuses_a_link(folder: Path, tmp_path: Path) -> None:
    (tmp_path / "other").mkdir()
    link(folder / "motion", tmp_path / "other")
    with pytest.raises(OSError, match="symbolic link"):
        make_folder(folder / "motion")
    assert make_folder(folder / "fresh" / "motion").is_dir()


def test_the_trace_writer_refuses_a_link_before_reading_or_cutting_it(folder: Path, victim: Path) -> None:
    victim.write_bytes(b'{"kind": "run", "seq": 0, "run_id": "x", "time_unix": 0, "meta": {}}\n{"cut')
    before = victim.read_bytes()
    with pytest.raises(OSError, match="symbolic link"):
        TraceWriter(link(folder / "trace.jsonl", victim), fsync="never")
    assert victim.read_bytes() == before  # its torn tail was not cut off through the link


def test_the_story_stream_refuses_a_link(folder: Path, victim: Path) -> None:
    link(folder / "story.jsonl", victim)
    with pytest.raises(OSError, match="symbolic link"):
        StoryStream(folder)
    assert victim.read_bytes() == PRECIOUS


@pytest.mark.parametrize("planted", ["motion", "motion/Zoe.chunks"])
def test_the_chunk_store_refuses_links(folder: Path, victim: Path, planted: str) -> None:
    if planted == "motion":
        link(folder / "motion", victim.parent)
        (victim.parent / "Zoe.chunks").write_bytes(PRECIOUS)
    else:
        (folder / "motion").mkdir()
        link(folder / planted, victim)
    with pytest.raises(OSError, match="symbolic link"):
        ChunkStore.open(folder / "motion", ["Zoe", "Max"])  # a new store would empty every file
    assert victim.read_bytes() == PRECIOUS
    if planted == "motion":
        assert (victim.parent / "Zoe.chunks").read_bytes() == PRECIOUS


def test_the_manifest_replaces_a_link(folder: Path, victim: Path) -> None:
    link(folder / "run.json", victim)
    args = RunArguments(scene="home", names=("Zoe",), duration=1.0)
    write_manifest(folder, RunManifest(thread_id="t", scene_name="home", seed=0, config=None, arguments=args))
    assert victim.read_bytes() == PRECIOUS
    assert not (folder / "run.json").is_symlink() and b'"thread_id": "t"' in (folder / "run.json").read_bytes()
    assert leftovers(folder) == []


def test_the_exports_and_pictures_replace_links(folder: Path, victim: Path) -> None:
    names = ["scene.glb", "Zoe.bvh", "Zoe.smplx.npz", "Zoe.track.npz", "topdown.png", "story.gif"]
    for name in names:
        link(folder / name, victim)
    scene = resolve_scene("home")
    track = random_track("Zoe", 40, seed=1)
    export_run(folder, scene, [track])
    recording = RunRecording(scene, {"Zoe": track})
    save_run_png(folder / "topdown.png", recording, size_px=200)
    save_run_animation(folder / "story.gif", recording, stride=20, size_px=200)
    assert victim.read_bytes() == PRECIOUS
    for name in names:
        assert not (folder / name).is_symlink() and (folder / name).stat().st_size > 0, name
    assert leftovers(folder) == []


def test_stale_temporaries_are_removed_and_nothing_else(tmp_path: Path) -> None:
    from storyteller.sim.no_follow_writes import remove_stale_temporaries

    victim = tmp_path / "victim"
    victim.write_text("v", encoding="utf-8")
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / ".story.md.0123456789ab.tmp.md").write_text("x", encoding="utf-8")
    (folder / ".scene.glb.00000000000f.tmp.glb").symlink_to(victim)
    (folder / ".x.0123456789ab.tmp").mkdir()  # a folder of such a name stays
    keep = [".story.md.0123.tmp.md", "story.md.tmp", ".story.md.0123456789ab.tmp.md.bak", "a.tmp"]
    for name in keep:
        (folder / name).write_text("k", encoding="utf-8")
    assert sorted(remove_stale_temporaries(folder)) == [".scene.glb.00000000000f.tmp.glb", ".story.md.0123456789ab.tmp.md"]
    assert sorted(p.name for p in folder.iterdir()) == sorted([*keep, ".x.0123456789ab.tmp"])
    assert victim.read_text(encoding="utf-8") == "v"
    assert remove_stale_temporaries(tmp_path / "missing") == []

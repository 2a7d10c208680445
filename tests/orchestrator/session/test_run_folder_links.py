"""A run folder is a sandbox for writing: a symbolic link planted in it is never written through.

One short run (fake OpenAI server on 127.0.0.1, as in ``tests/orchestrator/session/test_run_corrupt_files.py``) makes
a folder; each test copies it and plants a link at a name the run writes, pointing at a file
(or folder) outside the run folder. The real file is moved out to be the link's target, so a
command that followed the link would read a sound run and write through it, as the old code
did (``story.md``, ``metrics.json``, ``topdown.png``, a BVH and ``scene.glb`` overwritten,
``trace.jsonl`` appended to, exit 0). ``storyteller resume``, ``replay --out`` and ``run --out``
now refuse such a folder: exit code 2, one ``error:`` line naming the link, the target
byte for byte as it was. Without the check (``write_outputs`` called directly) the writers
replace a planted link and leave its target alone.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, cast

import pytest
from typer.testing import CliRunner

from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.session.run_folder_links import PlantedLinkError, refuse_planted_links
from storyteller.sim.run_folder_names import run_folder_entries
from storyteller.sim.world.character_track import CharacterTrack
from tests.support.finished_run import one_error_line
from tests.support.story_planner import RUN, Planner, write_config

if TYPE_CHECKING:
    from storyteller.sim.world.step import World

NAMES = ("Zoe", "Max")  # the characters of ``RUN``

PLANTED = [
    "story.md", "metrics.json", "topdown.png", "Zoe.bvh", "scene.glb", "trace.jsonl", "story.jsonl", "story.json",
    "run.json", "scene.json", "motion", "motion/Zoe.chunks", "session.snapshot", "runs.sqlite", "Max.smplx.npz",
    "Zoe.track.npz", "runs.sqlite-wal", "story.gif",
]
"""Names a run writes (every one a finished run holds, and two it holds only at times)."""


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    tmp = tmp_path_factory.mktemp("finished")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FAKE_PROVIDER_KEY", "sk-test-123")
        for var in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL"):
            mp.delenv(var, raising=False)
        with FakeOpenAI(responder=Planner()) as fake:
            cfg = write_config(tmp, fake.base)
            result = CliRunner().invoke(app, [*RUN, "-d", "3", "--max-events", "2", "--config", str(cfg),
                                              "--out", str(tmp / "run")])
            assert result.exit_code == 0, result.stderr
        yield tmp / "run"



def fingerprint(path: Path) -> dict[str, str]:
    """Relative path -> sha256 of every file at or under ``path`` (a folder's listing counts)."""
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    return {str(p.relative_to(path) if path.is_dir() else p.name): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in files}


def plant(run_dir: Path, entry: str, outside: Path) -> Path:
    """Move ``run_dir/entry`` out to ``outside`` (or make a file there when the run has none)
    and put a symbolic link to it in its place; returns the link's target."""
    target = outside / entry.replace("/", "_")
    outside.mkdir(parents=True, exist_ok=True)
    here = run_dir / entry
    if here.exists():
        shutil.move(str(here), str(target))
    else:
        target.write_bytes(b"precious: not the run's to write\n")
    here.symlink_to(target, target_is_directory=target.is_dir())
    return target


def test_every_planted_name_is_one_the_run_writes() -> None:
    entries = set(run_folder_entries(NAMES))
    assert set(PLANTED) <= entries
    assert {"session.snapshot.tmp", "runs.sqlite-journal", "runs.sqlite-shm", "story.mp4", "Max.bvh",
            "motion/Max.chunks"} <= entries


@pytest.mark.parametrize("entry", PLANTED)
def test_resume_refuses_a_planted_link_and_leaves_its_target_alone(run_dir: Path, tmp_path: Path, entry: str) -> None:
    target = plant(run_dir, entry, tmp_path / "outside")
    before = fingerprint(target)
    result = CliRunner().invoke(app, ["resume", str(run_dir), "--no-interactive"])
    line = one_error_line(result, "symbolic link")
    assert entry in line or entry.split("/")[-1] in line
    assert fingerprint(target) == before
    assert (run_dir / entry).is_symlink()  # not replaced either: the folder was refused whole


@pytest.mark.parametrize("entry", ["story.md", "trace.jsonl", "motion", "Zoe.bvh"])
def test_replay_into_a_folder_with_a_planted_link_is_refused(
    run_dir: Path, finished_run: Path, tmp_path: Path, entry: str
) -> None:
    out = tmp_path / "again"
    out.mkdir()
    (out / "motion").mkdir()  # a chunk file's link needs its folder
    target = plant(out, entry, tmp_path / "outside")
    before = fingerprint(target)
    result = CliRunner().invoke(app, ["replay", str(run_dir), "--out", str(out)])
    one_error_line(result, f"{out}: run folder holds a symbolic link at {entry}; refusing to write through it")
    assert fingerprint(target) == before


def test_run_into_a_folder_with_a_planted_link_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    target = plant(out, "story.md", tmp_path / "outside")
    result = CliRunner().invoke(app, [*RUN, "-d", "3", "--out", str(out)])  # refused before any model is opened
    one_error_line(result, f"{out}: run folder holds a symbolic link at story.md")
    assert target.read_bytes() == b"precious: not the run's to write\n"
    assert sorted(p.name for p in out.iterdir()) == ["story.md"]  # nothing written


@pytest.mark.parametrize("command", ["run", "resume", "replay"])
def test_a_run_folder_that_is_a_link_is_refused(run_dir: Path, tmp_path: Path, command: str) -> None:
    elsewhere = tmp_path / "elsewhere"
    shutil.move(str(run_dir), str(elsewhere))
    link = tmp_path / "linked"
    link.symlink_to(elsewhere, target_is_directory=True)
    before = fingerprint(elsewhere)
    args = {
        "run": [*RUN, "-d", "3", "--out", str(link)],
        "resume": ["resume", str(link), "--no-interactive"],
        "replay": ["replay", str(elsewhere), "--out", str(link)],
    }[command]
    if command == "replay":  # replaying a run into another folder that is a link (to an empty one)
        empty = tmp_path / "empty"
        empty.mkdir()
        link.unlink()
        link.symlink_to(empty, target_is_directory=True)
    result = CliRunner().invoke(app, args)
    one_error_line(result, f"{link}: the run folder is a symbolic link; refusing to write through it")
    assert fingerprint(elsewhere) == before
    if command == "replay":
        assert not any((tmp_path / "empty").iterdir())


def test_a_hard_linked_trace_is_refused(run_dir: Path, tmp_path: Path) -> None:
    outside = tmp_path / "outside.jsonl"
    os.link(run_dir / "trace.jsonl", outside)  # appending would change the file out there too
    before = outside.read_bytes()
    result = CliRunner().invoke(app, ["resume", str(run_dir), "--no-interactive"])
    one_error_line(result, "trace.jsonl in the run folder has 2 hard links")
    assert outside.read_bytes() == before


def test_the_check_passes_a_folder_that_does_not_exist_yet_and_a_clean_one(finished_run: Path, tmp_path: Path) -> None:
    refuse_planted_links(tmp_path / "new", NAMES)
    refuse_planted_links(finished_run, NAMES)
    (tmp_path / "new").mkdir()
    (tmp_path / "new" / "story.jsonl").mkdir()  # an appended file must be a regular file
    with pytest.raises(PlantedLinkError, match=r"story\.jsonl in the run folder is not a regular file"):
        refuse_planted_links(tmp_path / "new", NAMES)


def test_without_the_check_the_outputs_replace_planted_links(run_dir: Path, tmp_path: Path) -> None:
    """``write_outputs`` (what a run ends with; the API, no folder check): every file it writes
    replaces a link planted at its name, and the link's target is untouched."""
    from storyteller.orchestrator.session.run_outputs import write_outputs
    from storyteller.orchestrator.session.session_types import SessionResult
    from storyteller.sim.scene.bundled import resolve_scene
    from storyteller.sim.world.track_chunks import chunked_track

    names = list(NAMES)
    tracks = {}
    for n in names:
        track = chunked_track(run_dir / "motion" / f"{n}.chunks", n)
        assert track is not None
        tracks[n] = track
    frames = tracks["Zoe"].num_frames

    class Finished:  # what write_outputs reads of a world
        grid = None

        def tracks(self) -> dict[str, CharacterTrack]:
            return dict(tracks)

        def event_ids(self) -> dict[str, list[str]]:
            return {n: [""] * frames for n in names}

    written = ["story.json", "story.md", "metrics.json", "scene.json", "scene.glb", "topdown.png", "Zoe.bvh",
               "Max.smplx.npz", "Zoe.track.npz", "story.gif"]
    targets = {entry: plant(run_dir, entry, tmp_path / "outside") for entry in written}
    before = {entry: fingerprint(t) for entry, t in targets.items()}
    result = SessionResult(frames=frames, steps=0, events=[], outcomes=[], applied_frames=[])
    world = cast("World", Finished())  # a stand-in with the parts write_outputs reads
    write_outputs(run_dir, resolve_scene("home"), world, result, names, "", 30, gif=True)
    for entry, target in targets.items():
        assert fingerprint(target) == before[entry], entry
        assert not (run_dir / entry).is_symlink() and (run_dir / entry).stat().st_size > 0, entry
    assert not [p.name for p in run_dir.iterdir() if p.name.startswith(".")]  # no temporary file left

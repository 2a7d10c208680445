"""A run folder saved before the one installed name (issue 26) still resumes: its
``session.snapshot`` names classes by the old module paths (``sim.world.step.WorldSnapshot``,
``orchestrator.session.snapshot_file._array``) and loads as the same classes under
``storyteller.``, without importing any module a second time under its old name.

``tests/data/snapshots/old_module_names.snapshot`` was written by main at c842af8 (before the
rename): the home scene, Ava and Ben, 12 frames, as the ``checkpoint`` fixture of
test_snapshot_file.py makes it.
"""

# ns-rewrite: skip-file (this file names the old module paths on purpose; the namespace rewrite
# script of issue 26 leaves it alone)
from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from storyteller.orchestrator.session.session_types import SessionCheckpoint
from storyteller.orchestrator.session.snapshot_errors import SnapshotError
from storyteller.orchestrator.session.snapshot_file import current_module_name, load_checkpoint
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.step import World, WorldSnapshot
from tests.support.namespace_guard import second_names

OLD = Path(__file__).resolve().parents[2] / "data" / "snapshots" / "old_module_names.snapshot"


def test_the_file_names_the_old_modules() -> None:
    data = OLD.read_bytes()
    modules = set(re.findall(rb"(?:sim|orchestrator)\.[a-z_.]+", data))
    assert {b"sim.world.step", b"orchestrator.session.session_types", b"orchestrator.session.snapshot_file"} <= modules
    assert b"storyteller." not in data


def test_an_old_snapshot_resumes_under_the_new_names(home: Scene, motion: MotionMatcher, tmp_path: Path) -> None:
    path = tmp_path / "session.snapshot"
    shutil.copyfile(OLD, path)
    world = World(home, {"Ava": ((1.0, 1.0), 0.0), "Ben": ((2.5, 1.0), 0.0)}, motion)
    loaded = load_checkpoint(path, world)
    assert type(loaded) is SessionCheckpoint
    assert type(loaded.world) is WorldSnapshot
    assert loaded.world.frame == 12
    assert loaded.world.buffers.pelvis.shape[0] >= 12
    assert second_names() == []


@pytest.mark.parametrize(("old", "new"), [
    ("sim.world.step", "storyteller.sim.world.step"),
    ("orchestrator.session.snapshot_file", "storyteller.orchestrator.session.snapshot_file"),
    ("storyteller.sim.world.step", "storyteller.sim.world.step"),
    ("builtins", "builtins"),
    ("sim", "sim"),  # a bare folder name is no module a checkpoint holds: left to be refused
    ("os.path", "os.path"),
])
def test_old_names_map_to_new_ones(old: str, new: str) -> None:
    assert current_module_name(old) == new


def test_an_old_name_of_an_unlisted_class_is_still_refused(home: Scene, motion: MotionMatcher, tmp_path: Path) -> None:
    data = OLD.read_bytes()
    # same length, so the pickle stays well formed: a listed class swapped for an unlisted one
    forged = data.replace(b"sim.world.step", b"sim.world.fake", 1)
    assert forged != data
    header, _, payload = forged.partition(b"\n")
    import hashlib

    path = tmp_path / "session.snapshot"
    path.write_bytes(header.split(b"sha256=")[0] + b"sha256=" + hashlib.sha256(payload).hexdigest().encode() + b"\n" + payload)
    world = World(home, {"Ava": ((1.0, 1.0), 0.0), "Ben": ((2.5, 1.0), 0.0)}, motion)
    with pytest.raises(SnapshotError, match=r"storyteller\.sim\.world\.fake\.WorldSnapshot"):
        load_checkpoint(path, world)

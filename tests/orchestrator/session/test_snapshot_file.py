"""``session.snapshot`` runs no code from the file, and a damaged one is one clear error.

Hostile snapshots are made with a valid header and checksum (so the checksum is not what stops
them): a payload calling ``os.system`` / ``subprocess`` / ``eval`` / a project function, an
object of a project class that is not listed, arrays whose shape asks for terabytes, nesting a
hundred thousand deep, a cycle, a dict key that would take the C stack to hash. Each would
create a marker file if its code ran: the marker must not exist. A real checkpoint still
round-trips.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import pickle
import pickletools
import subprocess
from pathlib import Path
from typing import Any, cast

import numpy as np
import pytest
from pydantic import BaseModel

from storyteller.orchestrator.planning.state import StepProgress
from storyteller.orchestrator.session import snapshot_file
from storyteller.orchestrator.session.runtime import Session
from storyteller.orchestrator.session.session_types import PlanningRequest, SessionCheckpoint, SessionSettings
from storyteller.orchestrator.session.snapshot_errors import SnapshotError
from storyteller.orchestrator.session.snapshot_file import (
    SNAPSHOT_CLASSES,
    load_checkpoint,
    save_checkpoint,
    shared_names,
)
from storyteller.sim.motion.matching import MotionMatcher
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.step import World, step


def _world(home: Scene, motion: MotionMatcher) -> World:
    return World(home, {"Ava": ((1.0, 1.0), 0.0), "Ben": ((2.5, 1.0), 0.0)}, motion)


class _Waits:
    async def plan(self, request: PlanningRequest, progress: StepProgress | None = None) -> None:
        return None


@pytest.fixture(scope="module")
def checkpoint(home: Scene, motion: MotionMatcher) -> tuple[World, SessionCheckpoint]:
    world = _world(home, motion)
    session = Session(world, _Waits(), SessionSettings(frames=20))
    while session.world.frame < 12:
        session.world, _ = step(session.world, [], session.world.dt)
    return session.world, session.checkpoint()


def header(payload: bytes, fmt: int = snapshot_file._FORMAT) -> bytes:
    return b"storyteller-snapshot %d sha256=%s\n" % (fmt, hashlib.sha256(payload).hexdigest().encode())


def write_snapshot(path: Path, payload: bytes) -> Path:
    path.write_bytes(header(payload) + payload)
    return path


def real_payload(world: World, cp: SessionCheckpoint) -> bytes:
    """The pickle of ``cp`` as the writer makes it, without frames (so opcodes can be spliced in)."""
    import io

    buf = io.BytesIO()
    snapshot_file._Pickler(buf, shared_names(world)).dump(cp)
    data = buf.getvalue()
    cuts = [(pos, pos + 9) for op, _, pos in pickletools.genops(data) if op.name == "FRAME" and pos is not None]
    for start, end in reversed(cuts):
        data = data[:start] + data[end:]
    return data


def spliced(world: World, cp: SessionCheckpoint, opcodes: bytes) -> bytes:
    """A real checkpoint's pickle with its ``instruction`` field's value replaced by ``opcodes``."""
    sentinel = "SENTINEL_INSTRUCTION"
    data = real_payload(world, dataclasses.replace(cp, instruction=sentinel))
    needle = b"\x8c" + bytes([len(sentinel)]) + sentinel.encode()
    assert data.count(needle) == 1
    return data.replace(needle, opcodes)


def test_a_real_checkpoint_round_trips(checkpoint: tuple[World, SessionCheckpoint], home: Scene,
                                       motion: MotionMatcher, tmp_path: Path) -> None:
    world, cp = checkpoint
    path = tmp_path / "session.snapshot"
    save_checkpoint(path, world, cp)
    assert path.read_bytes().startswith(b"storyteller-snapshot %d sha256=" % snapshot_file._FORMAT)
    loaded = load_checkpoint(path, _world(home, motion))
    assert loaded.world.frame == cp.world.frame == 12
    assert np.array_equal(loaded.world.buffers.pelvis, cp.world.buffers.pelvis)
    assert loaded.world.buffers.pelvis.flags.writeable
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left


def test_the_spliced_payload_is_still_a_checkpoint(checkpoint: tuple[World, SessionCheckpoint], home: Scene,
                                                   motion: MotionMatcher, tmp_path: Path) -> None:
    """The splicing the hostile cases use keeps a loadable checkpoint when it splices a plain string."""
    world, cp = checkpoint
    path = write_snapshot(tmp_path / "session.snapshot", spliced(world, cp, b"\x8c\x05hello"))
    assert load_checkpoint(path, _world(home, motion)).instruction == "hello"


class _Call:
    """Pickles as a call of ``func(*args)`` (what a crafted snapshot does)."""

    def __init__(self, func: Any, *args: Any) -> None:
        self.func, self.args = func, args

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        return self.func, self.args


def _calls(marker: Path) -> dict[str, _Call]:
    touch = f"touch {marker}"
    return {
        "os.system": _Call(os.system, touch),
        "subprocess.Popen": _Call(subprocess.Popen, ["touch", str(marker)]),
        "subprocess.check_call": _Call(subprocess.check_call, ["touch", str(marker)]),
        "builtins.eval": _Call(eval, f"open({str(marker)!r}, 'w')"),
        "builtins.exec": _Call(exec, f"open({str(marker)!r}, 'w')"),
        "pathlib.Path.touch": _Call(Path.touch, marker),
        "a project function": _Call(snapshot_file.write_checkpoint, marker, None, {}, None),
        "a project class method": _Call(snapshot_file.__dict__["ChunkStore"].open, marker.parent / "motion", ["x"]),
    }


@pytest.mark.parametrize("name", list(_calls(Path("m"))))
@pytest.mark.parametrize("where", ["whole file", "inside a real checkpoint"])
def test_a_crafted_call_is_refused_and_never_runs(checkpoint: tuple[World, SessionCheckpoint], home: Scene,
                                                  motion: MotionMatcher, tmp_path: Path, name: str, where: str) -> None:
    world, cp = checkpoint
    marker = tmp_path / "PWNED"
    evil = _calls(marker)[name]
    if where == "whole file":
        payload = pickle.dumps(evil, protocol=2)
    else:
        payload = real_payload(world, dataclasses.replace(cp, instruction=cast(str, evil)))  # not a str on purpose: the check refuses it
    path = write_snapshot(tmp_path / "session.snapshot", payload)
    with pytest.raises(SnapshotError) as exc:
        load_checkpoint(path, _world(home, motion))
    assert str(path) in str(exc.value) and "\n" not in str(exc.value)
    assert not marker.exists()
    assert not (tmp_path / "motion").exists()


def test_a_class_that_is_not_listed_is_refused(checkpoint: tuple[World, SessionCheckpoint], home: Scene,
                                               motion: MotionMatcher, tmp_path: Path) -> None:
    from storyteller.sim.world.events import ReleaseCharacters

    world, cp = checkpoint
    assert ("storyteller.sim.world.events", "ReleaseCharacters") not in SNAPSHOT_CLASSES
    payload = real_payload(world, dataclasses.replace(cp, instruction=cast(str, ReleaseCharacters(characters=("Ava",)))))  # not a str on purpose
    path = write_snapshot(tmp_path / "session.snapshot", payload)
    with pytest.raises(SnapshotError, match=r"sim\.world\.events\.ReleaseCharacters, which a checkpoint may not hold"):
        load_checkpoint(path, _world(home, motion))


@pytest.mark.parametrize(
    ("opcodes", "needle"),
    [
        # protocol 0 INST: os.system('touch ...') by class-instantiation instead of REDUCE
        (b"(S'touch PWNED'\nios\nsystem\n", "instruction a checkpoint never has"),
        # a listed class called through REDUCE (its constructor would run)
        (b"csim.world.tracks\nTrackBuffers\n(K\x01K\x01tR", "other than its array decoders"),
        # an array whose shape asks for 8 TB from 8 bytes
        (b"corchestrator.session.snapshot_file\n_array\n(C\x08\x00\x00\x00\x00\x00\x00\x00\x00"
         b"\x8c\x03<f8\x8a\x06\x00\x00\x00\x00\x00\x01\x85tR", "malformed shape"),
        (b"corchestrator.session.snapshot_file\n_array\n(C\x08\x00\x00\x00\x00\x00\x00\x00\x00"
         b"\x8c\x03<f8K\x02K\x03\x86tR", "does not fit its 8 bytes"),
        (b"corchestrator.session.snapshot_file\n_array\n(C\x00\x8c\x01O)tR", "only plain numeric arrays"),
        # a list nested 100,000 deep (made with the stack, not recursion)
        (b"]" * 100_000 + b"a" * 99_999, "more than 48 levels deep"),
        # a list that holds itself
        (b"]p999999\ng999999\na", "refer back to themselves"),
        # a dict whose key is a tuple nested 100,000 deep: hashing it would exhaust the C stack
        (b"}" + b")" + b"\x85" * 100_000 + b"Ns", "not a plain value"),
        # an object of a listed class with an attribute that is a class (callable later)
        (b"csim.paths.fallback\nPriorityKeeper\n)\x81}\x8c\x04seedcsim.world.tracks\nTrackBuffers\nsb",
         "holds a type, which a checkpoint may not hold"),
        # an extension-registry global
        (b"\x82\x01", "instruction a checkpoint never has"),
        # NEWOBJ of something that is not a class: a number, and an unhashable list
        (b"K\x05)\x81", "creates an object of a class it may not hold"),
        (b"])\x81", "creates an object of a class it may not hold"),
    ],
    ids=["inst", "class-call", "array-bomb", "array-misfit", "object-array", "deep", "cycle", "deep-key", "class-attr", "ext",
         "newobj-value", "newobj-unhashable"],
)
def test_hostile_opcodes_inside_a_checkpoint(checkpoint: tuple[World, SessionCheckpoint], home: Scene,
                                             motion: MotionMatcher, tmp_path: Path, opcodes: bytes,
                                             needle: str) -> None:
    world, cp = checkpoint
    path = write_snapshot(tmp_path / "session.snapshot", spliced(world, cp, opcodes))
    with pytest.raises(SnapshotError) as exc:
        load_checkpoint(path, _world(home, motion))
    text = str(exc.value)
    assert text.startswith(str(path)) and "\n" not in text and needle in text, text


def test_a_model_with_a_wrong_field_type_is_refused(checkpoint: tuple[World, SessionCheckpoint], home: Scene,
                                                    motion: MotionMatcher, tmp_path: Path) -> None:
    from storyteller.orchestrator.session.session_types import TimedInstruction

    world, cp = checkpoint
    bad = TimedInstruction.model_construct(frame=cast(int, "soon"), text="x", source="script")  # not an int on purpose
    path = write_snapshot(tmp_path / "session.snapshot",
                          real_payload(world, dataclasses.replace(cp, instructions=[bad])))
    with pytest.raises(SnapshotError, match="TimedInstruction whose field frame is invalid"):
        load_checkpoint(path, _world(home, motion))


@pytest.mark.parametrize("slot", ["__pydantic_private__", "__pydantic_extra__"])
@pytest.mark.parametrize("forged", [False, {}, 0])
def test_a_model_with_a_forged_pydantic_slot_is_refused(checkpoint: tuple[World, SessionCheckpoint], home: Scene,
                                                       motion: MotionMatcher, tmp_path: Path, slot: str,
                                                       forged: object) -> None:
    """A falsy non-None value in a model's private or extra slot (found by the run-folder fuzzer:
    False there passed the check and stopped the resumed run deep in ``copy.deepcopy``)."""
    from storyteller.orchestrator.session.session_types import TimedInstruction

    world, cp = checkpoint
    bad = TimedInstruction(frame=3, text="x", source="script")
    object.__setattr__(bad, slot, forged)
    path = write_snapshot(tmp_path / "session.snapshot",
                          real_payload(world, dataclasses.replace(cp, instructions=[bad])))
    with pytest.raises(SnapshotError, match="TimedInstruction with values besides its fields"):
        load_checkpoint(path, _world(home, motion))


@pytest.mark.parametrize(("attribute", "forged"), [("_rank", None), ("_since", 1.5), ("boost", "many")])
def test_a_navigator_part_with_a_wrong_item_is_refused(checkpoint: tuple[World, SessionCheckpoint], home: Scene,
                                                       motion: MotionMatcher, tmp_path: Path, attribute: str,
                                                       forged: object) -> None:
    """A plain class's attributes are checked item by item against the annotations of its own
    ``__init__`` (found by the run-folder fuzzer: a None among the priority keeper's ranks passed
    and stopped the resumed run in ``sorted`` with exit 1)."""
    import copy

    world, cp = checkpoint
    snap = copy.deepcopy(cp.world, memo={id(o): o for o in world.shared_objects().values()})
    keeper = snap.navigator.nav.keeper
    getattr(keeper, attribute)["Ava"] = forged
    path = write_snapshot(tmp_path / "session.snapshot", real_payload(world, dataclasses.replace(cp, world=snap)))
    with pytest.raises(SnapshotError, match=f"PriorityKeeper whose attribute {attribute} is not"):
        load_checkpoint(path, _world(home, motion))


def test_a_checksum_mismatch_is_one_line(checkpoint: tuple[World, SessionCheckpoint], home: Scene,
                                         motion: MotionMatcher, tmp_path: Path) -> None:
    world, cp = checkpoint
    path = tmp_path / "session.snapshot"
    save_checkpoint(path, world, cp)
    data = bytearray(path.read_bytes())
    data[-100] ^= 0x01
    path.write_bytes(bytes(data))
    with pytest.raises(SnapshotError) as exc:
        load_checkpoint(path, _world(home, motion))
    assert str(exc.value) == (
        f"{path}: cannot read the session checkpoint (its checksum does not match: the file was changed or damaged)"
    )


def test_an_old_format_or_another_version_is_refused(checkpoint: tuple[World, SessionCheckpoint], home: Scene,
                                                     motion: MotionMatcher, tmp_path: Path) -> None:
    world, cp = checkpoint
    path = tmp_path / "session.snapshot"
    path.write_bytes(pickle.dumps((4, "an old checkpoint")))
    with pytest.raises(SnapshotError, match="written by an older version, damaged, or not a checkpoint"):
        load_checkpoint(path, _world(home, motion))
    payload = real_payload(world, cp)
    now = snapshot_file._FORMAT
    for other in (now - 1, now + 1):  # the version before (its classes lived elsewhere) and a later one
        path.write_bytes(header(payload, fmt=other) + payload)
        with pytest.raises(SnapshotError, match=rf"not a session checkpoint of this version \(format {other}, expected {now}\)"):
            load_checkpoint(path, _world(home, motion))


def test_a_linked_fifo_or_oversized_snapshot_is_refused(checkpoint: tuple[World, SessionCheckpoint], home: Scene,
                                                        motion: MotionMatcher, tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    world, cp = checkpoint
    real = tmp_path / "elsewhere.snapshot"
    save_checkpoint(real, world, cp)
    link = tmp_path / "session.snapshot"
    link.symlink_to(real)
    with pytest.raises(SnapshotError, match="symbolic link"):
        load_checkpoint(link, _world(home, motion))
    link.unlink()
    os.mkfifo(link)
    with pytest.raises(SnapshotError, match="not a regular file"):
        load_checkpoint(link, _world(home, motion))
    link.unlink()
    monkeypatch.setattr(snapshot_file, "MAX_SNAPSHOT_BYTES", 1000)
    with pytest.raises(SnapshotError, match="more than the 1000 allowed"):
        load_checkpoint(real, _world(home, motion))


def test_the_writer_replaces_a_planted_link_instead_of_writing_through_it(
    checkpoint: tuple[World, SessionCheckpoint], tmp_path: Path
) -> None:
    world, cp = checkpoint
    outside = tmp_path / "outside.txt"
    outside.write_text("keep me")
    run = tmp_path / "run"
    run.mkdir()
    (run / "session.snapshot").symlink_to(outside)
    (run / "session.snapshot.tmp").symlink_to(outside)  # the old writer's fixed temporary name
    (run / ".session.snapshot.0123456789abcdef.tmp").symlink_to(outside)  # as a killed writer leaves a temp
    save_checkpoint(run / "session.snapshot", world, cp)
    assert outside.read_text() == "keep me"
    assert sorted(p.name for p in run.iterdir()) == ["session.snapshot", "session.snapshot.tmp"]
    assert not (run / "session.snapshot").is_symlink()
    assert (run / "session.snapshot").read_bytes().startswith(b"storyteller-snapshot")


def test_every_listed_class_is_plain_data() -> None:
    """What the unpickler admits: classes whose instances are made by ``object.__new__`` and whose
    state is set without code of their own (pydantic's ``__setstate__`` only sets its dicts)."""
    resolved = snapshot_file._resolve_classes()
    assert set(resolved) == SNAPSHOT_CLASSES
    names = {cls.__name__ for cls in resolved.values()}
    assert "ChunkStore" not in names
    for cls in resolved.values():
        assert vars(object)["__new__"] is cls.__new__, cls
        setstate = getattr(cls, "__setstate__", None)
        assert setstate is None or setstate is BaseModel.__setstate__, cls
        assert all("__reduce__" not in vars(k) and "__reduce_ex__" not in vars(k) for k in cls.__mro__[:-1]), cls
        assert all("__call__" not in vars(k) for k in cls.__mro__), cls  # an instance is never callable


# ----- values of the right types that no run could have made ----------------------------------
def _impossible(world: World, cp: SessionCheckpoint, case: str) -> SessionCheckpoint:
    """A deep copy of ``cp`` (sharing ``world``'s read-only parts) with one impossible value of the right type."""
    import copy

    from storyteller.sim.world.events import Assignment

    bad = copy.deepcopy(cp, {id(obj): obj for obj in world.shared_objects().values()})
    ava = bad.world.characters["Ava"]
    if case == "negative frame":
        bad.world.frame = -5
    elif case == "event pointing nowhere":
        ava.event_id = "event-0042"
    elif case == "NaN position":
        ava.xy = np.array([float("nan"), 1.0])
    elif case == "far outside the scene":
        ava.anchor_xy = np.array([1e6, 1.0])
    elif case == "seat not in the scene":
        ava.assignment = Assignment(character="Ava", action="sit_idle", target_xy=(1.0, 1.0), facing_xy=(1.0, 0.0),
                                    seat="throne_9")
    elif case == "cell off the grid":
        ava.anchor_cell = (10**6, 3)
    elif case == "applied after the checkpoint":
        bad.outcomes, bad.applied_frames, bad.steps = [(0, None)], [10**6], 1
    elif case == "outcome of a step never taken":
        bad.outcomes, bad.applied_frames, bad.steps = [(7, None)], [3], 1
    return bad


@pytest.mark.parametrize(
    ("case", "needle"),
    [
        ("negative frame", "world is at frame -5"),
        ("event pointing nowhere", "character 'Ava' takes part in event 'event-0042', which its world does not hold"),
        ("NaN position", "character 'Ava''s xy is (nan, 1), not a point of the scene"),
        ("far outside the scene", "character 'Ava''s anchor_xy is (1e+06, 1), not a point of the scene"),
        ("seat not in the scene", "seat is 'throne_9', which scene 'home' has no object of"),
        ("cell off the grid", "anchor_cell is (1000000, 3), off the navigation grid"),
        ("applied after the checkpoint", "the frame step 0 was applied at is frame 1000000, outside the frames so far"),
        ("outcome of a step never taken", "an outcome's step 7 is not one of the 1 steps taken"),
    ],
)
def test_a_checkpoint_no_run_could_have_made_is_one_line(checkpoint: tuple[World, SessionCheckpoint], home: Scene,
                                                         motion: MotionMatcher, tmp_path: Path, case: str,
                                                         needle: str) -> None:
    world, cp = checkpoint
    path = write_snapshot(tmp_path / "session.snapshot", real_payload(world, _impossible(world, cp, case)))
    with pytest.raises(SnapshotError) as exc:
        load_checkpoint(path, _world(home, motion))
    text = str(exc.value)
    assert text.startswith(f"{path}: cannot read the session checkpoint: ") and "\n" not in text, text
    assert needle in text, text

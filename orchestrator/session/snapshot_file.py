"""The session's last checkpoint on disk (``session.snapshot`` in the run folder).

:func:`save_checkpoint` writes a :class:`~orchestrator.session.runtime.SessionCheckpoint` with
pickle, atomically: to a temporary file in the same folder, fsynced, then renamed over the old
one, so a kill -9 at any moment leaves either the previous checkpoint or the new one, never a
torn file. The world's read-only parts (scene, navigation grids, path planners, motion layer:
``World.shared_objects``) are stored by name only; :func:`load_checkpoint` binds those names to
the objects of a world built from the same run arguments. A streaming world's checkpoint holds
only its frames not yet in the chunk files (``sim.world.track_chunks``) and how many are there;
those are fsynced before the checkpoint is written, so the count it gives is always on disk. The file is the run's own state,
read back only by ``storyteller resume`` of the same run folder (never an untrusted file).
"""

from __future__ import annotations

import io
import os
import pickle
from pathlib import Path
from typing import Any

from orchestrator.session.runtime import SessionCheckpoint
from sim.world.step import World
from sim.world.track_chunks import ChunkStore

SNAPSHOT_FILE = "session.snapshot"
_FORMAT = 4  # 2: the checkpoint holds the session's instructions; 3: the world's motion is in the chunk files;
# 4: planning requests carry the summary of the events before their history (``earlier``)


class SnapshotError(Exception):
    """A checkpoint file that cannot be read against this world (the message says why)."""


class _Pickler(pickle.Pickler):
    def __init__(self, file: io.BytesIO, shared: dict[int, str]) -> None:
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self._shared = shared

    def persistent_id(self, obj: Any) -> str | None:
        return self._shared.get(id(obj))


class _Unpickler(pickle.Unpickler):
    def __init__(self, file: io.BytesIO, shared: dict[str, Any]) -> None:
        super().__init__(file)
        self._shared = shared

    def persistent_load(self, pid: Any) -> Any:
        if pid not in self._shared:
            raise SnapshotError(f"the checkpoint refers to an unknown shared object {pid!r}")
        return self._shared[pid]


def save_checkpoint(path: Path, world: World, checkpoint: SessionCheckpoint) -> None:
    """Write ``checkpoint`` (of a session on ``world``) to ``path`` atomically, after making the
    motion chunks it counts on durable."""
    write_checkpoint(path, checkpoint, shared_names(world), world.buffers.store)


def shared_names(world: World) -> dict[int, str]:
    """``id`` -> name of ``world``'s shared objects, as a checkpoint file stores them."""
    return {id(obj): name for name, obj in world.shared_objects().items()}


def write_checkpoint(path: Path, checkpoint: SessionCheckpoint, shared: dict[int, str], store: ChunkStore | None) -> None:
    """:func:`save_checkpoint` with the world's parts it needs taken beforehand (``shared``:
    :func:`shared_names`; ``store``: its chunk store, synced first), so it can run in a worker
    thread while the world steps on: ``checkpoint`` is a copy the session no longer touches, and
    the chunk files only grow while the world runs (the frames the checkpoint counts were
    written before it was taken)."""
    if store is not None:
        store.sync()
    buf = io.BytesIO()
    _Pickler(buf, shared).dump((_FORMAT, checkpoint))
    tmp = path.with_name(path.name + ".tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            view = memoryview(buf.getbuffer())
            while view:
                view = view[os.write(fd, view):]
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError as exc:  # a full disk: the previous checkpoint stays, the partial one goes
        tmp.unlink(missing_ok=True)
        raise OSError(exc.errno, exc.strerror, str(path)) from None
    os.replace(tmp, path)
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def load_checkpoint(path: Path, world: World) -> SessionCheckpoint:
    """The checkpoint in ``path``, its shared objects bound to ``world``'s."""
    try:
        data = path.read_bytes()
        fmt, checkpoint = _Unpickler(io.BytesIO(data), world.shared_objects()).load()
    except (OSError, pickle.UnpicklingError, EOFError, ValueError, AttributeError) as exc:
        raise SnapshotError(f"{path}: cannot read the session checkpoint ({type(exc).__name__}: {exc})") from None
    if fmt != _FORMAT or not isinstance(checkpoint, SessionCheckpoint):
        raise SnapshotError(f"{path}: not a session checkpoint of this version")
    return checkpoint

"""The session's last checkpoint on disk (``session.snapshot`` in the run folder).

:func:`save_checkpoint` writes a :class:`~storyteller.orchestrator.session.session_types.SessionCheckpoint`
atomically: to a temporary file of a fresh name in the same folder (created with ``O_EXCL``
and ``O_NOFOLLOW``, so a planted link is never written through), fsynced, then renamed over
the old one, so a kill -9 at any moment leaves either the previous checkpoint or the new one,
never a torn file. The world's read-only parts (scene, navigation grids, path planners, motion
layer: ``World.shared_objects``) are stored by name only; :func:`load_checkpoint` binds those
names to the objects of a world built from the same run arguments. A streaming world's
checkpoint holds only its frames not yet in the chunk files (``storyteller.sim.world.track_chunks``) and
how many are there; those are fsynced before the checkpoint is written, so the count it gives
is always on disk.

A run folder may come from someone else, so reading a checkpoint runs no code from it:

- the file is read without following a link, at most :data:`MAX_SNAPSHOT_BYTES` of it;
- its first line gives the format version and the sha256 of the rest (the payload): a file of
  another version or whose payload does not match is refused before anything is decoded;
- the payload is a pickle decoded by a restricted unpickler: it admits only the classes listed
  in :data:`SNAPSHOT_CLASSES` (the project's own data types), creates their instances without
  calling a constructor (``cls.__new__(cls)`` and the pickle's state, never ``__init__``), calls
  no function but this module's two array decoders (which check dtype, shape and byte count),
  and adds items only to real lists, dicts and sets; every other global, call or extension
  opcode is a :class:`SnapshotError`;
- the decoded objects are then checked as a whole (:func:`~storyteller.orchestrator.session.snapshot_tree.check_tree`): only listed
  instances, plain values and numeric arrays, each listed instance with exactly its declared
  fields, pydantic models valid against their schema, every dataclass field of the type its
  annotation gives (:func:`~storyteller.orchestrator.session.snapshot_tree.fits`: ``int``, ``str | None``, ``tuple[int, int]``,
  ``dict[str, CharacterState]``, an array of the annotated dtype, ``Literal`` values...), at
  most :data:`~storyteller.orchestrator.session.snapshot_tree.MAX_DEPTH` levels deep;
- and against the world it is bound to (:func:`~storyteller.orchestrator.session.snapshot_sense.check_fits_world`): the same characters, in
  the same order, everywhere the world keeps them by name;
- and for sense (:func:`~storyteller.orchestrator.session.snapshot_sense.check_sense`): values of the right types that no run could have made
  are refused too: a frame below 0 or after the checkpoint's own, a step index outside the
  steps taken, an event id a character, a pending assignment or the world's event book names
  that the checkpoint does not hold, a character or event member that is not this run's, a
  position or angle that is not finite or lies more than :data:`~storyteller.orchestrator.session.snapshot_sense.OUTSIDE_M` outside the scene's
  floor, a grid cell off the navigation grid, a seat or used object the scene has no object of.

So a crafted checkpoint with a wrong-typed or impossible field is refused at load, with one
line, instead of stopping the resumed run with an error deep in the simulation.

Every failure is a :class:`~storyteller.orchestrator.session.snapshot_errors.SnapshotError` with one line
naming the file.
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import importlib
import io
import os
import pickle
import re
import secrets
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar, Protocol

import numpy as np

from storyteller.orchestrator.session.session_types import SessionCheckpoint
from storyteller.orchestrator.session.snapshot_errors import SnapshotError
from storyteller.orchestrator.session.snapshot_sense import check_fits_world, check_sense
from storyteller.orchestrator.session.snapshot_tree import MAX_KEY_DEPTH, check_tree, plain_key, plain_templates
from storyteller.sim.bounded_files import BoundedFileError, read_bounded_bytes
from storyteller.sim.world.step import World
from storyteller.sim.world.track_chunks import ChunkStore

SNAPSHOT_FILE = "session.snapshot"
_FORMAT = 6  # 2: the checkpoint holds the session's instructions; 3: the world's motion is in the chunk files;
# 4: planning requests carry the summary of the events before their history (``earlier``);
# 5: a header line (version, sha256 of the payload); arrays stored by _array / _scalar; read by an allowlist;
# 6: the session's checkpoint types live in orchestrator.session.session_types (a 5 names them in .runtime)
_MAGIC = b"storyteller-snapshot"
_HEADER = re.compile(rb"storyteller-snapshot (\d{1,6}) sha256=([0-9a-f]{64})\n")
_HEADER_MAX = 128  # bytes: the header line is shorter

MAX_SNAPSHOT_BYTES = 256 << 20
"""Bytes of the largest checkpoint file read back (a streaming run's checkpoint holds at most
``STREAM_WINDOW`` frames per character: well under a MiB per character)."""
_MAX_NDIM = 8  # dimensions of an array at most (the checkpoint's arrays have up to 5)
_MAX_DIM = 1 << 32  # entries along one axis at most (the bytes must fit the shape as well)

SNAPSHOT_CLASSES: frozenset[tuple[str, str]] = frozenset({
    # Every class a session checkpoint holds, as (module, qualified name). Recorded from the
    # find_class calls made while the resume tests (test_session_runtime, test_run_folder,
    # test_run_corrupt_files, test_run_faults, test_live_instructions, test_checkpoint_writer,
    # test_session_concurrency, test_story_log) saved and loaded real checkpoints, completed from
    # the type hints reachable from SessionCheckpoint. Each is a dataclass, a pydantic model or a
    # plain state holder whose ``__new__`` is ``object.__new__`` and which defines no
    # ``__setstate__`` / ``__reduce__`` of its own (pydantic's ``__setstate__`` only sets its
    # field dicts); none opens a file, starts a process, imports or evaluates anything when its
    # state is set (tests/orchestrator/session/test_snapshot_file.py checks this list for it). Never add ChunkStore
    # (it opens files; a checkpoint stores its frame count) or any class whose state runs code.
    ("storyteller.orchestrator.session.session_types", "SessionCheckpoint"),
    ("storyteller.orchestrator.session.session_types", "StoryEvent"),
    ("storyteller.orchestrator.session.session_types", "PlanningRequest"),
    ("storyteller.orchestrator.session.session_types", "TimedInstruction"),
    ("storyteller.agents.messages", "CharacterSoFar"),
    ("storyteller.agents.messages", "CharacterStatus"),
    ("storyteller.agents.messages", "EarlierEvents"),
    ("storyteller.agents.messages", "Event"),
    ("storyteller.agents.messages", "HistoryEntry"),
    ("storyteller.agents.messages", "ParsedEvent"),
    ("storyteller.agents.messages", "PlannedCharacter"),
    ("storyteller.agents.messages", "PlanningFailure"),
    ("storyteller.sim.world.step", "WorldSnapshot"),
    ("storyteller.sim.world.phases", "CharacterState"),
    ("storyteller.sim.world.phases", "StandTarget"),
    ("storyteller.sim.world.event_book", "EventState"),
    ("storyteller.sim.world.events", "AssignEvent"),
    ("storyteller.sim.world.events", "Assignment"),
    ("storyteller.sim.world.events", "EventFailure"),
    ("storyteller.sim.world.navigation", "WorldNavigator"),
    ("storyteller.sim.world.tracks", "TrackBuffers"),
    ("storyteller.sim.paths.following", "CrowdNavigator"),
    ("storyteller.sim.paths.off_grid", "Leg"),
    ("storyteller.sim.paths.tracks", "PlanTracks"),
    ("storyteller.sim.paths.fallback", "PriorityKeeper"),
    ("storyteller.sim.paths.cooperative_astar", "PlanResult"),
    ("storyteller.sim.motion.matching", "MatchState"),
    ("storyteller.sim.body.foot_ik", "FootState"),
})  # fmt: skip
_FOLDERS_BEFORE_THE_NAMESPACE = frozenset({"sim", "tools", "agents", "orchestrator", "benchmark", "prompts"})


def current_module_name(module: str) -> str:
    """``module`` as this version names it: checkpoints written before the package had one
    installed name (issue 26) name a class's module by its folder alone (the ``sim`` package's
    ``world.step``), which now takes the ``storyteller.`` prefix; any other name is returned as
    it is (and still has to be listed in :data:`SNAPSHOT_CLASSES`)."""
    top, dot, _ = module.partition(".")
    return f"storyteller.{module}" if dot and top in _FOLDERS_BEFORE_THE_NAMESPACE else module


_DECODERS = ("_array", "_scalar")  # the only functions a checkpoint calls: this module's array decoders


def _array(data: object, dtype: object, shape: object) -> np.ndarray[Any, Any]:
    """An array from its bytes (arguments as a checkpoint gives them, unchecked): refuses object
    dtypes and a shape that does not fit the bytes."""
    kind = _numeric_dtype(dtype)
    if not isinstance(data, bytes) or not isinstance(shape, tuple) or len(shape) > _MAX_NDIM:
        raise SnapshotError("an array with a malformed shape")
    if not all(type(n) is int and 0 <= n <= _MAX_DIM for n in shape):
        raise SnapshotError("an array with a malformed shape")
    if int(np.prod(shape, dtype=object)) * kind.itemsize != len(data):
        raise SnapshotError(f"an array of shape {shape} and dtype {kind.str} does not fit its {len(data)} bytes")
    return np.frombuffer(data, dtype=kind).reshape(shape).copy()


def _scalar(data: object, dtype: object) -> np.generic:
    """A numpy scalar from its bytes (one item of ``dtype``)."""
    kind = _numeric_dtype(dtype)
    if not isinstance(data, bytes) or len(data) != kind.itemsize:
        raise SnapshotError(f"a scalar of dtype {kind.str} does not fit its bytes")
    value: np.generic = np.frombuffer(data, dtype=kind)[0]
    return value


def _numeric_dtype(text: object) -> np.dtype[Any]:
    if not isinstance(text, str) or len(text) > 16:
        raise SnapshotError("an array of a malformed dtype")
    try:
        kind = np.dtype(text)
    except (TypeError, ValueError):
        raise SnapshotError(f"an array of an unknown dtype {text!r}") from None
    if kind.hasobject or kind.fields is not None or kind.subdtype is not None or kind.itemsize == 0:
        raise SnapshotError(f"an array of dtype {text!r} (only plain numeric arrays are stored)")
    return kind


_Reduction = tuple[Callable[..., object], tuple[object, ...]]  # a function and its arguments, as ``__reduce__`` gives


class _Pickler(pickle.Pickler):
    def __init__(self, file: io.BytesIO, shared: dict[int, str]) -> None:
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self._shared = shared

    def persistent_id(self, obj: object) -> str | None:
        return self._shared.get(id(obj))

    def reducer_override(self, obj: object) -> _Reduction | types.NotImplementedType:
        """:func:`_numpy_reduction` for arrays and numpy scalars; anything else (NotImplemented)
        is pickled as usual."""
        reduced = _numpy_reduction(obj)
        # one expression: mypy reads a bare ``return NotImplemented`` as returning Any (python/mypy#18914)
        return NotImplemented if reduced is None else reduced


def _numpy_reduction(obj: object) -> _Reduction | None:
    """Arrays and numpy scalars as (bytes, dtype, shape) for :func:`_array` / :func:`_scalar`,
    not numpy's own reduce functions (which the loader does not admit); None for anything else."""
    if isinstance(obj, np.ndarray):
        if type(obj) is not np.ndarray or obj.dtype.hasobject or obj.dtype.fields is not None:
            raise TypeError(f"a checkpoint stores plain numeric arrays only, not {type(obj).__name__} of {obj.dtype}")
        return _array, (obj.tobytes(), obj.dtype.str, tuple(int(n) for n in obj.shape))
    if isinstance(obj, np.generic):
        return _scalar, (obj.tobytes(), obj.dtype.str)
    return None


def _resolve_classes() -> dict[tuple[str, str], type]:
    out: dict[tuple[str, str], type] = {}
    for module, name in SNAPSHOT_CLASSES:
        cls = getattr(importlib.import_module(module), name)
        assert isinstance(cls, type), (module, name)
        out[module, name] = cls
    return out


class _PyOpcodes(Protocol):
    """The opcode methods of the pure-Python unpickler class that the checks below call after
    their own, each with the unpickler as its argument (private, and not in typeshed)."""

    def load_reduce(self, unpickler: pickle._Unpickler, /) -> None: ...
    def load_build(self, unpickler: pickle._Unpickler, /) -> None: ...
    def load_append(self, unpickler: pickle._Unpickler, /) -> None: ...
    def load_appends(self, unpickler: pickle._Unpickler, /) -> None: ...
    def load_setitem(self, unpickler: pickle._Unpickler, /) -> None: ...
    def load_setitems(self, unpickler: pickle._Unpickler, /) -> None: ...
    def load_dict(self, unpickler: pickle._Unpickler, /) -> None: ...
    def load_additems(self, unpickler: pickle._Unpickler, /) -> None: ...
    def load_frozenset(self, unpickler: pickle._Unpickler, /) -> None: ...


_PY_UNPICKLER: _PyOpcodes = vars(pickle)["_Unpickler"]
"""The pure-Python unpickler (``pickle._Unpickler``), whose opcode methods the checks below call
after their own; read from the module's namespace, as typeshed's stub of the class lacks them."""


class _Unpickler(pickle._Unpickler):  # the Python unpickler: its opcodes can be checked one by one
    """Decodes only what :func:`load_checkpoint` admits (the module docstring lists it)."""

    dispatch: ClassVar[dict[int, Any]] = dict(pickle._Unpickler.dispatch)
    stack: list[object]  # the Python unpickler's own state (not in typeshed)
    metastack: list[list[object]]
    append: Callable[[object], None]  # ``stack.append``, bound by ``load``

    def __init__(self, file: io.BytesIO, shared: dict[str, object], classes: dict[tuple[str, str], type]) -> None:
        super().__init__(file)
        self._shared = shared
        self._classes = classes
        self._class_set = frozenset(classes.values())

    def persistent_load(self, pid: object) -> object:
        if not isinstance(pid, str) or pid not in self._shared:
            raise SnapshotError(f"the checkpoint refers to an unknown shared object {str(pid)[:40]!r}")
        return self._shared[pid]

    def find_class(self, module: str, name: str) -> Callable[..., object]:
        module = current_module_name(module)
        if module == __name__ and name in _DECODERS:
            decoders: dict[str, Callable[..., object]] = {"_array": _array, "_scalar": _scalar}
            return decoders[name]
        cls = self._classes.get((module, name))
        if cls is None:
            raise SnapshotError(f"the checkpoint refers to {str(module)[:60]}.{str(name)[:60]}, which a checkpoint may not hold")
        return cls

    def _refuse(self) -> None:
        raise SnapshotError("the checkpoint holds a pickle instruction a checkpoint never has")

    def _load_reduce(self) -> None:
        func = self.stack[-2]
        if func is not _array and func is not _scalar:
            raise SnapshotError("the checkpoint calls something other than its array decoders")
        _PY_UNPICKLER.load_reduce(self)

    def _new_instance(self, cls: object, args: object, kwargs: object) -> None:
        # not a type (a value, or something unhashable that the set lookup would trip on): refused first
        if not isinstance(cls, type) or cls not in self._class_set or args != () or kwargs:
            raise SnapshotError("the checkpoint creates an object of a class it may not hold")
        kind: type[object] = cls  # a listed class: its ``__new__`` is ``object.__new__`` (SNAPSHOT_CLASSES)
        self.append(kind.__new__(kind))

    def _load_newobj(self) -> None:
        args = self.stack.pop()
        cls = self.stack.pop()
        self._new_instance(cls, args, None)

    def _load_newobj_ex(self) -> None:
        kwargs = self.stack.pop()
        args = self.stack.pop()
        cls = self.stack.pop()
        self._new_instance(cls, args, kwargs)

    def _load_build(self) -> None:
        if type(self.stack[-2]) not in self._class_set:
            raise SnapshotError("the checkpoint sets the state of an object it may not hold")
        _PY_UNPICKLER.load_build(self)

    def _load_append(self) -> None:
        if type(self.stack[-2]) is not list:
            raise SnapshotError("the checkpoint appends to something other than a list")
        _PY_UNPICKLER.load_append(self)

    def _load_appends(self) -> None:
        if type(self.metastack[-1][-1] if self.metastack else None) is not list:
            raise SnapshotError("the checkpoint appends to something other than a list")
        _PY_UNPICKLER.load_appends(self)

    def _load_setitem(self) -> None:
        if type(self.stack[-3]) is not dict:
            raise SnapshotError("the checkpoint sets an item of something other than a dict")
        _check_keys(self.stack[-2:-1])
        _PY_UNPICKLER.load_setitem(self)

    def _load_setitems(self) -> None:
        if type(self.metastack[-1][-1] if self.metastack else None) is not dict:
            raise SnapshotError("the checkpoint sets items of something other than a dict")
        _check_keys(self.stack[::2])
        _PY_UNPICKLER.load_setitems(self)

    def _load_dict(self) -> None:
        _check_keys(self.stack[::2])
        _PY_UNPICKLER.load_dict(self)

    def _load_additems(self) -> None:
        if type(self.metastack[-1][-1] if self.metastack else None) is not set:
            raise SnapshotError("the checkpoint adds items to something other than a set")
        _check_keys(self.stack)
        _PY_UNPICKLER.load_additems(self)

    def _load_frozenset(self) -> None:
        _check_keys(self.stack)
        _PY_UNPICKLER.load_frozenset(self)


def _check_keys(keys: list[object]) -> None:
    """Dict keys and set items are plain values or short tuples of them: hashing anything else
    (a tuple nested a million deep, a model holding one) could exhaust the C stack."""
    for key in keys:
        if not plain_key(key, MAX_KEY_DEPTH):
            raise SnapshotError("the checkpoint holds a dict key or set item that is not a plain value")


for _op, _handler in (
    (pickle.REDUCE, _Unpickler._load_reduce),
    (pickle.NEWOBJ, _Unpickler._load_newobj),
    (pickle.NEWOBJ_EX, _Unpickler._load_newobj_ex),
    (pickle.BUILD, _Unpickler._load_build),
    (pickle.APPEND, _Unpickler._load_append),
    (pickle.APPENDS, _Unpickler._load_appends),
    (pickle.SETITEM, _Unpickler._load_setitem),
    (pickle.SETITEMS, _Unpickler._load_setitems),
    (pickle.DICT, _Unpickler._load_dict),
    (pickle.ADDITEMS, _Unpickler._load_additems),
    (pickle.FROZENSET, _Unpickler._load_frozenset),
    # protocol 0/1 instance creation (calls the class), extension registry, class-by-name
    (pickle.INST, _Unpickler._refuse),
    (pickle.OBJ, _Unpickler._refuse),
    (pickle.EXT1, _Unpickler._refuse),
    (pickle.EXT2, _Unpickler._refuse),
    (pickle.EXT4, _Unpickler._refuse),
):
    _Unpickler.dispatch[_op[0]] = _handler


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
    _Pickler(buf, shared).dump(checkpoint)
    payload = buf.getbuffer()
    header = b"%s %d sha256=%s\n" % (_MAGIC, _FORMAT, hashlib.sha256(payload).hexdigest().encode("ascii"))
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(8)}.tmp")  # a fresh name: nothing planted there
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        try:
            for part in (memoryview(header), payload):
                view = part
                while view:
                    view = view[os.write(fd, view):]
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)  # replaces a link planted at ``path`` itself, never its target
    except OSError as exc:  # a full disk: the previous checkpoint stays, the partial one goes
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise OSError(exc.errno, exc.strerror, str(path)) from None
    dir_fd = os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
    for stale in path.parent.glob(f".{glob.escape(path.name)}.*.tmp"):  # left by a writer killed mid-write
        with contextlib.suppress(OSError):
            stale.unlink()  # a link planted under such a name goes, never its target


def load_checkpoint(path: Path, world: World) -> SessionCheckpoint:
    """The checkpoint in ``path``, its shared objects bound to ``world``'s; :class:`SnapshotError`
    (one line naming the file) when it is not a checkpoint this version wrote and can trust."""
    try:
        data = read_bounded_bytes(path, MAX_SNAPSHOT_BYTES, str(path), follow_symlinks=False)
    except BoundedFileError as exc:
        raise SnapshotError(f"cannot read the session checkpoint {exc}") from None
    payload = _payload(path, data)
    shared = world.shared_objects()
    try:
        classes = _resolve_classes()
        checkpoint = _Unpickler(io.BytesIO(payload), shared, classes).load()
    except SnapshotError as exc:
        raise SnapshotError(f"{path}: cannot read the session checkpoint: {exc}") from None
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, KeyError, IndexError,
            MemoryError, RecursionError) as exc:
        raise SnapshotError(f"{path}: cannot read the session checkpoint ({type(exc).__name__}: {str(exc)[:200]})") from None
    if not isinstance(checkpoint, SessionCheckpoint):
        raise SnapshotError(f"{path}: not a session checkpoint of this version")
    try:
        listed = frozenset(classes.values())
        check_tree(checkpoint, {id(o) for o in shared.values()}, listed, plain_templates(world, listed))
        check_fits_world(checkpoint, world)
        check_sense(checkpoint, world)
    except SnapshotError as exc:
        raise SnapshotError(f"{path}: cannot read the session checkpoint: {exc}") from None
    except _CHECK_SLIPS as exc:  # a forged object the checks' own code trips on (a validator reading a field the forgery lacks)
        raise SnapshotError(f"{path}: cannot read the session checkpoint ({type(exc).__name__}: {str(exc)[:200]})") from None
    return checkpoint


# What checking a forged object of the right class can raise before a check refuses it: the
# checks read fields, hash keys and run the models' validators on state the forgery shaped.
_CHECK_SLIPS = (AttributeError, TypeError, ValueError, KeyError, IndexError, ArithmeticError, RecursionError)


def _payload(path: Path, data: bytes) -> bytes:
    """The pickle after the header line, once the version and the checksum match."""
    end = data.find(b"\n", 0, _HEADER_MAX)
    m = _HEADER.fullmatch(data[: end + 1]) if end >= 0 else None
    if m is None:  # a format before 5 (a bare pickle), a damaged header, or not a checkpoint at all
        raise SnapshotError(
            f"{path}: cannot read the session checkpoint (it does not start with a '{_MAGIC.decode()} {_FORMAT}' line: "
            "written by an older version, damaged, or not a checkpoint)"
        )
    if int(m.group(1)) != _FORMAT:
        raise SnapshotError(f"{path}: not a session checkpoint of this version (format {int(m.group(1))}, expected {_FORMAT})")
    payload = data[end + 1:]
    if hashlib.sha256(payload).hexdigest().encode("ascii") != m.group(2):
        raise SnapshotError(f"{path}: cannot read the session checkpoint (its checksum does not match: the file was changed or damaged)")
    return payload



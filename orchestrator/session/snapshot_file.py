"""The session's last checkpoint on disk (``session.snapshot`` in the run folder).

:func:`save_checkpoint` writes a :class:`~orchestrator.session.session_types.SessionCheckpoint`
atomically: to a temporary file of a fresh name in the same folder (created with ``O_EXCL``
and ``O_NOFOLLOW``, so a planted link is never written through), fsynced, then renamed over
the old one, so a kill -9 at any moment leaves either the previous checkpoint or the new one,
never a torn file. The world's read-only parts (scene, navigation grids, path planners, motion
layer: ``World.shared_objects``) are stored by name only; :func:`load_checkpoint` binds those
names to the objects of a world built from the same run arguments. A streaming world's
checkpoint holds only its frames not yet in the chunk files (``sim.world.track_chunks``) and
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
- the decoded objects are then checked as a whole (:func:`_check_tree`): only listed
  instances, plain values and numeric arrays, each listed instance with exactly its declared
  fields, pydantic models valid against their schema, every dataclass field of the type its
  annotation gives (:func:`_fits`: ``int``, ``str | None``, ``tuple[int, int]``,
  ``dict[str, CharacterState]``, an array of the annotated dtype, ``Literal`` values...), at
  most :data:`MAX_DEPTH` levels deep;
- and against the world it is bound to (:func:`_check_fits_world`): the same characters, in
  the same order, everywhere the world keeps them by name;
- and for sense (:func:`_check_sense`): values of the right types that no run could have made
  are refused too: a frame below 0 or after the checkpoint's own, a step index outside the
  steps taken, an event id a character, a pending assignment or the world's event book names
  that the checkpoint does not hold, a character or event member that is not this run's, a
  position or angle that is not finite or lies more than :data:`_OUTSIDE_M` outside the scene's
  floor, a grid cell off the navigation grid, a seat or used object the scene has no object of.

So a crafted checkpoint with a wrong-typed or impossible field is refused at load, with one
line, instead of stopping the resumed run with an error deep in the simulation.

Every failure is a :class:`SnapshotError` with one line naming the file.
"""

from __future__ import annotations

import ast
import contextlib
import dataclasses
import glob
import hashlib
import importlib
import inspect
import io
import os
import pickle
import re
import secrets
import textwrap
import types
import typing
from collections.abc import Hashable, Sequence
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ValidationError

from orchestrator.session.session_types import SessionCheckpoint
from sim.bounded_files import BoundedFileError, read_bounded_bytes
from sim.validation_text import problem_field, problem_message
from sim.world.step import World
from sim.world.track_chunks import ChunkStore

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
MAX_DEPTH = 48
"""Levels of nesting of the decoded objects at most (the checkpoints of the resume tests have 8)."""
_MAX_NDIM = 8  # dimensions of an array at most (the checkpoint's arrays have up to 5)
_MAX_DIM = 1 << 32  # entries along one axis at most (the bytes must fit the shape as well)
_MAX_KEY_DEPTH = 3  # tuples in tuples in a dict key or set item at most
_OUTSIDE_M = 1.0
"""Metres a stored position may lie outside the scene's floor rectangle (a character stands,
walks and sits on the floor; a seat's approach point is within reach of it)."""

SNAPSHOT_CLASSES: frozenset[tuple[str, str]] = frozenset({
    # Every class a session checkpoint holds, as (module, qualified name). Recorded from the
    # find_class calls made while the resume tests (test_session_runtime, test_run_folder,
    # test_run_corrupt_files, test_run_faults, test_live_instructions, test_checkpoint_writer,
    # test_session_concurrency, test_story_log) saved and loaded real checkpoints, completed from
    # the type hints reachable from SessionCheckpoint. Each is a dataclass, a pydantic model or a
    # plain state holder whose ``__new__`` is ``object.__new__`` and which defines no
    # ``__setstate__`` / ``__reduce__`` of its own (pydantic's ``__setstate__`` only sets its
    # field dicts); none opens a file, starts a process, imports or evaluates anything when its
    # state is set (tests/test_snapshot_file.py checks this list for it). Never add ChunkStore
    # (it opens files; a checkpoint stores its frame count) or any class whose state runs code.
    ("orchestrator.session.session_types", "SessionCheckpoint"),
    ("orchestrator.session.session_types", "StoryEvent"),
    ("orchestrator.session.session_types", "PlanningRequest"),
    ("orchestrator.session.session_types", "TimedInstruction"),
    ("agents.messages", "CharacterSoFar"),
    ("agents.messages", "CharacterStatus"),
    ("agents.messages", "EarlierEvents"),
    ("agents.messages", "Event"),
    ("agents.messages", "HistoryEntry"),
    ("agents.messages", "ParsedEvent"),
    ("agents.messages", "PlannedCharacter"),
    ("agents.messages", "PlanningFailure"),
    ("sim.world.step", "WorldSnapshot"),
    ("sim.world.phases", "CharacterState"),
    ("sim.world.phases", "StandTarget"),
    ("sim.world.event_book", "EventState"),
    ("sim.world.events", "AssignEvent"),
    ("sim.world.events", "Assignment"),
    ("sim.world.events", "EventFailure"),
    ("sim.world.navigation", "WorldNavigator"),
    ("sim.world.tracks", "TrackBuffers"),
    ("sim.paths.following", "CrowdNavigator"),
    ("sim.paths.off_grid", "Leg"),
    ("sim.paths.tracks", "PlanTracks"),
    ("sim.paths.fallback", "PriorityKeeper"),
    ("sim.paths.cooperative_astar", "PlanResult"),
    ("sim.motion.matching", "MatchState"),
    ("sim.body.foot_ik", "FootState"),
})  # fmt: skip
_DECODERS = ("_array", "_scalar")  # the only functions a checkpoint calls: this module's array decoders
_PLAIN_TYPES = (type(None), bool, int, float, complex, str, bytes)
_CONTAINERS = (tuple, list, dict, set, frozenset)


class SnapshotError(Exception):
    """A checkpoint file that cannot be read against this world (the message says why)."""


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


class _Pickler(pickle.Pickler):
    def __init__(self, file: io.BytesIO, shared: dict[int, str]) -> None:
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self._shared = shared

    def persistent_id(self, obj: Any) -> str | None:
        return self._shared.get(id(obj))

    def reducer_override(self, obj: Any) -> Any:
        """Arrays and numpy scalars as (bytes, dtype, shape) for :func:`_array` / :func:`_scalar`,
        not numpy's own reduce functions (which the loader does not admit)."""
        if isinstance(obj, np.ndarray):
            if type(obj) is not np.ndarray or obj.dtype.hasobject or obj.dtype.fields is not None:
                raise TypeError(f"a checkpoint stores plain numeric arrays only, not {type(obj).__name__} of {obj.dtype}")
            return _array, (obj.tobytes(), obj.dtype.str, tuple(int(n) for n in obj.shape))
        if isinstance(obj, np.generic):
            return _scalar, (obj.tobytes(), obj.dtype.str)
        return NotImplemented


def _resolve_classes() -> dict[tuple[str, str], type]:
    out: dict[tuple[str, str], type] = {}
    for module, name in SNAPSHOT_CLASSES:
        cls = getattr(importlib.import_module(module), name)
        assert isinstance(cls, type), (module, name)
        out[module, name] = cls
    return out


_PY_UNPICKLER: Any = pickle._Unpickler
"""The pure-Python unpickler whose opcode methods (``load_reduce``...) the checks below call
after their own: they are private and not in typeshed, so they are reached through ``Any``."""


class _Unpickler(pickle._Unpickler):  # the Python unpickler: its opcodes can be checked one by one
    """Decodes only what :func:`load_checkpoint` admits (the module docstring lists it)."""

    dispatch: ClassVar[dict[int, Any]] = dict(pickle._Unpickler.dispatch)
    stack: list[Any]  # the Python unpickler's own state (not in typeshed)
    metastack: list[list[Any]]
    append: Any

    def __init__(self, file: io.BytesIO, shared: dict[str, Any], classes: dict[tuple[str, str], type]) -> None:
        super().__init__(file)
        self._shared = shared
        self._classes = classes
        self._class_set = frozenset(classes.values())

    def persistent_load(self, pid: Any) -> Any:
        if not isinstance(pid, str) or pid not in self._shared:
            raise SnapshotError(f"the checkpoint refers to an unknown shared object {str(pid)[:40]!r}")
        return self._shared[pid]

    def find_class(self, module: str, name: str) -> Any:
        if module == __name__ and name in _DECODERS:
            return {"_array": _array, "_scalar": _scalar}[name]
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

    def _new_instance(self, cls: Any, args: Any, kwargs: Any) -> None:
        if cls not in self._class_set or args != () or kwargs:
            raise SnapshotError("the checkpoint creates an object of a class it may not hold")
        self.append(cls.__new__(cls))

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


def _check_keys(keys: list[Any]) -> None:
    """Dict keys and set items are plain values or short tuples of them: hashing anything else
    (a tuple nested a million deep, a model holding one) could exhaust the C stack."""
    for key in keys:
        if not _plain_key(key, _MAX_KEY_DEPTH):
            raise SnapshotError("the checkpoint holds a dict key or set item that is not a plain value")


def _plain_key(key: Any, depth: int) -> bool:
    if isinstance(key, _PLAIN_TYPES):
        return True
    return type(key) is tuple and depth > 0 and len(key) <= 64 and all(_plain_key(k, depth - 1) for k in key)


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
        checkpoint = _Unpickler(io.BytesIO(payload), shared, _resolve_classes()).load()
    except SnapshotError as exc:
        raise SnapshotError(f"{path}: cannot read the session checkpoint: {exc}") from None
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, KeyError, IndexError,
            MemoryError, RecursionError) as exc:
        raise SnapshotError(f"{path}: cannot read the session checkpoint ({type(exc).__name__}: {str(exc)[:200]})") from None
    if not isinstance(checkpoint, SessionCheckpoint):
        raise SnapshotError(f"{path}: not a session checkpoint of this version")
    try:
        _check_tree(checkpoint, {id(o) for o in shared.values()}, _plain_templates(world))
        _check_fits_world(checkpoint, world)
        _check_sense(checkpoint, world)
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


def _check_tree(root: SessionCheckpoint, shared: set[int], templates: dict[type, Any] | None = None) -> None:
    """Every object reachable from ``root`` is a plain value, a container, a numeric array, a
    numpy scalar, a shared object of the world or an instance of a listed class with exactly its
    declared fields; pydantic models are valid; nesting is at most :data:`MAX_DEPTH` deep and
    has no cycle; then every dataclass field is of its annotated type, and every instance of a
    listed plain class (no declared fields: the navigators, the priority keeper) has the
    attributes of its template in ``templates`` (the world's own instance), each of the
    template's type where the template's is not None. Iterative: a hostile tree cannot exhaust
    the interpreter's stack here."""
    listed = frozenset(_resolve_classes().values())
    done: set[int] = set(shared)
    on_path: set[int] = set()
    stack: list[tuple[Any, bool]] = [(root, False)]
    typed: list[Any] = []  # dataclass instances: their field types are checked once the tree is
    plain: list[Any] = []  # instances of listed plain classes: checked against ``templates``
    while stack:
        obj, leaving = stack.pop()
        key = id(obj)
        if leaving:
            on_path.discard(key)
            done.add(key)
            continue
        if key in done or isinstance(obj, (*_PLAIN_TYPES, np.generic)):
            continue
        if key in on_path:
            raise SnapshotError("the checkpoint's objects refer back to themselves")
        if len(on_path) >= MAX_DEPTH:
            raise SnapshotError(f"the checkpoint nests objects more than {MAX_DEPTH} levels deep")
        if isinstance(obj, np.ndarray):
            if obj.dtype.hasobject:
                raise SnapshotError("the checkpoint holds an array of objects")
            done.add(key)
            continue
        on_path.add(key)
        stack.append((obj, True))
        stack.extend((child, False) for child in _children(obj, listed))
        if dataclasses.is_dataclass(obj):
            typed.append(obj)
        elif type(obj) in listed and not isinstance(obj, BaseModel):
            plain.append(obj)
    _check_field_types(typed)
    _check_plain_objects(plain, templates)


def _children(obj: Any, listed: frozenset[type]) -> list[Any]:
    kind = type(obj)
    if kind in _CONTAINERS:
        if kind is dict:
            return [*obj.keys(), *obj.values()]
        return list(obj)
    if kind not in listed:
        raise SnapshotError(f"the checkpoint holds a {kind.__name__[:60]}, which a checkpoint may not hold")
    state = vars(obj)
    if isinstance(obj, BaseModel):
        model = type(obj)
        fields = set(model.model_fields)
        fields_set = obj.__pydantic_fields_set__
        if set(state) != fields or type(fields_set) is not set or not fields_set <= fields:
            raise SnapshotError(f"a {kind.__name__} with other fields than its own")
        # None is what pydantic stores for a model without extra or private values (ours have
        # neither); anything else, even a falsy False or {}, is a forged slot
        if obj.__pydantic_extra__ is not None or obj.__pydantic_private__ is not None:
            raise SnapshotError(f"a {kind.__name__} with values besides its fields")
        try:
            model.model_validate(state)
        except ValidationError as exc:
            err = exc.errors()[0]
            where, message = problem_field(err), problem_message(err)
            raise SnapshotError(f"a {kind.__name__} whose field {where} is invalid ({message})") from None
        return list(state.values())
    if dataclasses.is_dataclass(obj) and set(state) != {f.name for f in dataclasses.fields(obj)}:
        raise SnapshotError(f"a {kind.__name__} with other fields than its own")
    return [*state.keys(), *state.values()]


def _plain_templates(world: World) -> dict[type, Any]:
    """The instances of listed plain classes that ``world`` holds (its navigator and the objects
    under it), one per class: what a checkpoint's instances of those classes are checked against."""
    listed = frozenset(_resolve_classes().values())
    out: dict[type, Any] = {}
    stack: list[Any] = [world.navigator]
    while stack:
        obj = stack.pop()
        kind = type(obj)
        if kind in out or kind not in listed or dataclasses.is_dataclass(obj) or isinstance(obj, BaseModel):
            continue
        out[kind] = obj
        stack.extend(vars(obj).values())
    return out


def _check_plain_objects(objects: list[Any], templates: dict[type, Any] | None) -> None:
    """Each instance of a listed plain class has its template's attributes, of its types."""
    if templates is None:
        return
    for obj in objects:
        kind = type(obj)
        template = templates.get(kind)
        if template is None:
            raise SnapshotError(f"the checkpoint holds a {kind.__name__}, which this run's world has none of")
        mine, theirs = vars(obj), vars(template)
        if set(mine) != set(theirs):
            raise SnapshotError(f"a {kind.__name__} with other attributes than its own")
        hints = _init_hints(kind)
        for name, expected in theirs.items():
            value = mine[name]
            if name in hints and not _fits(value, hints[name]):
                raise SnapshotError(
                    f"a {kind.__name__} whose attribute {name} is not {_hint_name(hints[name])}"
                )
            if expected is None or value is None or type(value) is type(expected):
                continue
            if _fits(value, float) and _fits(expected, float):
                continue
            raise SnapshotError(
                f"a {kind.__name__} whose attribute {name} is a {type(value).__name__[:40]}, not {type(expected).__name__}"
            )


_INIT_HINTS: dict[type, dict[str, Any]] = {}


def _init_hints(kind: type) -> dict[str, Any]:
    """The annotations a plain class gives its attributes in its own ``__init__``
    (``self._rank: dict[Agent, float] = {}``), resolved in the class's module: so a checkpoint's
    navigator or priority keeper is checked item by item, as a dataclass's fields are, and a
    forged None among a dict's floats is refused at load instead of stopping the resumed run.
    Read from the project's own source (never from the file); an annotation that does not
    resolve at run time (a name imported for type checking only) is left to the template check.
    Cached per class."""
    if kind in _INIT_HINTS:
        return _INIT_HINTS[kind]
    found: dict[str, str] = {}
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(vars(kind)["__init__"])))
    except (OSError, TypeError, SyntaxError, KeyError):  # no source (a frozen build) or no __init__ of its own: the template check only
        tree = None
    for node in ast.walk(tree) if tree is not None else ():
        if not isinstance(node, ast.AnnAssign):
            continue
        target = node.target
        if isinstance(target, ast.Attribute) and isinstance(target.value, ast.Name) and target.value.id == "self":
            found[target.attr] = ast.unparse(node.annotation)
    hints: dict[str, Any] = {}
    for name, text in found.items():
        holder = type("_Hint", (), {"__annotations__": {name: text}, "__module__": kind.__module__})
        try:
            hints[name] = typing.get_type_hints(holder)[name]
        except (NameError, TypeError, AttributeError, SyntaxError):
            continue
    _INIT_HINTS[kind] = hints
    return hints


def _check_field_types(objects: list[Any]) -> None:
    """Every field of each dataclass instance in ``objects`` is of its annotated type (after the
    tree is known to be acyclic and shallow)."""
    for obj in objects:
        kind = type(obj)
        for name, hint in _field_types(kind).items():
            value = vars(obj)[name]
            if not _fits(value, hint):
                raise SnapshotError(
                    f"a {kind.__name__} whose field {name} is a {type(value).__name__[:40]}, not {_hint_name(hint)}"
                )


_FIELD_TYPES: dict[type, dict[str, Any]] = {}


def _field_types(kind: type) -> dict[str, Any]:
    """The resolved annotation of each dataclass field of ``kind`` (cached)."""
    if kind not in _FIELD_TYPES:
        hints = typing.get_type_hints(kind)
        _FIELD_TYPES[kind] = {f.name: hints[f.name] for f in dataclasses.fields(kind)}
    return _FIELD_TYPES[kind]


_FITS_DEPTH = 8  # levels of a field's annotation checked (``dict[str, list[tuple[int, int]]]`` has 4)


def _fits(value: Any, hint: Any, depth: int = _FITS_DEPTH) -> bool:
    """Whether ``value`` is of the annotated type ``hint``. Containers are checked item by item
    (keys and values, every item of a list); instances of listed classes by their type (their
    own fields are checked when :func:`_check_tree` reaches them); an ``int`` passes for a
    ``float`` and numpy's scalars for Python's. Linear in the items, bounded in the annotation."""
    if depth <= 0 or hint is Any or hint is object:
        return True
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin is typing.Union or origin is types.UnionType:
        return any(_fits(value, arm, depth - 1) for arm in args)
    if origin is Literal:
        return any(type(value) is type(arm) and value == arm for arm in args)
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool | np.bool_)
    if hint is int:
        return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)
    if hint is float:
        return isinstance(value, float | int | np.floating | np.integer) and not isinstance(value, bool | np.bool_)
    if hint is Hashable:
        return _plain_key(value, _MAX_KEY_DEPTH)
    if hint is np.ndarray or origin is np.ndarray:
        return isinstance(value, np.ndarray) and _dtype_fits(value, args)
    if origin in (tuple, list, set, frozenset, dict):
        if type(value) is not origin:
            return False
        if origin is dict:
            key, item = args or (Any, Any)
            return all(_fits(k, key, depth - 1) and _fits(v, item, depth - 1) for k, v in value.items())
        if origin is tuple and args and args[-1] is not Ellipsis:
            return len(value) == len(args) and all(_fits(v, a, depth - 1) for v, a in zip(value, args, strict=True))
        item = args[0] if args else Any
        return all(_fits(v, item, depth - 1) for v in value)
    if isinstance(hint, type):
        return isinstance(value, hint)
    return True  # an annotation this check does not know: left to the pydantic and tree checks


def _dtype_fits(value: np.ndarray[Any, Any], args: tuple[Any, ...]) -> bool:
    """An array annotated ``NDArray[np.float64]`` holds float64 (a bare ``np.ndarray``: any numeric)."""
    if len(args) != 2:
        return True
    scalar = typing.get_args(args[1])
    return not scalar or not isinstance(scalar[0], type) or value.dtype.type is scalar[0]


def _hint_name(hint: Any) -> str:
    return (getattr(hint, "__name__", None) if isinstance(hint, type) else None) or str(hint).replace("typing.", "")[:80]


def _check_fits_world(checkpoint: SessionCheckpoint, world: World) -> None:
    """The checkpoint is of this run's characters: the world's names, in its order, as the keys
    of its per-character state, motion states and track buffers, each state named by its key."""
    names = list(world.characters)
    snap = checkpoint.world
    for what, keys in (
        ("characters", list(snap.characters)),
        ("motion states", list(snap.motion_states)),
        ("track buffers", list(snap.buffers.names)),
    ):
        if keys != names:
            raise SnapshotError(f"the checkpoint's {what} are {keys[:8]}, this run's characters are {names[:8]}")
    for name, state in snap.motion_states.items():
        if type(state) is not type(world.motion_states[name]):
            raise SnapshotError(f"the checkpoint's motion state of {name!r} is a {type(state).__name__[:40]}, this "
                                f"run's motion layer keeps a {type(world.motion_states[name]).__name__}")
    for name, state in snap.characters.items():
        if state.name != name:
            raise SnapshotError(f"the checkpoint's character {name!r} holds the state of {state.name!r}")
    for event_id, event in checkpoint.events.items():
        if event.event_id != event_id:
            raise SnapshotError(f"the checkpoint's event {event_id!r} holds event {event.event_id!r}")


def _check_sense(checkpoint: SessionCheckpoint, world: World) -> None:
    """Values of the right types that no run could have made (module doc): frames, step indices,
    event ids, characters, positions, grid cells and object names."""
    snap = checkpoint.world
    frame = snap.frame
    if frame < 0:
        raise SnapshotError(f"the checkpoint's world is at frame {frame} (frames count from 0)")

    def at(what: str, value: int | None, low: int = 0) -> None:
        if value is not None and not low <= value <= frame:
            raise SnapshotError(f"{what} is frame {value}, outside the frames so far [{low}, {frame}]")

    def count(what: str, value: int) -> None:
        if value < 0:
            raise SnapshotError(f"{what} is {value} (a count is 0 or more)")

    for what, value in (("the checkpoint's step count", checkpoint.steps),
                        ("its planning failures in a row", checkpoint.failures_in_a_row),
                        ("its count of event changes", checkpoint.changes),
                        ("its next planning frame", checkpoint.next_plan_frame),
                        ("its track buffers' base frame", snap.buffers.base),
                        ("its track buffers' length", snap.buffers.length)):
        count(what, value)
    if len(checkpoint.outcomes) != len(checkpoint.applied_frames):
        raise SnapshotError(f"the checkpoint has {len(checkpoint.outcomes)} planning outcomes and "
                            f"{len(checkpoint.applied_frames)} frames they were applied at")
    for (index, _), applied in zip(checkpoint.outcomes, checkpoint.applied_frames, strict=True):
        _step_index(f"an outcome's step {index}", index, checkpoint.steps)
        at(f"the frame step {index} was applied at", applied)
    for request in (checkpoint.in_flight, *checkpoint.more_in_flight):
        if request is not None:
            _step_index(f"the step in flight {request.index}", request.index, checkpoint.steps)
            at(f"the request frame of step {request.index}", request.frame)
    names = set(world.characters)
    for event_id, event in checkpoint.events.items():
        _step_index(f"event {event_id!r}'s step {event.index}", event.index, checkpoint.steps)
        at(f"the request frame of event {event_id!r}", event.requested_frame)
        at(f"the frame event {event_id!r} was applied at", event.applied_frame, event.requested_frame)
        at(f"the frame event {event_id!r} finished at", event.finished_frame, event.applied_frame)
        _members(f"event {event_id!r}", event.characters, names)
    for event_id, state in snap.events.items():
        if event_id not in checkpoint.events or state.event.event_id != event_id:
            raise SnapshotError(f"the checkpoint's world holds event {event_id!r}, which its story does not")
        _members(f"event {event_id!r}", (*state.members, *(a.character for a in state.event.assignments)), names)
        for assignment in state.event.assignments:
            _assignment(f"event {event_id!r}", assignment, world)
    for name, character in snap.characters.items():
        _character(name, character, snap.events, world)


def _step_index(what: str, index: int, steps: int) -> None:
    if not 0 <= index < steps:
        raise SnapshotError(f"{what} is not one of the {steps} steps taken")


def _members(what: str, members: Sequence[str], names: set[str]) -> None:
    strangers = sorted(set(members) - names)
    if strangers:
        raise SnapshotError(f"{what} names {strangers[:4]}, not characters of this run ({sorted(names)[:8]})")


def _character(name: str, character: Any, events: dict[str, Any], world: World) -> None:
    """One character's state: its event and pending event held, counts, angles, positions, cells."""
    for event_id in (character.event_id, character.pending[0] if character.pending is not None else None):
        if event_id is not None and event_id not in events:
            raise SnapshotError(f"the checkpoint's character {name!r} takes part in event {event_id!r}, "
                                "which its world does not hold")
    for field_name in ("phase_frame", "turn_frames", "stalled_frames", "replans"):
        if getattr(character, field_name) < 0:
            raise SnapshotError(f"the checkpoint's character {name!r} has {field_name} {getattr(character, field_name)}")
    for field_name in ("heading", "turn_from", "act_yaw"):
        value = getattr(character, field_name)
        if value is not None and not np.isfinite(value):
            raise SnapshotError(f"the checkpoint's character {name!r} has {field_name} {value}, not a finite angle")
    where = f"the checkpoint's character {name!r}"
    for field_name in ("xy", "anchor_xy", "seat_xy"):
        _point(f"{where}'s {field_name}", getattr(character, field_name), world)
    for field_name in ("anchor_cell", "goal_cell"):
        _cell(f"{where}'s {field_name}", getattr(character, field_name), world)
    for target in (character.target, character.pending[2] if character.pending is not None else None):
        if target is not None:
            _point(f"{where}'s stand target", target.xy, world)
            _cell(f"{where}'s stand target cell", target.cell, world)
    for assignment in (character.assignment, character.pending[1] if character.pending is not None else None):
        if assignment is not None:
            _assignment(where, assignment, world)


def _assignment(where: str, assignment: Any, world: World) -> None:
    _point(f"{where}: {assignment.character!r}'s target", assignment.target_xy, world)
    for field_name in ("seat", "focus"):
        obj = getattr(assignment, field_name)
        if obj is not None and obj not in world.scene.by_name:
            raise SnapshotError(f"{where}: {assignment.character!r}'s {field_name} is {str(obj)[:60]!r}, "
                                f"which scene {world.scene.name!r} has no object of")


def _point(what: str, value: Any, world: World) -> None:
    """``value`` (None, or an (x, y) point) is finite and within :data:`_OUTSIDE_M` of the floor."""
    if value is None:
        return
    xy = np.asarray(value, dtype=float)
    low = np.asarray(world.scene.bounds_min, dtype=float) - _OUTSIDE_M
    high = np.asarray(world.scene.bounds_max, dtype=float) + _OUTSIDE_M
    if xy.shape != (2,) or not np.isfinite(xy).all() or (xy < low).any() or (xy > high).any():
        shown = ", ".join(f"{v:.6g}" for v in xy.ravel()[:2])
        raise SnapshotError(f"{what} is ({shown}), not a point of the scene (x {low[0]:.6g}..{high[0]:.6g}, "
                            f"y {low[1]:.6g}..{high[1]:.6g})")


def _cell(what: str, cell: tuple[int, int] | None, world: World) -> None:
    if cell is None:
        return
    rows, cols = world.grid.free.shape[:2]
    if not (0 <= cell[0] < rows and 0 <= cell[1] < cols):
        raise SnapshotError(f"{what} is {cell}, off the navigation grid ({rows} x {cols} cells)")

"""A decoded checkpoint checked as a tree of typed objects, before it is trusted.

:func:`check_tree` walks every object reachable from the checkpoint (iteratively: a hostile
tree cannot exhaust the interpreter's stack): only listed instances, plain values and numeric
arrays, each listed instance with exactly its declared fields, pydantic models valid against
their schema, every dataclass field of the type its annotation gives (:func:`fits`: ``int``,
``str | None``, ``tuple[int, int]``, ``dict[str, CharacterState]``, an array of the annotated
dtype, ``Literal`` values...), every plain listed object (a navigator, the priority keeper) with
its template's attributes, at most :data:`MAX_DEPTH` levels deep and without a cycle.
:func:`plain_key` is the rule for dict keys and set items (the unpickler applies it too).

Reads the project's own classes and source only, never the file; every refusal is a
:class:`~storyteller.orchestrator.session.snapshot_errors.SnapshotError` with one line.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import textwrap
import types
import typing
from collections.abc import Hashable
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ValidationError

from storyteller.orchestrator.session.session_types import SessionCheckpoint
from storyteller.orchestrator.session.snapshot_errors import SnapshotError
from storyteller.sim.validation_text import problem_field, problem_message
from storyteller.sim.world.step import World

MAX_DEPTH = 48
"""Levels of nesting of the decoded objects at most (the checkpoints of the resume tests have 8)."""
MAX_KEY_DEPTH = 3  # tuples in tuples in a dict key or set item at most
_PLAIN_TYPES = (type(None), bool, int, float, complex, str, bytes)
_CONTAINERS = (tuple, list, dict, set, frozenset)


def plain_key(key: object, depth: int) -> bool:
    """Whether ``key`` is a plain value or a tuple of at most 64 of them, nested at most ``depth`` deep."""
    if isinstance(key, _PLAIN_TYPES):
        return True
    return type(key) is tuple and depth > 0 and len(key) <= 64 and all(plain_key(k, depth - 1) for k in key)


def check_tree(root: SessionCheckpoint, shared: set[int], listed: frozenset[type],
                templates: dict[type, object] | None = None) -> None:
    """Every object reachable from ``root`` is a plain value, a container, a numeric array, a
    numpy scalar, a shared object of the world or an instance of a ``listed`` class (:data:`~storyteller.orchestrator.session.snapshot_file.SNAPSHOT_CLASSES`) with exactly its
    declared fields; pydantic models are valid; nesting is at most :data:`MAX_DEPTH` deep and
    has no cycle; then every dataclass field is of its annotated type, and every instance of a
    listed plain class (no declared fields: the navigators, the priority keeper) has the
    attributes of its template in ``templates`` (the world's own instance), each of the
    template's type where the template's is not None. Iterative: a hostile tree cannot exhaust
    the interpreter's stack here."""
    done: set[int] = set(shared)
    on_path: set[int] = set()
    stack: list[tuple[object, bool]] = [(root, False)]
    typed: list[object] = []  # dataclass instances: their field types are checked once the tree is
    plain: list[object] = []  # instances of listed plain classes: checked against ``templates``
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


def _children(obj: object, listed: frozenset[type]) -> list[object]:
    kind = type(obj)
    if kind in _CONTAINERS and isinstance(obj, _CONTAINERS):  # exact types only; the isinstance narrows
        if isinstance(obj, dict):
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


def plain_templates(world: World, listed: frozenset[type]) -> dict[type, object]:
    """The instances of listed plain classes that ``world`` holds (its navigator and the objects
    under it), one per class: what a checkpoint's instances of those classes are checked against."""
    out: dict[type, object] = {}
    stack: list[object] = [world.navigator]
    while stack:
        obj = stack.pop()
        kind = type(obj)
        if kind in out or kind not in listed or dataclasses.is_dataclass(obj) or isinstance(obj, BaseModel):
            continue
        out[kind] = obj
        stack.extend(vars(obj).values())
    return out


def _check_plain_objects(objects: list[object], templates: dict[type, object] | None) -> None:
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
            if name in hints and not fits(value, hints[name]):
                raise SnapshotError(
                    f"a {kind.__name__} whose attribute {name} is not {_hint_name(hints[name])}"
                )
            if expected is None or value is None or type(value) is type(expected):
                continue
            if fits(value, float) and fits(expected, float):
                continue
            raise SnapshotError(
                f"a {kind.__name__} whose attribute {name} is a {type(value).__name__[:40]}, not {type(expected).__name__}"
            )


_INIT_HINTS: dict[type, dict[str, object]] = {}


def _init_hints(kind: type) -> dict[str, object]:
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
    hints: dict[str, object] = {}
    for name, text in found.items():
        holder = type("_Hint", (), {"__annotations__": {name: text}, "__module__": kind.__module__})
        try:
            hints[name] = typing.get_type_hints(holder)[name]
        except (NameError, TypeError, AttributeError, SyntaxError):
            continue
    _INIT_HINTS[kind] = hints
    return hints


def _check_field_types(objects: list[object]) -> None:
    """Every field of each dataclass instance in ``objects`` is of its annotated type (after the
    tree is known to be acyclic and shallow)."""
    for obj in objects:
        kind = type(obj)
        for name, hint in _field_types(kind).items():
            value = vars(obj)[name]
            if not fits(value, hint):
                raise SnapshotError(
                    f"a {kind.__name__} whose field {name} is a {type(value).__name__[:40]}, not {_hint_name(hint)}"
                )


_FIELD_TYPES: dict[type, dict[str, object]] = {}


def _field_types(kind: type) -> dict[str, object]:
    """The resolved annotation of each dataclass field of ``kind`` (cached)."""
    if kind not in _FIELD_TYPES:
        hints = typing.get_type_hints(kind)
        _FIELD_TYPES[kind] = {f.name: hints[f.name] for f in dataclasses.fields(kind)}
    return _FIELD_TYPES[kind]


_FITS_DEPTH = 8  # levels of a field's annotation checked (``dict[str, list[tuple[int, int]]]`` has 4)


def fits(value: object, hint: object, depth: int = _FITS_DEPTH) -> bool:
    """Whether ``value`` is of the annotated type ``hint``. Containers are checked item by item
    (keys and values, every item of a list); instances of listed classes by their type (their
    own fields are checked when :func:`check_tree` reaches them); an ``int`` passes for a
    ``float`` and numpy's scalars for Python's. Linear in the items, bounded in the annotation."""
    if depth <= 0 or hint is Any or hint is object:
        return True
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin is typing.Union or origin is types.UnionType:
        return any(fits(value, arm, depth - 1) for arm in args)
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
        return plain_key(value, MAX_KEY_DEPTH)
    if hint is np.ndarray or origin is np.ndarray:
        return isinstance(value, np.ndarray) and _dtype_fits(value, args)
    if origin in (tuple, list, set, frozenset, dict):
        if type(value) is not origin or not isinstance(value, _CONTAINERS):  # the isinstance narrows
            return False
        if isinstance(value, dict):  # origin is dict
            key, item = args or (Any, Any)
            return all(fits(k, key, depth - 1) and fits(v, item, depth - 1) for k, v in value.items())
        if origin is tuple and args and args[-1] is not Ellipsis:
            return len(value) == len(args) and all(fits(v, a, depth - 1) for v, a in zip(value, args, strict=True))
        item = args[0] if args else Any
        return all(fits(v, item, depth - 1) for v in value)
    if isinstance(hint, type):
        return isinstance(value, hint)
    return True  # an annotation this check does not know: left to the pydantic and tree checks


def _dtype_fits(value: np.ndarray[Any, Any], args: tuple[Any, ...]) -> bool:
    """An array annotated ``NDArray[np.float64]`` holds float64 (a bare ``np.ndarray``: any numeric)."""
    if len(args) != 2:
        return True
    scalar = typing.get_args(args[1])
    return not scalar or not isinstance(scalar[0], type) or value.dtype.type is scalar[0]


def _hint_name(hint: object) -> str:
    return (getattr(hint, "__name__", None) if isinstance(hint, type) else None) or str(hint).replace("typing.", "")[:80]

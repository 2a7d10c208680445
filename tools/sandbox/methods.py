"""The methods of built-in types that event programs may call (``str.split``, ``list.append``...).

``METHODS`` maps each of str / list / dict / tuple / set / frozenset to its allow-listed
methods; anything else (``str.format``, ``list.__class__``...) does not exist for a program.
A method that can grow a value checks the size first (``list.extend``, ``str.replace``,
``set.union``); the others are called and their result bounded.
"""

from __future__ import annotations

from collections.abc import Callable, Container, Sequence, Sized
from typing import TypeAlias, TypeVar, cast

from storyteller.tools.sandbox.boundary import CONTAINER_TYPES, check_key, is_int, materialize, type_name
from storyteller.tools.sandbox.budget import SET_ITEM_BYTES, str_bytes
from storyteller.tools.sandbox.builtin_functions import Host, arity, dict_from, sort_items, words
from storyteller.tools.sandbox.errors import Line, ProgramRuntimeError
from storyteller.tools.sandbox.operators import check_hash_spread, comparison_work
from storyteller.tools.value_text import show

_R = TypeVar("_R")

Method: TypeAlias = Callable[[Host, _R, list[object], dict[str, object], Line], object]
"""A method of receiver type ``_R``: (interpreter, receiver, positional args, keyword args,
program line) -> value."""
MethodImpl: TypeAlias = Method[object]
"""A method as ``METHODS`` holds it (the receiver's type is the table's key)."""


def _on(impl: Method[_R]) -> MethodImpl:
    """A method for ``METHODS[t]``: the interpreter looks methods up by the receiver's exact
    type, so a method registered under ``t`` only ever receives a ``t``."""
    return cast(MethodImpl, impl)


def _plain(name: str, key_arg: bool = False, searches: bool = False) -> MethodImpl:
    """A method that cannot grow anything much: call it, then bound the result.

    ``key_arg``: the first argument is hashed (dict/set key); ``searches``: it is compared
    with every item (list.index / count / remove).
    """

    def impl(
        host: Host, obj: Sized, args: list[object], kwargs: dict[str, object], line: Line
    ) -> object:
        if key_arg and args:
            check_key(args[0], line)
            if (
                name in _RAISES_KEY
                and len(args) == 1
                and args[0] not in cast("Container[object]", obj)
            ):
                # CPython's KeyError renders repr(key) in full: report it bounded instead
                raise ProgramRuntimeError(
                    f"{type_name(obj)}.{name}(): {show(args[0])} is not in the {type_name(obj)}",
                    line=line,
                )
        if searches and args:
            comparison_work(host.meter, line, [args[0]], repeat=len(obj))
            if name == "index" and not _contains_in(obj, args, line):
                # CPython's "%R is not in list" renders the value in full: report it bounded
                raise ProgramRuntimeError(
                    f"{type_name(obj)}.index(): {show(args[0])} is not in the {type_name(obj)}",
                    line=line,
                )
        result = getattr(obj, name)(*args, **kwargs)
        t = type(result)
        if t is str:
            host.meter.check_str(len(result), line)
        elif t in CONTAINER_TYPES:
            host.meter.check_len(len(result), line)
            if type(obj) is str:  # split / partition: new strings
                host.meter.charge(sum(str_bytes(len(p)) for p in result), line)
        elif name in ("keys", "values", "items"):
            result = list(result)
            host.meter.check_len(len(result), line)
        return result

    return _on(impl)


_RAISES_KEY = frozenset({"pop", "remove"})
"""Methods that raise ``KeyError(key)`` for a missing key (``dict.pop``, ``set.remove``)."""


def _contains_in(obj: Sized, args: list[object], line: Line) -> bool:
    """Whether ``obj.index(*args)`` would find its value (``args``: value[, start[, stop]])."""
    bounds: list[int] = []
    for b in args[1:3]:
        if not is_int(b):
            raise ProgramRuntimeError("index() needs integer start and stop", line=line)
        bounds.append(b)
    haystack = cast("Sequence[object]", obj)
    if bounds:
        haystack = haystack[slice(*bounds)]
    return args[0] in haystack


def _str_join(
    host: Host, obj: str, args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    arity("str.join", args, kwargs, line, 1, 1)
    parts: list[str] = []
    for p in materialize(args[0], host.meter, line, "join()"):
        if type(p) is not str:
            raise ProgramRuntimeError(
                f"str.join() needs strings, found '{type_name(p)}' (use str(x) first)", line=line
            )
        parts.append(p)
    host.meter.check_str(sum(map(len, parts)) + len(obj) * max(len(parts) - 1, 0), line)
    return obj.join(parts)


def _str_replace(
    host: Host, obj: str, args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    arity("str.replace", args, kwargs, line, 2, 3)
    old, new = args[0], args[1]
    count = args[2] if len(args) > 2 else -1
    if type(old) is not str or type(new) is not str or not is_int(count):
        raise ProgramRuntimeError(
            "str.replace() needs (old: str, new: str[, count: int])", line=line
        )
    hits = len(obj) + 1 if old == "" else obj.count(old)
    if count >= 0:
        hits = min(hits, count)
    host.meter.check_str(len(obj) + hits * (len(new) - len(old)), line)
    return obj.replace(old, new, count)


def _list_append(
    host: Host, obj: list[object], args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    arity("list.append", args, kwargs, line, 1, 1)
    host.meter.check_len(len(obj) + 1, line, added=1)
    obj.append(args[0])
    return None


def _list_insert(
    host: Host, obj: list[object], args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    arity("list.insert", args, kwargs, line, 2, 2)
    index = args[0]
    if not is_int(index):
        raise ProgramRuntimeError("list.insert() needs an integer index", line=line)
    host.meter.check_len(len(obj) + 1, line, added=1)
    obj.insert(index, args[1])
    return None


def _list_extend(
    host: Host, obj: list[object], args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    arity("list.extend", args, kwargs, line, 1, 1)
    items = materialize(args[0], host.meter, line)
    host.meter.check_len(len(obj) + len(items), line, added=len(items))
    obj.extend(items)
    return None


def _list_sort(
    host: Host, obj: list[object], args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    arity("list.sort", args, kwargs, line, 0, 0, ("key", "reverse"))
    obj[:] = sort_items(host, list(obj), kwargs.get("key"), kwargs.get("reverse", False), line)
    return None


def _dict_update(
    host: Host,
    obj: dict[object, object],
    args: list[object],
    kwargs: dict[str, object],
    line: Line,
) -> object:
    arity("dict.update", args, kwargs, line, 0, 1, tuple(kwargs))
    other = dict_from(host, args, kwargs, line)
    host.meter.check_len(len(obj) + len(other), line)
    check_hash_spread([*obj, *other], host.meter, line)
    obj.update(other)
    return None


def _dict_setdefault(
    host: Host,
    obj: dict[object, object],
    args: list[object],
    kwargs: dict[str, object],
    line: Line,
) -> object:
    arity("dict.setdefault", args, kwargs, line, 1, 2)
    check_key(args[0], line)
    host.meter.check_len(len(obj) + 1, line, added=1)
    return obj.setdefault(args[0], args[1] if len(args) > 1 else None)


def _set_add(
    host: Host, obj: set[object], args: list[object], kwargs: dict[str, object], line: Line
) -> object:
    arity("set.add", args, kwargs, line, 1, 1)
    check_key(args[0], line)
    host.meter.check_len(len(obj) + 1, line, added=1)
    obj.add(args[0])
    return None


def _set_combine(name: str) -> MethodImpl:
    def impl(
        host: Host,
        obj: set[object] | frozenset[object],
        args: list[object],
        kwargs: dict[str, object],
        line: Line,
    ) -> object:
        arity(f"set.{name}", args, kwargs, line, 0, 10)
        others = [materialize(a, host.meter, line) for a in args]
        host.meter.check_len(len(obj) + sum(map(len, others)), line, item_bytes=SET_ITEM_BYTES)
        for other in others:
            for item in other:
                check_key(item, line)
        check_hash_spread([*obj, *(item for other in others for item in other)], host.meter, line)
        return getattr(obj, name)(*others)

    return _on(impl)


_STR_PLAIN = tuple(
    words(
        """
    lower upper strip lstrip rstrip capitalize title casefold swapcase startswith endswith
    find rfind index rindex count isdigit isalpha isalnum isspace islower isupper isnumeric
    isdecimal istitle removeprefix removesuffix partition rpartition split rsplit splitlines
    """
    )
)


def _set_copy(
    host: Host,
    obj: set[object] | frozenset[object],
    args: list[object],
    kwargs: dict[str, object],
    line: Line,
) -> object:
    arity("set.copy", args, kwargs, line, 0, 0)
    check_hash_spread(list(obj), host.meter, line)
    host.meter.check_len(len(obj), line)
    return obj.copy()


_SET_COMBINE = (
    "union",
    "intersection",
    "difference",
    "symmetric_difference",
    "issubset",
    "issuperset",
    "isdisjoint",
)

METHODS: dict[type, dict[str, MethodImpl]] = {
    str: {
        **{n: _plain(n) for n in _STR_PLAIN},
        "join": _on(_str_join),
        "replace": _on(_str_replace),
    },
    list: {
        **{n: _plain(n) for n in ("pop", "reverse", "copy", "clear")},
        **{n: _plain(n, searches=True) for n in ("remove", "index", "count")},
        "append": _on(_list_append),
        "insert": _on(_list_insert),
        "extend": _on(_list_extend),
        "sort": _on(_list_sort),
    },
    dict: {
        **{n: _plain(n) for n in ("keys", "values", "items", "copy", "clear", "popitem")},
        "get": _plain("get", key_arg=True),
        "pop": _plain("pop", key_arg=True),
        "setdefault": _on(_dict_setdefault),
        "update": _on(_dict_update),
    },
    tuple: {n: _plain(n, searches=True) for n in ("index", "count")},
    set: {
        **{n: _plain(n) for n in ("pop", "clear")},
        "copy": _on(_set_copy),
        **{n: _plain(n, key_arg=True) for n in ("remove", "discard")},
        **{n: _set_combine(n) for n in _SET_COMBINE},
        "add": _on(_set_add),
        "update": _set_combine("update"),
    },
    frozenset: {
        "copy": _on(_set_copy),
        **{n: _set_combine(n) for n in _SET_COMBINE},
    },
}

"""Strict, bounded JSON for scene files, with errors that name the file, the object and the field.

``read_json(path, layout)``: the file read only up to ``MAX_SCENE_FILE_BYTES``
(``storyteller.sim.bounded_files``: a regular file, never a device or a FIFO), UTF-8 text, nested at most ``MAX_SCENE_JSON_DEPTH``
deep, no NaN / Infinity (nor numbers that overflow to infinity, nor integers over 300 digits),
no duplicate keys, at most ``storyteller.sim.bounded_files.MAX_OBJECT_KEYS`` keys in one object. Every problem is a ``SceneFileError``; a non-finite number is reported with
the object holding it, named as the scene loaders (``storyteller.sim.scene.files``) name objects.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from storyteller.sim.bounded_files import (
    MAX_OBJECT_KEYS,
    BoundedFileError,
    json_depth_exceeds,
    read_bounded_bytes,
)
from storyteller.sim.scene.errors import SceneFileError

MAX_SCENE_FILE_BYTES = 16 * 1024 * 1024
"""Bytes of one scene JSON file (a reference ``objects.json`` takes about 1 KB per object)."""
MAX_SCENE_JSON_DEPTH = 32
"""Nesting of a scene JSON file (the formats need 4)."""


def short_repr(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters, for quoting a bad value in an error."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def read_text(path: Path) -> str:
    """The file's text; a clear error for missing, unreadable, empty or binary files."""
    try:
        raw = read_bounded_bytes(path, MAX_SCENE_FILE_BYTES, str(path))
    except BoundedFileError as exc:
        raise SceneFileError(path, exc.problem) from None
    if not raw.strip():
        raise SceneFileError(path, "file is empty")
    if b"\x00" in raw[:4096]:
        raise SceneFileError(path, "file holds binary data, expected UTF-8 JSON text")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise SceneFileError(
            path, f"file is not UTF-8 text (bad byte at offset {exc.start})"
        ) from None


def parse_json(path: Path, text: str, layout: str | None = None) -> Any:
    """Strict JSON: no NaN / Infinity (nor numbers that overflow to infinity), no duplicate keys.

    A non-finite number is reported with the object and field holding it: ``layout`` says how
    objects are found, ``"scene"`` (the project format, objects under ``"objects"``),
    ``"objects"`` (a reference ``objects.json`` list) or None (no objects; field only).
    """
    if json_depth_exceeds(text.encode("utf-8", "surrogatepass"), MAX_SCENE_JSON_DEPTH):
        raise SceneFileError(path, f"JSON nested more than {MAX_SCENE_JSON_DEPTH} levels deep")
    try:
        data = json.loads(
            text,
            parse_constant=_NonFinite,
            parse_float=_finite_float,
            parse_int=_bounded_int,
            object_pairs_hook=_unique_keys,
        )
    except json.JSONDecodeError as exc:
        what = (
            "JSON ends early (truncated file?)" if exc.pos >= len(text.rstrip()) else "invalid JSON"
        )
        raise SceneFileError(
            path, f"{what} at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        ) from None
    except _JsonValueError as exc:
        raise SceneFileError(path, str(exc)) from None
    except RecursionError:
        raise SceneFileError(path, "JSON nested too deeply") from None
    found = _first_non_finite(data)
    if found is not None:
        loc, bad = found
        obj, field = _locate(data, loc, layout)
        raise SceneFileError(path, bad.message, obj=obj, field=field)
    return data


def read_json(path: Path, layout: str | None = None) -> Any:
    return parse_json(path, read_text(path), layout)


class _JsonValueError(ValueError):
    pass


class _NonFinite:
    """Stands for a number JSON may not hold (NaN, Infinity, 1e999) until it is located."""

    __slots__ = ("message",)

    def __init__(self, text: str, message: str | None = None) -> None:
        self.message = message or (
            f"non-finite number '{text[:40]}' is not allowed (numbers must be finite)"
        )


def _finite_float(text: str) -> float | _NonFinite:
    value = float(text)
    if not math.isfinite(value):
        return _NonFinite(text, f"number {text[:40]} is too large (numbers must be finite)")
    return value


_MAX_INT_DIGITS = 300


def _bounded_int(text: str) -> int | _NonFinite:
    if len(text) > _MAX_INT_DIGITS:
        return _NonFinite(
            text, f"number {text[:40]}... has {len(text)} digits (too large for a scene)"
        )
    return int(text)


def _first_non_finite(data: Any) -> tuple[list[str | int], _NonFinite] | None:
    """Where the first (in file order) non-finite number is, as a key / index path."""
    stack: list[tuple[list[str | int], Any]] = [([], data)]
    while stack:
        loc, value = stack.pop()
        if isinstance(value, _NonFinite):
            return loc, value
        if isinstance(value, dict):
            stack.extend(([*loc, k], v) for k, v in reversed(value.items()))
        elif isinstance(value, list):
            stack.extend(([*loc, i], v) for i, v in reversed(list(enumerate(value))))
    return None


def _locate(data: Any, loc: list[str | int], layout: str | None) -> tuple[str | None, str | None]:
    """(object name, dotted field) of a key / index path, as other errors name them."""
    obj: str | None = None
    rest = loc
    if layout == "scene" and len(loc) >= 2 and loc[0] == "objects" and isinstance(loc[1], int):
        raw = data["objects"][loc[1]]
        name = raw.get("name") if isinstance(raw, dict) else None
        obj = name if isinstance(name, str) and name else f"#{loc[1]}"
        rest = loc[2:]
    elif layout == "objects" and loc and isinstance(loc[0], int):
        raw = data[loc[0]]
        obj = reference_name(raw, loc[0])
        rest = loc[1:]
    while rest and isinstance(rest[-1], int):  # "center", not "center.0"
        rest = rest[:-1]
    return obj, ".".join(map(str, rest)) or None


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    if len(pairs) > MAX_OBJECT_KEYS:
        raise _JsonValueError(f"an object of {len(pairs)} keys (at most {MAX_OBJECT_KEYS} allowed)")
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _JsonValueError(f"key '{key}' appears twice in one JSON object")
        out[key] = value
    return out


def reference_name(raw: Any, i: int) -> str:
    """``<label>_<idx>`` of a reference entry, ``#i`` when it has no usable label and idx."""
    label = raw.get("label") if isinstance(raw, dict) else None
    idx = raw.get("idx") if isinstance(raw, dict) else None
    ok_idx = isinstance(idx, int) and not isinstance(idx, bool)
    return f"{label}_{idx}" if isinstance(label, str) and label and ok_idx else f"#{i}"

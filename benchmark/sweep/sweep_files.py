"""Reading and writing a sweep folder that may come from someone else.

``bench score`` re-scores anyone's published sweep, so every file of a sweep folder is read
and written as a run folder's are (issue 22):

- :func:`read_json_model` and :func:`read_json_lines` read a file within a byte cap, refuse a
  symbolic link, a FIFO or a device (``storyteller.sim.bounded_files``: nothing blocks, nothing is read
  through a link), parse JSON with bounded nesting, integer size and finite numbers, and
  validate into the given pydantic model;
- :func:`write_sweep_file` replaces a file through a fresh temporary name
  (``storyteller.sim.no_follow_writes.write_file``): a link planted at the name is replaced, its target
  untouched; :func:`sweep_folder` makes a sub-folder and refuses a link in its place;
  :func:`append_line` appends without following a link or writing into a hard-linked file.

Every failure to read is a :class:`SweepFileError` whose ``str()`` is one line naming the file
(and the line, the field); the bench commands print it with exit code 2. Refused writes are
``OSError`` naming the file (the commands' one line as well).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TypeVar

from pydantic import BaseModel, ValidationError

from storyteller.sim.bounded_files import BoundedFileError, load_bounded_json, read_bounded_bytes
from storyteller.sim.no_follow_writes import append_durably, make_folder, open_append, write_file
from storyteller.sim.validation_text import user_error

M = TypeVar("M", bound=BaseModel)

MAX_SWEEP_FILE_BYTES = 256 << 20
"""Bytes of the largest sweep file read (``results.jsonl`` of 100,000 runs is about 60 MB)."""
MAX_JSON_DEPTH = 32
"""JSON nesting of a sweep file at most (``sweep.json``, a result line, a description: under 8)."""


class SweepFileError(ValueError):
    """A sweep folder's file that cannot be read or does not hold what it should (one line)."""


def read_sweep_bytes(path: Path, max_bytes: int = MAX_SWEEP_FILE_BYTES) -> bytes:
    try:
        return read_bounded_bytes(path, max_bytes, str(path), follow_symlinks=False)
    except BoundedFileError as exc:
        raise SweepFileError(str(exc)) from None


def parse_json_model(data: bytes, model: type[M], where: str) -> M:
    """``data`` (one JSON document) validated as ``model``; ``where`` names it in the error."""
    try:
        return model.model_validate(load_bounded_json(data, MAX_JSON_DEPTH, where))
    except BoundedFileError as exc:
        raise SweepFileError(str(exc)) from None
    except ValidationError as exc:
        raise SweepFileError(user_error(where, exc)) from None


def read_json_model(path: Path, model: type[M]) -> M:
    """The file ``path`` as ``model`` (see the module docstring)."""
    return parse_json_model(read_sweep_bytes(path), model, str(path))


def read_json_lines(path: Path, model: type[M]) -> list[M]:
    """Every complete line of ``path`` as ``model``; a torn last line (no newline: a kill in the
    middle of an append) is left out. A missing file holds no line."""
    if not (path.exists() or path.is_symlink()):
        return []
    lines = read_sweep_bytes(path).split(b"\n")
    lines.pop()  # after the last newline: empty, or a torn line
    return [parse_json_model(line, model, f"{path}: line {i}") for i, line in enumerate(lines, 1) if line.strip()]


def write_sweep_file(path: Path, data: bytes) -> None:
    """Replace ``path`` with ``data``, durably, never through a link planted there."""
    write_file(path, data, durable=True)


def sweep_folder(out: Path, *parts: str) -> Path:
    """The sub-folder ``out/part/...`` of the sweep folder ``out``, each level made when missing;
    a link at any level is refused (``OSError``), so nothing is made or written outside ``out``."""
    path = out
    for part in parts:
        path = make_folder(path / part)
    return path


def append_line(path: Path, line: bytes) -> None:
    """Append ``line`` with one ``os.write`` and fsync it (a regular file with one link only)."""
    append_durably(path, line)


def cut_torn_line(path: Path) -> None:
    """Cut a torn last line (no newline) off ``path`` before appending to it."""
    if not (path.exists() or path.is_symlink()):
        return
    data = read_sweep_bytes(path)
    if data and not data.endswith(b"\n"):
        fd = open_append(path)
        try:
            os.ftruncate(fd, data.rfind(b"\n") + 1)
        finally:
            os.close(fd)

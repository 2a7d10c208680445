"""Reading a file the project did not necessarily write: bounded in bytes, in nesting, in numbers.

Every reader of a file that may come from someone else (a shared run folder, a downloaded
scene, a trace) goes through two functions:

- :func:`read_bounded_bytes` reads at most ``max_bytes`` bytes of a *regular* file: it opens
  without blocking (a FIFO never hangs the reader), refuses anything that is not a regular file
  (``/dev/zero``, a FIFO, a folder), optionally refuses a symbolic link (``O_NOFOLLOW``), and
  reads ``max_bytes + 1`` bytes at most, so a file that grows or lies about its size still costs
  no more than the cap;
- :func:`read_bounded_tail` reads, under the same checks, only what a file gained since a read
  that ended at a given byte (a reader polling a growing file), or the whole file again when it
  is another file or shorter, saying which;
- :func:`load_bounded_json` parses JSON text into plain Python values with a nesting depth of at
  most ``max_depth`` (deeper text is refused before a value is built from it, so no
  ``RecursionError`` reaches the caller), integers of at most :data:`MAX_INT_DIGITS` digits,
  finite numbers only (``NaN``, ``Infinity`` and ``1e999`` are refused), no key given twice
  in one object (readers disagree on which value wins) and at most :data:`MAX_OBJECT_KEYS` keys
  in one object;
- :func:`load_bounded_toml` parses TOML text (UTF-8) with keys of at most
  :data:`MAX_TOML_KEY_PARTS` dotted parts, counted before the parser sees them (``tomllib``
  spends time quadratic in a dotted key's parts, and in a table header's parts times its keys:
  a key of 50,000 parts took 1.5 GB, a header of 30,000 parts over 60,000 keys minutes);
- :func:`json_keys_exceed` tells, without parsing, whether a JSON text holds more keys than
  allowed, for the readers that hand bytes straight to pydantic (a model that forbids unknown
  keys builds one error per key: 1.2 million of them took 1.7 GB).

Both raise :class:`BoundedFileError` whose ``str()`` is one line naming the file (``what``)
and what was wrong; nothing else escapes them (``OSError``, ``UnicodeDecodeError``,
``JSONDecodeError``, ``RecursionError`` and ``MemoryError`` are all turned into it). The work
is linear in the bytes given. Validation into typed models is the caller's next step.
"""

from __future__ import annotations

import errno
import io
import json
import math
import os
import re
import stat
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any
from zlib import error as zlib_error

import numpy as np

MAX_INT_DIGITS = 64
"""Digits of the longest integer :func:`load_bounded_json` accepts (a 64-bit seed has 20)."""

MAX_OBJECT_KEYS = 10_000
"""Keys of one JSON object at most (the project's files have tens; an LLM reply a few hundred)."""

MAX_TOML_KEY_PARTS = 16
"""Dotted parts of one TOML key or table header at most (the project's configs use 3)."""

_READ_CHUNK = 1 << 20  # bytes per read() call
_DEPTH_CHUNK = 1 << 22  # brackets per step of the depth scan (32 MiB of running depths)

# A JSON string, closed or running to the end of the text; it never fails to match at a quote,
# so a scan over the text is linear (a pattern that must find the closing quote is quadratic on
# a quote followed by many escaped quotes). Runs of plain characters are taken whole (the loop
# "unrolled"): 2.6 times faster than one alternation per character on a 50 MB story.json.
_STRING = re.compile(rb'"[^"\\]*+(?:\\.[^"\\]*+)*+"?', re.DOTALL)
_NOT_BRACKETS = bytes(c for c in range(256) if c not in b"[]{}")  # deleted by bytes.translate


class BoundedFileError(ValueError):
    """A file that cannot be read within its limits; ``str()`` is one line for a user.
    ``missing``: there is no file at the path (a caller may treat that case apart)."""

    def __init__(self, what: str, problem: str, *, missing: bool = False) -> None:
        self.what = what
        self.problem = problem
        self.missing = missing
        super().__init__(_one_line(f"{what}: {problem}"))


def read_bounded_bytes(path: Path | str, max_bytes: int, what: str, *, follow_symlinks: bool = True) -> bytes:
    """The bytes of the regular file ``path``, at most ``max_bytes`` of them (a larger file is a
    :class:`BoundedFileError`). ``what`` names the file in errors (e.g. its path). With
    ``follow_symlinks=False`` a symbolic link is refused instead of followed."""
    fd, _ = _open_bounded(path, max_bytes, what, follow_symlinks)
    try:
        chunks: list[bytes] = []
        left = max_bytes + 1
        while left > 0:
            chunk = os.read(fd, min(left, _READ_CHUNK))
            if not chunk:
                break
            chunks.append(chunk)
            left -= len(chunk)
    except OSError as exc:
        raise BoundedFileError(what, f"cannot read ({exc.strerror or exc})") from None
    finally:
        os.close(fd)
    if left <= 0:
        raise BoundedFileError(what, f"is more than the {max_bytes} bytes allowed")
    return b"".join(chunks)


@dataclass(frozen=True)
class FileTail:
    """What :func:`read_bounded_tail` read: the bytes of a file from ``start`` to ``size``."""

    identity: tuple[int, int]
    """``(st_dev, st_ino)``: which file it was."""
    size: int
    """Its size when it was opened."""
    start: int
    """The byte ``data`` starts at: the offset asked for, or 0 when :attr:`reread` says why not."""
    data: bytes
    reread: str | None


def read_bounded_tail(path: Path | str, max_bytes: int, what: str, offset: int = 0,
                      identity: tuple[int, int] | None = None) -> FileTail:
    """The bytes of the regular file ``path`` appended since a read that ended at byte ``offset``
    of the file ``identity``: from ``offset`` to its size, or from 0 when it is another file or
    shorter than ``offset`` (:attr:`FileTail.reread` says which). The limits of
    :func:`read_bounded_bytes`: a file over ``max_bytes`` (counted whole) is refused from its size
    before a byte is read, and no more than its size at opening is read."""
    fd, info = _open_bounded(path, max_bytes, what, True)
    found = (info.st_dev, info.st_ino)
    reread = None
    if identity is not None and found != identity:
        reread = "another file in its place (replaced)"
    elif info.st_size < offset:
        reread = f"{info.st_size} bytes, shorter than the {offset} already read (cut)"
    start = 0 if reread is not None else offset
    try:
        chunks: list[bytes] = []
        at = start
        while at < info.st_size:
            chunk = os.pread(fd, min(info.st_size - at, _READ_CHUNK), at)
            if not chunk:
                break
            chunks.append(chunk)
            at += len(chunk)
    except OSError as exc:
        raise BoundedFileError(what, f"cannot read ({exc.strerror or exc})") from None
    finally:
        os.close(fd)
    return FileTail(found, info.st_size, start, b"".join(chunks), reread)


def _open_bounded(path: Path | str, max_bytes: int, what: str, follow_symlinks: bool) -> tuple[int, os.stat_result]:
    """``path`` opened for reading without blocking, with its ``fstat``, when it is a regular file
    of at most ``max_bytes`` (its size at opening); :class:`BoundedFileError` otherwise."""
    flags = os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
    if not follow_symlinks:
        flags |= os.O_NOFOLLOW
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise BoundedFileError(what, "file not found", missing=True) from None
    except IsADirectoryError:
        raise BoundedFileError(what, "expected a file, found a folder") from None
    except OSError as exc:
        if not follow_symlinks and exc.errno == errno.ELOOP:
            raise BoundedFileError(what, "is a symbolic link (refused: the file must be a regular file)") from None
        raise BoundedFileError(what, f"cannot open ({exc.strerror or exc})") from None
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise BoundedFileError(what, "expected a file, found a folder")
        if not stat.S_ISREG(info.st_mode):
            raise BoundedFileError(what, "is not a regular file (a device, a FIFO or a socket)")
        if info.st_size > max_bytes:
            raise BoundedFileError(what, f"is {info.st_size} bytes, more than the {max_bytes} allowed")
    except OSError as exc:
        os.close(fd)
        raise BoundedFileError(what, f"cannot read ({exc.strerror or exc})") from None
    except BoundedFileError:
        os.close(fd)
        raise
    return fd, info


def json_depth_exceeds(data: bytes, max_depth: int) -> bool:
    """Whether the JSON text ``data`` nests arrays and objects more than ``max_depth`` deep
    (brackets inside strings do not count). Linear in ``len(data)``; the text need not be valid."""
    brackets = _STRING.sub(b"", data).translate(None, _NOT_BRACKETS)
    if len(brackets) <= max_depth:
        return False
    depth = 0
    for start in range(0, len(brackets), _DEPTH_CHUNK):
        codes = np.frombuffer(brackets, dtype=np.uint8, count=min(_DEPTH_CHUNK, len(brackets) - start), offset=start)
        steps = np.where((codes == ord("[")) | (codes == ord("{")), 1, -1).astype(np.int64)
        running = np.cumsum(steps) + depth
        if int(running.max()) > max_depth:
            return True
        depth = int(running[-1])
    return False


def json_keys_exceed(data: bytes, max_keys: int) -> bool:
    """Whether the JSON text ``data`` holds more than ``max_keys`` keys in all (colons outside
    strings). Linear in ``len(data)``; a text with no more colons than that is not scanned."""
    return data.count(b":") > max_keys and _STRING.sub(b"", data).count(b":") > max_keys


def load_bounded_json(data: bytes | str, max_depth: int, what: str) -> Any:
    """The JSON value in ``data`` (UTF-8 bytes, a BOM allowed, or text), nested at most
    ``max_depth`` deep, its integers at most :data:`MAX_INT_DIGITS` digits and its numbers
    finite; :class:`BoundedFileError` (one line, naming ``what``) otherwise."""
    raw = data.encode("utf-8", "surrogatepass") if isinstance(data, str) else data
    if json_depth_exceeds(raw, max_depth):
        raise BoundedFileError(what, f"JSON nested more than {max_depth} levels deep")
    if isinstance(data, str):
        text = data
    else:
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            raise BoundedFileError(what, f"not UTF-8 text (bad byte at offset {exc.start})") from None
    try:
        return json.loads(text, parse_constant=_refuse_constant, parse_float=_finite_float, parse_int=_bounded_int,
                          object_pairs_hook=_unique_keys)
    except json.JSONDecodeError as exc:
        raise BoundedFileError(what, f"not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})") from None
    except _NumberError as exc:
        raise BoundedFileError(what, str(exc)) from None
    except (RecursionError, MemoryError):  # unreachable after the depth check; kept as a floor
        raise BoundedFileError(what, "JSON too large or too deeply nested to read") from None


def load_bounded_toml(data: bytes, what: str) -> dict[str, Any]:
    """The TOML table in ``data`` (UTF-8), its keys and table headers of at most
    :data:`MAX_TOML_KEY_PARTS` parts; :class:`BoundedFileError` (one line, naming ``what``) otherwise."""
    import tomllib

    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise BoundedFileError(what, f"not UTF-8 text (bad byte at offset {exc.start})") from None
    parts = toml_key_parts(text)
    if parts > MAX_TOML_KEY_PARTS:
        raise BoundedFileError(what, f"a TOML key of {parts} dotted parts (at most {MAX_TOML_KEY_PARTS} allowed)")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise BoundedFileError(what, f"not valid TOML ({exc})") from None
    except RecursionError:  # tomllib is recursive: arrays or inline tables nested hundreds deep
        raise BoundedFileError(what, "not valid TOML (nested too deeply)") from None
    except ValueError as exc:  # e.g. an integer of more digits than Python converts
        raise BoundedFileError(what, f"not valid TOML ({' '.join(str(exc).split())[:200]})") from None


_TOML_KEY_CHARS = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-. \t\"'")
_TOML_NOT_KEY = {c: "\n" for c in range(128) if chr(c) not in _TOML_KEY_CHARS}


def toml_key_parts(text: str) -> int:
    """The most dotted parts of a key or table header in the TOML ``text``: the most dots in a run
    of key characters (letters, digits, ``_ - .``, blanks, quoted parts) outside string values
    and comments, plus one. Linear in ``len(text)``; the text need not be valid."""
    skeleton: list[str] = []  # the text with each string as "s" and each comment as a line end
    ahead = {opener: text.find(opener) for opener in ('"', "'", "#", "\n")}  # the next of each at or after ``at``
    at = 0
    while at < len(text):
        for opener, found in ahead.items():
            if found != -1 and found < at:
                ahead[opener] = text.find(opener, at)
        stop = min((ahead[o] for o in ('"', "'", "#") if ahead[o] != -1), default=len(text))
        skeleton.append(text[at:stop])
        if stop == len(text):
            break
        skeleton.append("\n" if text[stop] == "#" else "s")
        if ahead["\n"] != -1 and ahead["\n"] < stop:
            ahead["\n"] = text.find("\n", stop)
        at = _toml_skip(text, stop, len(text) if ahead["\n"] == -1 else ahead["\n"])
    runs = "".join(skeleton).translate(_TOML_NOT_KEY).split("\n")
    return max(run.count(".") for run in runs) + 1


def _toml_skip(text: str, at: int, line: int) -> int:
    """Past the string or comment starting at ``at``, on the line ending at ``line``."""
    if text[at] == "#":
        return line
    quote = text[at]
    if text.startswith(quote * 3, at):
        end = text.find(quote * 3, at + 3)
        return len(text) if end == -1 else end + 3
    at += 1
    while True:
        end = text.find(quote, at, line)
        if end == -1:  # a string ends on its line
            return line
        slash = end
        while quote == '"' and slash > at and text[slash - 1] == "\\":
            slash -= 1
        if (end - slash) % 2 == 0:
            return end + 1
        at = end + 1  # an escaped quote


class _NumberError(ValueError):
    pass


def _refuse_constant(text: str) -> Any:
    raise _NumberError(f"non-finite number {text} (numbers must be finite)")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise _NumberError(f"number {text[:40]}{'...' if len(text) > 40 else ''} is too large (numbers must be finite)")
    return value


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """An object whose keys are all different (a key given twice would let two readers of the
    same file see two different values: the last one wins in Python, the first in others) and
    at most :data:`MAX_OBJECT_KEYS` of them."""
    if len(pairs) > MAX_OBJECT_KEYS:
        raise _NumberError(f"an object of {len(pairs)} keys (at most {MAX_OBJECT_KEYS} allowed)")
    out = dict(pairs)
    if len(out) != len(pairs):
        seen: set[str] = set()
        twice = ""
        for key, _ in pairs:
            if key in seen:
                twice = key
                break
            seen.add(key)
        shown = "".join(c if c.isprintable() else "?" for c in twice[:40])
        raise _NumberError(f"key '{shown}' given twice in one object")
    return out


def _bounded_int(text: str) -> int:
    digits = len(text.lstrip("-"))
    if digits > MAX_INT_DIGITS:
        raise _NumberError(f"an integer of {digits} digits (at most {MAX_INT_DIGITS} allowed)")
    return int(text)


def _one_line(text: str, limit: int = 400) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def read_bounded_npz(
    path: Path | str, max_bytes: int, max_array_bytes: int, what: str, *, skip_objects: bool = False
) -> dict[str, np.ndarray]:
    """The arrays of the ``.npz`` file at ``path``: the file read by :func:`read_bounded_bytes`
    (at most ``max_bytes``), the sizes its zip entries and every ``.npy`` header declare checked
    before anything is inflated or allocated (at most ``max_array_bytes`` in all, no header
    claiming more than its entry holds), and never unpickled: an array of Python objects is
    refused, or with ``skip_objects`` left out of the result. Anything wrong is a
    :class:`BoundedFileError`."""
    data = read_bounded_bytes(path, max_bytes, what)
    objects: set[str] = set()
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            declared = sum(info.file_size for info in zf.infolist())
            if declared > max_array_bytes:
                raise BoundedFileError(what, f"its arrays unpack to {declared} bytes, more than the "
                                             f"{max_array_bytes} allowed")
            for info in zf.infolist():  # an array's header may claim more than its entry holds
                with zf.open(info) as member:
                    try:
                        size = _npy_bytes(member)
                    except _ObjectArray:
                        if not skip_objects:
                            raise ValueError("an array of Python objects (never unpickled)") from None
                        objects.add(info.filename.removesuffix(".npy"))
                        continue
                    if size > info.file_size:
                        raise BoundedFileError(what, f"array {info.filename[:60]!r} claims more bytes than its "
                                                     "entry holds")
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files if k not in objects}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib_error) as exc:
        if isinstance(exc, BoundedFileError):
            raise
        raise BoundedFileError(what, f"cannot read as .npz ({str(exc)[:200]})") from None


class _ObjectArray(ValueError):
    """An ``.npy`` member holding Python objects (a pickle)."""


def _npy_bytes(member: IO[bytes]) -> int:
    """The bytes of data the ``.npy`` header at the start of ``member`` announces."""
    version = np.lib.format.read_magic(member)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(member)
    elif version == (2, 0):
        shape, _, dtype = np.lib.format.read_array_header_2_0(member)
    else:
        raise ValueError(f"an array of .npy format {version} (1.0 and 2.0 are read)")
    if dtype.hasobject:
        raise _ObjectArray
    return int(np.prod(shape, dtype=object)) * dtype.itemsize

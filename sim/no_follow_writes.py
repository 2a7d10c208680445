"""Writing into a folder someone else made: a symbolic link planted there is never written through.

A shared run folder may hold links where the project is about to write (``story.md ->
~/.bashrc``, ``trace.jsonl -> ~/.profile``). Every file the project writes into a run folder
goes through one of three functions, which touch only the name in that folder, never what a
link there points at:

- :func:`write_file` (bytes) and :func:`replacing` (for a writer that must be given a path:
  ffmpeg, an exporter): the new file is created under a fresh temporary name in the same folder
  (``O_CREAT | O_EXCL | O_NOFOLLOW``: never an existing file, never through a link), written,
  and renamed over the final name. A rename replaces whatever has that name (a link itself,
  never its target), so a reader sees the old file or the whole new one, and a link planted at
  the name is gone afterwards, its target untouched;
- :func:`open_append` (a trace, a stream, a chunk file): opened with ``O_NOFOLLOW`` and
  without blocking; anything but a regular file with no other hard link is refused (a link, a
  FIFO, a device, a folder, a file that is also somewhere else); :func:`append_durably`
  appends one record through it and fsyncs it;
- :func:`make_folder` (a sub-folder such as ``motion/``): made when missing; a link in its
  place is refused;
- :func:`remove_stale_temporaries`: the temporary files a writer killed by ``kill -9`` left
  behind, removed before a run (or a sweep) writes into the folder again.

A refusal is an ``OSError`` naming the file (``ELOOP`` for a link), so a caller that reports a
failed write names it as it names a full disk. Only the last part of a path is guarded: the
folder itself is the caller's to check (``storyteller.orchestrator.session.run_folder_links`` refuses a run
folder that is a link). Limit: :func:`replacing` hands its temporary file on by name, so a
process writing into the same folder at the same moment could swap it; links planted in a
folder beforehand are never followed. Plain file I/O: no clock, no logging.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
from collections.abc import Iterator
from pathlib import Path

_CREATE = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)
_APPEND = os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
_MODE = 0o666  # less the umask, as open() creates files
_TRIES = 100  # fresh temporary names tried before giving up (each is 48 random bits)

LINK_REFUSED = "is a symbolic link; refusing to write through it"


def write_file(path: Path | str, data: bytes | bytearray | memoryview, *, durable: bool = False) -> Path:
    """Write ``data`` as the file ``path``: to a fresh temporary file in its folder, renamed over
    ``path`` (see the module docstring). ``durable``: fsync the file before the rename and the
    folder after it. Raises ``OSError`` naming ``path``; the temporary file is removed then."""
    path = Path(path)
    tmp, fd = _fresh(path)
    try:
        try:
            write_all(fd, data)
            if durable:
                os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise _naming(exc, path) from None
    if durable:
        _sync_folder(path.parent)
    return path


@contextlib.contextmanager
def replacing(path: Path | str, *, durable: bool = False) -> Iterator[Path]:
    """A fresh, empty temporary file in ``path``'s folder (same suffix, so a writer that picks
    its format from the name picks the same one) for the block to write by name; renamed over
    ``path`` when the block ends, removed when it raises. An ``OSError`` names ``path``."""
    path = Path(path)
    tmp, fd = _fresh(path)
    os.close(fd)
    try:
        yield tmp
        if durable:
            fd = os.open(tmp, os.O_RDONLY | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0))
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise _naming(exc, path) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    if durable:
        _sync_folder(path.parent)


def open_append(path: Path | str) -> int:
    """A descriptor appending to the regular file ``path`` (created if missing). Refused with an
    ``OSError`` naming ``path``: a symbolic link (``ELOOP``), anything that is not a regular
    file, and a file with other hard links (appending would change it there too)."""
    path = Path(path)
    try:
        fd = os.open(path, _APPEND, _MODE)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise OSError(errno.ELOOP, LINK_REFUSED, str(path)) from None
        if exc.errno == errno.ENXIO:  # a FIFO nobody reads (opened without blocking)
            raise OSError(errno.ENXIO, "is not a regular file; refusing to write to it", str(path)) from None
        raise _naming(exc, path) from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise OSError(errno.EINVAL, "is not a regular file; refusing to write to it", str(path))
        if info.st_nlink > 1:
            raise OSError(errno.EMLINK, f"has {info.st_nlink} hard links; refusing to append to it", str(path))
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def append_durably(path: Path | str, data: bytes | bytearray | memoryview) -> None:
    """Append ``data`` to ``path`` (:func:`open_append`) in one ``os.write`` where the system
    takes it whole, and fsync it before this returns."""
    fd = open_append(path)
    try:
        write_all(fd, data)
        os.fsync(fd)
    finally:
        os.close(fd)


def write_all(fd: int, data: bytes | bytearray | memoryview) -> None:
    """Every byte of ``data`` written to ``fd`` (``os.write`` may take fewer than it is given)."""
    view = memoryview(data).cast("B")
    while view:
        view = view[os.write(fd, view):]


def make_folder(path: Path | str) -> Path:
    """The folder ``path``, made (with its parents) when missing; a symbolic link or a file in its
    place is refused with an ``OSError`` naming it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(FileExistsError):
        os.mkdir(path)
    info = os.lstat(path)
    if stat.S_ISLNK(info.st_mode):
        raise OSError(errno.ELOOP, LINK_REFUSED, str(path))
    if not stat.S_ISDIR(info.st_mode):
        raise OSError(errno.ENOTDIR, "is not a folder", str(path))
    return path


_HEX = frozenset("0123456789abcdef")


def _is_temporary(name: str) -> bool:
    """Whether ``name`` is one :func:`_fresh` gives: ``.<name>.<12 hex digits>.tmp<suffix>``."""
    parts = name.split(".")
    if parts[-1] != "tmp":  # the suffix of the final name, kept for writers that read it
        if not (1 <= len(parts[-1]) <= 8 and parts[-1].isascii() and parts[-1].isalnum()):
            return False
        parts = parts[:-1]
    return (len(parts) >= 4 and parts[0] == "" and parts[-1] == "tmp" and len(parts[-2]) == 12
            and set(parts[-2]) <= _HEX and any(parts[1:-2]))


def remove_stale_temporaries(folder: Path | str) -> list[str]:
    """Remove the temporary files a writer killed mid-write left in ``folder`` (the names
    :func:`write_file` and :func:`replacing` use, nothing else); the names removed. Call it
    before the folder's writers start: a write in flight would lose its file. A link of such a
    name goes, never its target; a folder of such a name stays."""
    removed: list[str] = []
    try:
        names = os.listdir(folder)
    except (FileNotFoundError, NotADirectoryError):
        return removed
    for name in names:
        if _is_temporary(name):
            path = Path(folder) / name
            with contextlib.suppress(OSError):
                if not stat.S_ISDIR(os.lstat(path).st_mode):
                    os.unlink(path)
                    removed.append(name)
    return removed


def _fresh(path: Path) -> tuple[Path, int]:
    """(a new temporary file next to ``path``, created exclusively, its write descriptor)."""
    for _ in range(_TRIES):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp{path.suffix}")
        try:
            return tmp, os.open(tmp, _CREATE, _MODE)
        except FileExistsError:  # taken (a link or a file planted there): another name
            continue
        except OSError as exc:
            raise _naming(exc, path) from None
    raise OSError(errno.EEXIST, f"no free temporary name after {_TRIES} tries", str(path))


def _naming(exc: OSError, path: Path) -> OSError:
    """``exc`` naming ``path`` (the file the caller asked for, not a temporary one)."""
    return OSError(exc.errno, exc.strerror or str(exc), str(path))


def _sync_folder(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)

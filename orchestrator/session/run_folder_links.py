"""A run folder with planted links is refused before a run writes anything into it.

A run folder may come from someone else (shared, downloaded, unpacked). ``storyteller run
--out DIR``, ``resume DIR`` and ``replay ... --out DIR`` call :func:`refuse_planted_links`
first, which raises :class:`PlantedLinkError` (one sentence naming the folder and the name; the
command's ``error:`` line, exit code 2) when

- the folder itself is a symbolic link;
- a symbolic link has the name of a file the run writes (``storyteller.sim.run_folder_names``:
  the story files, the trace, ``run.json``, the checkpoint, ``runs.sqlite`` and SQLite's files
  beside it, the exports of each character, the pictures), or of ``motion/`` or a chunk file in it;
- a file the run writes in place (the trace, ``story.jsonl``, ``runs.sqlite`` and its journals,
  the chunk files) is not a regular file or has other hard links (appending would change it
  where it is linked from too).

The check is the clear refusal; the guarantee is in the writes themselves
(``storyteller.sim.no_follow_writes``): every file is replaced through a fresh temporary name or opened with
``O_NOFOLLOW``, so a link planted after this check is still never written through (that write
fails, or replaces the link). SQLite opens ``runs.sqlite`` by name and follows links, so for its
files this check is the guard.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Sequence
from pathlib import Path

from storyteller.sim.run_folder_names import APPENDED, CHUNK_SUFFIX, run_folder_entries


class PlantedLinkError(Exception):
    """A run folder that holds a link where the run would write (the message says where)."""


def refuse_planted_links(folder: Path, names: Sequence[str]) -> None:
    """Raise :class:`PlantedLinkError` when ``folder`` (a run of the characters ``names``) is a
    symbolic link or holds one where the run writes (see the module docstring). A folder that
    does not exist yet holds nothing: it passes."""
    if folder.is_symlink():
        raise PlantedLinkError(f"{folder}: the run folder is a symbolic link; refusing to write through it")
    for entry in run_folder_entries(names):
        try:
            info = os.lstat(folder / entry)
        except (FileNotFoundError, NotADirectoryError):
            continue
        if stat.S_ISLNK(info.st_mode):
            raise PlantedLinkError(f"{folder}: run folder holds a symbolic link at {entry}; refusing to write through it")
        if entry in APPENDED or entry.endswith(CHUNK_SUFFIX):
            if not stat.S_ISREG(info.st_mode):
                raise PlantedLinkError(f"{folder}: {entry} in the run folder is not a regular file; refusing to write to it")
            if info.st_nlink > 1:
                raise PlantedLinkError(
                    f"{folder}: {entry} in the run folder has {info.st_nlink} hard links; refusing to write through them"
                )

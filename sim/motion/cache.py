"""Content-addressed on-disk cache of generated motion arrays (``.npz``).

Entries live in the folder the caller passes in (the application's default,
``$STORYTELLER_CACHE_DIR/motion`` or ``~/.cache/storyteller/motion``, is chosen at the edge:
``storyteller.orchestrator.cache_paths``; ``None`` means no disk cache) and are named by the SHA-256 of a
JSON description of what produced them (generator version, parameters, input file hashes). A missing or unreadable entry is rebuilt; writes are atomic
(temporary file + rename), so concurrent builders never see half-written files.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np


def content_key(payload: Mapping[str, Any]) -> str:
    """Hex SHA-256 of the canonical JSON of ``payload`` (keys sorted)."""
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def cached_arrays(
    payload: Mapping[str, Any],
    build: Callable[[], dict[str, np.ndarray]],
    directory: Path | None,
) -> dict[str, np.ndarray]:
    """Load the arrays for ``payload`` from the cache folder ``directory``, or build, store and
    return them; ``directory=None``: no disk cache (build and return)."""
    if directory is None:
        return build()
    folder = directory
    path = folder / f"{content_key(payload)}.npz"
    if path.exists():
        try:
            with np.load(path, allow_pickle=False) as data:
                return {k: data[k] for k in data.files}
        except (OSError, ValueError, zipfile.BadZipFile, EOFError):
            pass  # corrupt entry: rebuild below
    arrays = build()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            named: dict[str, Any] = dict(arrays)  # savez's stub reads ** as allow_pickle
            np.savez(f, **named)
        os.replace(tmp, path)
    except OSError:
        pass  # a read-only cache only costs rebuild time
    return arrays

"""Where the application keeps its on-disk caches, read from the environment at the edge.

``$STORYTELLER_CACHE_DIR`` if set, else ``~/.cache/storyteller``; motion arrays live in its
``motion`` folder. ``sim`` never reads the environment or the home folder: the CLI and the
benchmarks pass ``motion_cache_dir()`` into ``sim.motion.database.load_databases`` and
``sim.motion.config.build_databases_from_config``.
"""

from __future__ import annotations

import os
from pathlib import Path

CACHE_ENV = "STORYTELLER_CACHE_DIR"


def cache_root() -> Path:
    """The cache folder (not created): ``$STORYTELLER_CACHE_DIR``, else ``~/.cache/storyteller``."""
    root = os.environ.get(CACHE_ENV)
    return Path(root) if root else Path.home() / ".cache" / "storyteller"


def motion_cache_dir() -> Path:
    """The motion array cache folder (not created)."""
    return cache_root() / "motion"

"""Where the application keeps its on-disk caches, read from the environment at the edge.

:func:`cache_root` is the one place the cache folder is computed: ``$STORYTELLER_CACHE_DIR``
if set (``~`` expanded), else ``~/.cache/storyteller``. In it: motion arrays in ``motion``
(:func:`motion_cache_dir`), the assembled embedded-model weights in ``models``
(``storyteller.orchestrator.llm.model_weights.cache_dir``), the default runs database ``runs.sqlite``
(``storyteller.orchestrator.planning.checkpoints.default_runs_db``) and the describer's cached scene
descriptions in ``descriptions`` (:func:`description_cache_dir`). ``sim`` never reads the environment or the home
folder: the CLI and the benchmarks pass ``motion_cache_dir()`` into
``storyteller.sim.motion.database.load_databases`` and ``storyteller.sim.motion.config.build_databases_from_config``.
"""

from __future__ import annotations

import os
from pathlib import Path

CACHE_ENV = "STORYTELLER_CACHE_DIR"


def cache_root() -> Path:
    """The cache folder (not created): ``$STORYTELLER_CACHE_DIR`` (``~`` expanded), else
    ``~/.cache/storyteller``."""
    root = os.environ.get(CACHE_ENV)
    return Path(root).expanduser() if root else Path.home() / ".cache" / "storyteller"


def motion_cache_dir() -> Path:
    """The motion array cache folder (not created)."""
    return cache_root() / "motion"


def description_cache_dir() -> Path:
    """The describer's cached scene descriptions (not created), per scene, model and prompts."""
    return cache_root() / "descriptions"

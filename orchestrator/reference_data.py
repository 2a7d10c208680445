"""Where the authors' reference data and the shared mocap clips are: one lookup for each.

The reference data is the public repository of "Event-Driven Storytelling with Multiple Lifelike
Humans in a 3D Scene" (Lim et al., ICCV 2025; https://github.com/rms0329/Event-Driven-Storytelling,
MIT licence): its ``configs/scenes/<Scene>/`` annotations and ``benchmark/test_cases/``. The
project never copies it; every module, benchmark and test finds it through
:func:`locate_reference`, and the real mocap clips through :func:`locate_mocap`.

Lookup order, the same for both folders:

1. the environment variable (``STORYTELLER_REFERENCE``, ``STORYTELLER_MOCAP``) when it is set
   and not empty. An explicit setting is never second-guessed: if that folder does not exist the
   data counts as absent (the reason names the variable), with no fall-back to the default;
2. else the default folder beside the checkout (``../shared/reference/event-driven-storytelling``,
   ``../shared/mocap``), looked for first relative to the current directory (a user running from
   the project root, or a clean clone checked out beside ``shared/``), then relative to the
   project root that holds this package (pytest or a script started from elsewhere).

Guarantee: nothing here raises on lookup. :class:`DataFolder` says where the folder is (or where
it was expected) and, when absent, a one-line reason saying how to provide it; ``require()``
turns absence into :class:`ReferenceDataNotFound` for callers that cannot go on without it.
Only this module reads these variables (``sim/`` and ``tools/`` never read the environment).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

REFERENCE_ENV = "STORYTELLER_REFERENCE"
MOCAP_ENV = "STORYTELLER_MOCAP"
REFERENCE_URL = "https://github.com/rms0329/Event-Driven-Storytelling"
DEFAULT_REFERENCE = Path("..") / "shared" / "reference" / "event-driven-storytelling"  # relative; see lookup order
DEFAULT_MOCAP = Path("..") / "shared" / "mocap"
PROJECT_ROOT = Path(__file__).resolve().parents[1]


class ReferenceDataNotFound(FileNotFoundError):
    """A data folder that a command needs is absent; the message is one line saying how to provide it."""


@dataclass(frozen=True)
class DataFolder:
    """The result of one lookup: the folder found, or where it was expected and why it is absent."""

    path: Path
    """The folder (absolute) when found; else the place it was expected (the variable's value,
    else the default relative to the current directory)."""
    found: bool
    reason: str
    """Empty when found; else one line naming what was looked for and how to provide it."""

    def require(self) -> Path:
        """The folder, or :class:`ReferenceDataNotFound` with the one-line reason."""
        if not self.found:
            raise ReferenceDataNotFound(self.reason)
        return self.path


def _locate(what: str, env_var: str, default: Path, hint: str,
            env: Mapping[str, str] | None, bases: Sequence[Path] | None) -> DataFolder:
    env = os.environ if env is None else env
    bases = (Path.cwd(), PROJECT_ROOT) if bases is None else bases
    value = env.get(env_var, "")
    if value:
        path = Path(value).expanduser().resolve()
        if path.is_dir():
            return DataFolder(path, True, "")
        return DataFolder(path, False, f"{what} not found: {env_var}={value} is not a folder ({hint})")
    candidates = [(base / default).resolve() for base in bases]
    for path in candidates:
        if path.is_dir():
            return DataFolder(path, True, "")
    return DataFolder(candidates[0], False,
                      f"{what} not found: {env_var} is not set and {default.as_posix()} does not exist ({hint})")


def locate_reference(env: Mapping[str, str] | None = None, bases: Sequence[Path] | None = None) -> DataFolder:
    """The authors' data folder (``configs/scenes/``, ``benchmark/test_cases/``); see the module docstring.

    ``env`` defaults to ``os.environ``; ``bases`` (the folders the default is relative to, first
    match wins) to the current directory, then the project root. Tests pass their own.
    """
    return _locate("reference data", REFERENCE_ENV, DEFAULT_REFERENCE,
                   f"clone {REFERENCE_URL}; set {REFERENCE_ENV} to the clone", env, bases)


def locate_mocap(env: Mapping[str, str] | None = None, bases: Sequence[Path] | None = None) -> DataFolder:
    """The real mocap clips folder that ``benchmark/mocap_shared.toml`` lists (``cmu/``, ...);
    same lookup as :func:`locate_reference`."""
    return _locate("mocap clips", MOCAP_ENV, DEFAULT_MOCAP,
                   f"set {MOCAP_ENV} to the folder holding cmu/ and fair_animated_drawings/", env, bases)

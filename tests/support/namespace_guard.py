"""Which modules of the project's folders are loaded under a name outside ``storyteller``.

The package ``storyteller`` reaches the folders ``sim/``, ``tools/``, ... through links, and
from the repository root the folders are importable by their own names too: ``import sim.x``
would load a second copy of ``storyteller.sim.x`` (two classes of one name, each failing the
other's ``isinstance``; two module-level caches). Nothing may import them so; the autouse
fixture in ``tests/conftest.py`` fails a test after which such a module is loaded, and
``tests/test_namespace_imports.py`` finds such an import in the source.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[2]
OLD_NAMES = frozenset({"sim", "tools", "agents", "prompts", "orchestrator", "benchmark"})
"""The top-level folders of the product: each is imported as ``storyteller.<folder>`` only."""


def _location(module: ModuleType) -> Path | None:
    file = getattr(module, "__file__", None)
    if file is None:
        paths = list(getattr(module, "__path__", []) or [])
        file = paths[0] if paths else None
    return Path(file).resolve() if file else None


def second_names(modules: Mapping[str, ModuleType] | None = None) -> list[str]:
    """Names in ``modules`` (default: ``sys.modules``) under which a module of the project's
    folders is loaded without the ``storyteller.`` prefix, sorted."""
    found = []
    for name, module in list((sys.modules if modules is None else modules).items()):
        if name.partition(".")[0] not in OLD_NAMES or module is None:
            continue
        where = _location(module)
        if where is not None and where.is_relative_to(ROOT):
            found.append(name)
    return sorted(found)

"""The one installed import name of the project: ``storyteller.sim``, ``storyteller.tools``,
``storyteller.agents``, ``storyteller.orchestrator``, ``storyteller.benchmark`` and
``storyteller.prompts`` (the prompt files, read with ``importlib.resources``).

The code lives in the repository's top-level folders (``sim/``, ``tools/``, ``agents/``,
``orchestrator/``, ``benchmark/``, ``prompts/``); each entry of this folder is a relative
symbolic link to one of them. A checkout therefore imports ``storyteller.sim`` straight from
the repository root (pytest, mypy and ruff see plain files; a new module needs no reinstall),
and the wheel copies the linked folders in as real sub-packages.

Only these names are imported: never ``sim`` or ``orchestrator`` at the top level, which would
load a second copy of a module beside its ``storyteller.`` one (two classes of one name that
``isinstance`` tells apart); ``tests/test_namespace_imports.py`` fails if anything does.
"""

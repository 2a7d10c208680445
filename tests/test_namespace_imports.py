"""One name per module: the project is imported as ``storyteller.sim``, ``storyteller.tools``, ...
and never by its folders' own names (``sim``, ``tools``, ``agents``, ``prompts``,
``orchestrator``, ``benchmark``), which would load a second copy of a module.

The source check reads every import statement of the product and the tests; the run-time
check (``second_names``, applied after every test by ``tests/conftest.py``) also sees a module
loaded by a string, e.g. ``monkeypatch.setattr("sim.x.y", ...)`` or ``importlib``.
"""

# ns-rewrite: skip-file (this file names the old module paths on purpose; the namespace rewrite
# script of issue 26 leaves it alone)
from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.namespace_guard import OLD_NAMES, ROOT, second_names

SCANNED = [*sorted(OLD_NAMES), "tests"]


def _sources() -> list[Path]:
    skipped = ROOT / "tests" / "pi_programs"  # event programs for the sandbox, not modules
    return [p for folder in SCANNED for p in sorted((ROOT / folder).rglob("*.py")) if not p.is_relative_to(skipped)]


def _old_imports(source: str) -> list[tuple[int, str]]:
    """(line, module) of every import of a folder by its own name in ``source``."""
    out: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        out.extend((node.lineno, n) for n in names if n.split(".")[0] in OLD_NAMES)
    return out


def test_the_scan_reads_the_product_and_the_tests() -> None:
    files = _sources()
    assert len(files) > 400
    assert {p.relative_to(ROOT).parts[0] for p in files} == set(SCANNED)


def test_no_module_imports_a_folder_by_its_own_name() -> None:
    wrong = [f"{path.relative_to(ROOT)}:{line} imports {name}"
             for path in _sources() for line, name in _old_imports(path.read_text(encoding="utf-8"))]
    assert not wrong, "\n".join(wrong)


def test_the_source_check_sees_an_old_import() -> None:
    source = ("import os\nfrom sim.world import step\nimport storyteller.sim.world\n"
              "from tests.support import reference\nimport orchestrator.cli.app as a\nfrom . import sim\n")
    assert _old_imports(source) == [(2, "sim.world"), (5, "orchestrator.cli.app")]


def test_the_package_and_its_folders_are_one() -> None:
    import storyteller
    import storyteller.sim

    assert Path(storyteller.__file__).resolve().parent == ROOT / "storyteller"
    assert Path(storyteller.sim.__file__).resolve() == ROOT / "sim" / "__init__.py"
    assert {p.name for p in (ROOT / "storyteller").iterdir() if p.is_symlink()} == OLD_NAMES


def test_this_process_holds_no_module_under_two_names() -> None:
    assert second_names() == []


@pytest.mark.parametrize("statement", ["import sim.world.step", "from orchestrator.cli import app"])
def test_the_run_time_check_sees_a_second_copy(statement: str) -> None:
    """From the repository root the folders are importable by their own names: the check finds it."""
    probe = (f"import sys; sys.path.insert(0, {str(ROOT)!r}); {statement}; "
             "import json; from tests.support.namespace_guard import second_names; print(json.dumps(second_names()))")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    names = json.loads(done.stdout.strip().splitlines()[-1])
    top = statement.split()[1].split(".")[0]
    assert top in names and all(n.split(".")[0] in OLD_NAMES for n in names)

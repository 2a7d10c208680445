"""The package layers import one way, and no two modules import each other in a cycle.

Floors, lowest first: ``sim`` <- ``tools`` <- ``agents`` <- ``orchestrator`` <- ``benchmark``.
A module may import from its own floor or a lower one. No product package imports the tests,
``benchmark`` included: the fakes and frozen baselines its speed scripts time against live in
``benchmark/support`` (the wheel has no ``tests``). Imports under ``if TYPE_CHECKING:`` count too: a type-only import upwards is still a
dependency a reader has to know about.
"""

from __future__ import annotations

import ast
from pathlib import Path

import networkx as nx
import pytest

ROOT = Path(__file__).resolve().parents[1]
FLOORS = ["sim", "tools", "agents", "orchestrator", "benchmark"]
PRODUCT = [*FLOORS, "prompts"]


def _module_name(path: Path) -> str:
    """The name a file is imported by: ``storyteller.sim.x`` for sim/x.py, ``tests.support.x``."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(["storyteller", *parts] if parts[0] in PRODUCT else parts)


def _modules() -> dict[str, Path]:
    found: dict[str, Path] = {}
    for top in [*PRODUCT, "tests/support"]:
        for path in sorted((ROOT / top).rglob("*.py")):
            found[_module_name(path)] = path
    return found


MODULES = _modules()


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, imported module) for every import in the file, resolved to a known module."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:
                full = f"{node.module}.{alias.name}"
                out.append((node.lineno, full if full in MODULES else node.module))
    return out


def _floor(module: str) -> int | None:
    parts = module.split(".")
    top = parts[1] if parts[0] == "storyteller" and len(parts) > 1 else None
    return FLOORS.index(top) if top in FLOORS else None


def test_the_scan_sees_every_package() -> None:
    for top in FLOORS:
        assert any(m.startswith(f"storyteller.{top}.") for m in MODULES), top
    assert len(MODULES) > 100


def test_imports_flow_one_way() -> None:
    wrong: list[str] = []
    for module, path in MODULES.items():
        here = _floor(module)
        for line, target in _imports(path):
            if target.split(".")[0] == "tests":
                if here is not None:
                    wrong.append(f"{path.relative_to(ROOT)}:{line} imports {target} (the tests)")
                continue
            there = _floor(target)
            if here is None or there is None:
                continue
            if there > here:
                wrong.append(f"{path.relative_to(ROOT)}:{line} imports {target} ({FLOORS[here]} <- {FLOORS[there]})")
    assert not wrong, "\n".join(wrong)


def test_no_import_cycles_between_modules() -> None:
    graph: nx.DiGraph[str] = nx.DiGraph()
    for module, path in MODULES.items():
        graph.add_node(module)
        for _, target in _imports(path):
            # a package's __init__ importing its own modules is how packages work, not a cycle
            if target in MODULES and target != module and not target.startswith(module + "."):
                graph.add_edge(module, target)
    cycles = list(nx.simple_cycles(graph, length_bound=6))
    assert not cycles, "\n".join(" -> ".join([*c, c[0]]) for c in cycles[:20])


@pytest.mark.parametrize("top", ["sim", "tools", "orchestrator", "agents"])
def test_no_flat_prefix_modules_left(top: str) -> None:
    """Sub-packages, not name prefixes, group modules: no ``sim/motion_*.py`` beside ``sim/motion/``."""
    packages = {p.name for p in (ROOT / top).iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    prefixed = [
        str(path.relative_to(ROOT))
        for path in (ROOT / top).glob("*.py")
        if any(path.stem.startswith(pkg + "_") for pkg in packages)
    ]
    assert not prefixed, prefixed

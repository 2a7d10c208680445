"""``.ci/size_budget.py``: counts product files over 500 lines and functions over 80 (methods and
nested functions on their own, tests not counted) and fails above the given maxima."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / ".ci" / "size_budget.py"


@pytest.fixture(scope="module")
def budget() -> ModuleType:
    spec = importlib.util.spec_from_file_location("size_budget", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _function(name: str, lines: int, indent: str = "") -> str:
    """A function of exactly ``lines`` lines (its def line included)."""
    body = "".join(f"{indent}    x{k} = {k}\n" for k in range(lines - 2))
    return f"{indent}def {name}() -> None:\n{body}{indent}    return None\n"


def _tree(root: Path) -> None:
    (root / "sim").mkdir()
    (root / "tools" / "sub").mkdir(parents=True)
    (root / "tests").mkdir()
    (root / "sim" / "big.py").write_text("x = 1\n" * 501)
    (root / "sim" / "edge.py").write_text("x = 1\n" * 500)  # exactly at the limit: not counted
    (root / "tests" / "test_big.py").write_text("x = 1\n" * 900 + _function("huge", 200))  # tests: not product
    nested = "class Planner:\n" + _function("plan", 81, "    ") + _function("short", 80, "    ")
    nested += "async " + _function("outer", 90).replace("    return None\n", _function("inner", 82, "    "), 1)
    (root / "tools" / "sub" / "mod.py").write_text(nested)


def test_long_functions_names_methods_and_nested_functions(budget: ModuleType) -> None:
    source = "class Planner:\n" + _function("plan", 81, "    ") + _function("short", 80, "    ")
    assert budget.long_functions(source) == [(2, "Planner.plan", 81)]
    outer = "async " + _function("outer", 90).replace("    return None\n", _function("inner", 82, "    "), 1)
    assert budget.long_functions(outer) == [(1, "outer", 171), (90, "outer.inner", 82)]


def test_counts_against_the_maxima(budget: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _tree(tmp_path)
    assert budget.main(["--max-files", "1", "--max-functions", "3", "--root", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "files over 500 lines: 1 (limit 1)" in out
    assert "functions over 80 lines: 3 (limit 3)" in out
    assert "sim/big.py" in out and "edge.py" not in out and "test_big" not in out
    assert "tools/sub/mod.py:2 Planner.plan" in out and "outer.inner" in out and "short" not in out
    assert budget.main(["--max-files", "0", "--max-functions", "3", "--root", str(tmp_path)]) == 1
    assert "FAIL: 1 files over 500 lines, at most 0 allowed" in capsys.readouterr().out
    assert budget.main(["--max-files", "1", "--max-functions", "2", "--root", str(tmp_path)]) == 1
    assert "FAIL: 3 functions over 80 lines, at most 2 allowed" in capsys.readouterr().out

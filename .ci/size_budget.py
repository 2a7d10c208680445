"""Count the product files over 500 lines and the product functions over 80 lines, against a budget.

Usage (from the repository root): ``python .ci/size_budget.py --max-files 10 --max-functions 22``

Product code is every ``*.py`` under the product folders (``FOLDERS``; ``tests/`` is not
product code). A file's size is its number of lines; a function's is from its ``def`` line to
its last line (decorators not counted, docstring and nested functions included), found with
``ast``, so methods and nested functions count as functions of their own. Prints every file
and function over its limit, longest first, then exits 1 when either count is above its
maximum. The maxima in ``.ci/run`` are the counts when they were last lowered: the budget only
goes down (lower it when a split brings a count below it; never raise it to fit new code).
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

FOLDERS = ("sim", "tools", "agents", "orchestrator", "benchmark", "prompts")
FILE_LINES = 500  # a file over this many lines counts against --max-files
FUNCTION_LINES = 80  # a function over this many lines counts against --max-functions


def product_files(root: Path) -> list[Path]:
    """Every Python file of the product folders under ``root``, sorted."""
    return [path for folder in FOLDERS for path in sorted((root / folder).rglob("*.py"))]


def long_functions(source: str, filename: str = "<source>") -> list[tuple[int, str, int]]:
    """(line, qualified name, lines) of every function in ``source`` over ``FUNCTION_LINES``."""
    found: list[tuple[int, str, int]] = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    assert child.end_lineno is not None
                    size = child.end_lineno - child.lineno + 1
                    if size > FUNCTION_LINES:
                        found.append((child.lineno, name, size))
                visit(child, name + ".")
            else:
                visit(child, prefix)

    visit(ast.parse(source, filename=filename), "")
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-files", type=int, required=True, help=f"most files over {FILE_LINES} lines allowed")
    parser.add_argument("--max-functions", type=int, required=True,
                        help=f"most functions over {FUNCTION_LINES} lines allowed")
    parser.add_argument("--root", type=Path, default=Path(), help="repository root (default: .)")
    args = parser.parse_args(argv)

    big_files: list[tuple[int, str]] = []
    big_functions: list[tuple[int, str]] = []
    for path in product_files(args.root):
        source = path.read_text(encoding="utf-8")
        rel = path.relative_to(args.root).as_posix()
        lines = len(source.splitlines())
        if lines > FILE_LINES:
            big_files.append((lines, rel))
        for line, name, size in long_functions(source, rel):
            big_functions.append((size, f"{rel}:{line} {name}"))
    big_files.sort(key=lambda item: (-item[0], item[1]))
    big_functions.sort(key=lambda item: (-item[0], item[1]))
    print(f"files over {FILE_LINES} lines: {len(big_files)} (limit {args.max_files})")
    for lines, rel in big_files:
        print(f"  {lines:5d}  {rel}")
    print(f"functions over {FUNCTION_LINES} lines: {len(big_functions)} (limit {args.max_functions})")
    for size, where in big_functions:
        print(f"  {size:5d}  {where}")
    failed = False
    if len(big_files) > args.max_files:
        print(f"FAIL: {len(big_files)} files over {FILE_LINES} lines, at most {args.max_files} allowed")
        failed = True
    if len(big_functions) > args.max_functions:
        print(f"FAIL: {len(big_functions)} functions over {FUNCTION_LINES} lines, at most {args.max_functions} allowed")
        failed = True
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

"""Every line the ``storyteller`` command prints goes through ``storyteller.orchestrator.terminal.say``
(issue 22: text from files and models reached the terminal raw where a module printed by itself).

An AST scan of every module of ``orchestrator`` and of every module of ``benchmark`` that a
command plugin (``pyproject.toml``, ``storyteller.commands``) imports, directly or inside a
function: a call of ``print``, ``typer.echo`` / ``click.echo`` (or ``secho``, or ``echo``
imported bare), a rich ``.print`` / ``.print_json`` / ``.print_exception`` (a console's
``log`` / ``out`` / ``rule`` too), ``sys.stdout.write`` / ``sys.stderr.write`` or
``os.write`` to fd 1 or 2 fails the test, naming the file, line and function. Exempt:
``orchestrator/terminal.py`` (the function itself), :data:`ALLOWED` (each with its reason) and
the ``main()`` of a module run as a script (``python -m storyteller.benchmark.own_cases.check``), which the
command never calls (checked: nothing scanned imports such a ``main``).
"""

from __future__ import annotations

import ast
import tomllib
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
PACKAGES = ("orchestrator", "benchmark")
THE_FUNCTION = "orchestrator/terminal.py"

ALLOWED: dict[tuple[str, str], str] = {
    ("orchestrator/logging_setup.py", "_StderrLogger.msg"): (
        "structlog's rendered line: every key and value went through safe_text.plain in the "
        "escape_controls processor, and the console renderer's colours are escape sequences of its "
        "own that say() would show as text"
    ),
}

_BARE = frozenset({"print", "echo", "secho", "pprint"})
_RICH = frozenset({"print", "print_json", "print_exception"})
_CONSOLE_ONLY = frozenset({"log", "out", "rule"})


def _dotted(node: ast.expr) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return f"{_dotted(node.value)}.{node.attr}"
    if isinstance(node, ast.Call):
        return f"{_dotted(node.func)}()"
    return "?"


def _printing(call: ast.Call) -> str | None:
    """What ``call`` prints with, if it prints to the terminal by itself."""
    func = call.func
    if isinstance(func, ast.Name):
        return func.id if func.id in _BARE else None
    if not isinstance(func, ast.Attribute):
        return None
    base, name = _dotted(func.value), func.attr
    if name in {"echo", "secho"} and base in {"typer", "click"}:
        return f"{base}.{name}"
    if name in _RICH or (name in _CONSOLE_ONLY and base.lower().endswith(("console", "console()"))):
        return f"{base}.{name}"
    if name == "write" and base in {"sys.stdout", "sys.stderr", "sys.__stdout__", "sys.__stderr__"}:
        return f"{base}.write"
    if (name == "write" and base == "os" and call.args and isinstance(call.args[0], ast.Constant)
            and call.args[0].value in (1, 2)):
        return f"os.write({call.args[0].value})"
    return None


def _is_main_guard(node: ast.stmt) -> bool:
    return isinstance(node, ast.If) and "__main__" in ast.unparse(node.test) and "__name__" in ast.unparse(node.test)


class _Scan(ast.NodeVisitor):
    def __init__(self) -> None:
        self.scope: list[str] = []
        self.found: list[tuple[int, str, str]] = []  # line, function, what

    def _enter(self, node: ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef) -> None:
        self.scope.append(node.name)
        self.generic_visit(node)
        self.scope.pop()

    visit_FunctionDef = visit_AsyncFunctionDef = visit_ClassDef = _enter

    def visit_Call(self, node: ast.Call) -> None:
        what = _printing(node)
        if what is not None:
            self.found.append((node.lineno, ".".join(self.scope) or "<module>", what))
        self.generic_visit(node)


def printing_calls(source: str) -> list[tuple[int, str, str]]:
    """(line, enclosing function, what) of every call in ``source`` that prints by itself, but
    those of a script's ``main()`` and ``if __name__ == "__main__":`` block."""
    tree = ast.parse(source)
    script = any(_is_main_guard(node) for node in tree.body)
    scan = _Scan()
    for node in tree.body:
        if script and (_is_main_guard(node) or (isinstance(node, ast.FunctionDef) and node.name == "main")):
            continue
        scan.visit(node)
    return scan.found


def _imports(tree: ast.Module) -> Iterator[tuple[str, tuple[str, ...]]]:
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, ()
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.module, tuple(alias.name for alias in node.names)


def _file_of(module: str) -> Path | None:
    """The file of ``storyteller.orchestrator.x``: orchestrator/x.py (as ``files`` lists it)."""
    folder = module.removeprefix("storyteller.").replace(".", "/")
    for candidate in (ROOT / f"{folder}.py", ROOT / folder / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _plugin_modules() -> list[str]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    plugins = project["project"]["entry-points"]["storyteller.commands"]
    return [value.split(":")[0] for value in plugins.values()]


def _scanned() -> tuple[set[Path], list[tuple[Path, str]]]:
    """The files of every ``orchestrator`` module and of the modules the command and its plugins
    import (within :data:`PACKAGES`); and each ``from X import main`` among them."""
    files = set((ROOT / "orchestrator").rglob("*.py"))
    todo = ["storyteller.orchestrator.cli.app", *_plugin_modules()]
    seen: set[Path] = set()
    imported_mains: list[tuple[Path, str]] = []
    while todo:
        path = _file_of(todo.pop())
        if path is None or path in seen:
            continue
        seen.add(path)
        for module, names in _imports(ast.parse(path.read_text(encoding="utf-8"))):
            if module.removeprefix("storyteller.").split(".")[0] in PACKAGES:
                todo.append(module)
                todo.extend(f"{module}.{name}" for name in names)
                if "main" in names:
                    imported_mains.append((path, module))
    return files | seen, imported_mains


def test_the_scan_sees_every_way_of_printing() -> None:
    source = '''
import os, sys, typer, click
from typer import echo
from rich.console import Console
def f(console, live):
    print("x")
    typer.echo("x")
    click.secho("x")
    echo("x")
    console.print("x")
    live.console.print("x")
    Console().print_json("{}")
    console.log("x")
    sys.stderr.write("x")
    os.write(2, b"x")
    logger.log(20, "x")  # a logger, not a console: not printing
    say("x")  # the one function
'''
    found = printing_calls(source)
    assert [what for _, _, what in found] == [
        "print", "typer.echo", "click.secho", "echo", "console.print", "live.console.print", "Console().print_json",
        "console.log", "sys.stderr.write", "os.write(2)",
    ]
    assert {scope for _, scope, _ in found} == {"f"}
    script = 'def main():\n    print("report")\n\ndef helper():\n    print("x")\n\nif __name__ == "__main__":\n    main()\n'
    assert printing_calls(script) == [(5, "helper", "print")]


def test_the_command_prints_only_through_say() -> None:
    files, imported_mains = _scanned()
    assert ROOT / "orchestrator/cli/scene.py" in files and ROOT / "benchmark/sweep/progress.py" in files
    offenders = []
    used_allowances = set()
    for path in sorted(files):
        rel = path.relative_to(ROOT).as_posix()
        if rel == THE_FUNCTION:
            continue
        for line, scope, what in printing_calls(path.read_text(encoding="utf-8")):
            if (rel, scope) in ALLOWED:
                used_allowances.add((rel, scope))
            else:
                offenders.append(f"{rel}:{line} in {scope}: {what}")
    assert offenders == [], "print through storyteller.orchestrator.terminal.say instead:\n" + "\n".join(offenders)
    assert used_allowances == set(ALLOWED), f"allowances no longer needed: {set(ALLOWED) - used_allowances}"
    assert imported_mains == [], f"a script's main() is called by the command: {imported_mains}"

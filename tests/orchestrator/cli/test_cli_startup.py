"""Commands start at once: ``storyteller --help``, ``scene list``, ``model info`` and the help of
``run``, ``replay`` and ``resume`` import no LLM client, planning graph, clustering, plotting or
compiled-kernel module (a run or replay imports its job's modules, the plotting of
``topdown.png`` among them, only once it runs).

Each command runs in a fresh interpreter (the test session itself has imported everything
already), and the child reports the top-level packages in its ``sys.modules`` after the
command returned. A control command that does cluster (``scene inspect``) shows that the probe
sees modules imported lazily inside a command.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
HEAVY = ("litellm", "langgraph", "sklearn", "matplotlib", "torch", "numba")

PROBE = """
import json, sys
from storyteller.orchestrator.cli.app import app
try:
    app(sys.argv[1:])
except SystemExit:
    pass
finally:
    print("\\nMODULES " + json.dumps(sorted({m.split(".")[0] for m in sys.modules})))
"""


def _imported_by(args: list[str], tmp_path: Path) -> set[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("STORYTELLER_")}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    env["HOME"] = str(tmp_path)  # no user config or cache changes what a command loads
    proc = subprocess.run(
        [sys.executable, "-c", PROBE, *args],
        capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300,
    )
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("MODULES "))
    return set(json.loads(line.removeprefix("MODULES ")))


@pytest.mark.parametrize(
    "args",
    [["--help"], ["scene", "list"], ["model", "info"], ["run", "--help"], ["replay", "--help"], ["resume", "--help"]],
    ids=" ".join,
)
@pytest.mark.slow
def test_quick_commands_import_no_heavy_module(args: list[str], tmp_path: Path) -> None:
    heavy = sorted(set(HEAVY) & _imported_by(args, tmp_path))
    assert heavy == [], f"storyteller {' '.join(args)} imported {heavy}"


@pytest.mark.slow
def test_the_probe_sees_modules_a_command_imports(tmp_path: Path) -> None:
    """``scene inspect`` clusters the objects, so scikit-learn must show up in the probe."""
    assert "sklearn" in _imported_by(["scene", "inspect", "home", "--json"], tmp_path)

"""Every regular expression in the product packages runs in linear time on Python's
backtracking engine, checked two ways over every pattern:

- structurally (``tests/support/regex_audit.py``): no repeat inside a repeat, no two repeats
  of overlapping characters side by side, no unguarded repeat that a search can start from
  every position of a run;
- on adversarial inputs (runs of 100,000 characters each repeat takes, with the pattern's
  literal prefix and a character none takes), in a subprocess with a CPU-time limit: a
  backstop, never a timing (a linear pattern needs a few milliseconds per input; a quadratic
  one needs minutes, and the limit is far from both).

The patterns are collected from the source: every ``re.<function>(...)`` call of ``agents``,
``tools``, ``sim``, ``orchestrator`` and ``benchmark``. A literal pattern is read from the call,
a module-level ``NAME = re.compile(...)`` from the imported module; a pattern built at run time
must be listed in ``BUILT_AT_RUN_TIME`` with the function that builds it and sample inputs,
so a new one cannot slip in unchecked. (pydantic ``Field(pattern=...)`` runs on the Rust
``regex`` crate, linear by construction, and is not collected.)
"""

from __future__ import annotations

import ast
import importlib
import json
import re
import subprocess
import sys
import textwrap
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from storyteller.agents.event_parser import fenced_blocks
from tests.support.regex_audit import backtracking_risks

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("agents", "tools", "sim", "orchestrator", "benchmark")
FUNCTIONS = {"compile", "match", "search", "fullmatch", "sub", "subn", "split", "findall", "finditer"}
FLAG_POSITION = {"compile": 1, "match": 2, "search": 2, "fullmatch": 2, "findall": 2, "finditer": 2,
                 "split": 3, "sub": 4, "subn": 4}  # fmt: skip
CPU_SECONDS = 10
"""CPU seconds the backstop subprocess allows each pattern on all its inputs (a linear one needs
well under a second; the old fence pattern needed about 20 s for each of them)."""


def _names() -> tuple[str, ...]:
    return ("Ava", "Ben", "Cleo")


def _instruction_patterns() -> list[tuple[str, int]]:
    from storyteller.agents import instruction_parts as ip

    run = ip._name_run(_names())
    return [(run, 0), (ip._leading_subject_pattern(run), 0), (ip._clause_cut_pattern(run), 0),
            (ip._consequence_pattern(run), 0)]


def _shortlist_patterns() -> list[tuple[str, int]]:
    from storyteller.agents import shortlist

    return [(shortlist.mention_pattern(word), 0) for word in ("coffee_maker_1", "ava", "a.b+c")]


def _story_text_patterns() -> list[tuple[str, int]]:
    """The shapes ``agents/narrator_words.py`` builds inline (mirrored here with sample words)."""
    import re as _re

    from storyteller.agents import narrator_words

    words = [_re.escape("coffee_maker_1"), _re.escape("coffee_maker").replace("_", "[ _]") + "s?", _re.escape("cup") + "s?"]
    return (
        [(r"(?:\bthe\s+)?(?P<id>" + narrator_words._ID_IN_TEXT.pattern + ")", _re.IGNORECASE)]
        + [(rf"(?<![a-z0-9_]){p}(?![a-z0-9_])", _re.IGNORECASE) for p in words]
        + [(rf"(?<![a-z]){_re.escape(w)}", 0) for w in ("sit", "coffee", "a.b")]
    )


def _fidelity_patterns() -> list[tuple[str, int]]:
    """The shape ``benchmark/story_text_fidelity.py`` (``raw_ids``) builds inline, mirrored."""
    import re as _re

    escaped = [_re.escape(n).replace("_", r"\\?_") for n in ("coffee_maker_1", "tv_2")]
    return [(rf"(?<![A-Za-z0-9_]){e}(?![A-Za-z0-9_])", 0) for e in escaped]


def _subject_patterns() -> list[tuple[str, int]]:
    from storyteller.agents import instruction_subjects

    built = [instruction_subjects.clause_pattern(names) for names in (("Ava", "Ben"), ("Ava", "A.v+a", "Cy"))]
    return [(p.pattern, p.flags) for p in built if p is not None]


BUILT_AT_RUN_TIME: dict[tuple[str, str], Callable[[], list[tuple[str, int]]]] = {
    ("agents/instruction_parts.py", "_actors"): _instruction_patterns,
    ("agents/instruction_parts.py", "_leading_subject"): _instruction_patterns,
    ("agents/instruction_parts.py", "_at_the_same_time"): _instruction_patterns,
    ("agents/instruction_subjects.py", "clause_pattern"): _subject_patterns,
    ("agents/shortlist.py", "_mentions"): _shortlist_patterns,
    ("agents/narrator_words.py", "with_names"): _story_text_patterns,
    ("agents/narrator_words.py", "_mentions_object"): _story_text_patterns,
    ("agents/narrator_words.py", "_says_word"): _story_text_patterns,
    ("agents/narrator_words.py", "unplanned_ids"): _story_text_patterns,
    ("benchmark/story_text_fidelity.py", "raw_ids"): _fidelity_patterns,
}
"""(file, enclosing function) of each call whose pattern is built at run time -> the patterns it
builds from sample inputs (character names, object names)."""


@dataclass(frozen=True)
class Site:
    where: str  # file:line
    pattern: str | bytes
    flags: int


def _flags(node: ast.expr | None) -> int:
    if node is None:
        return 0
    value = eval(compile(ast.Expression(node), "<flags>", "eval"), {"re": re})  # only re.X names
    return int(value)


def collect() -> tuple[list[Site], set[tuple[str, str]]]:
    """Every pattern of the product's ``re`` calls, and the sites met whose pattern is built at
    run time (checked through ``BUILT_AT_RUN_TIME``)."""
    sites: list[Site] = []
    dynamic: set[tuple[str, str]] = set()
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            tree = ast.parse(path.read_text(encoding="utf-8"))
            module_level = {id(n.value): n.targets[0].id for n in tree.body
                            if isinstance(n, ast.Assign) and isinstance(n.targets[0], ast.Name)}
            functions = {id(c): f.name for f in ast.walk(tree)
                         if isinstance(f, ast.FunctionDef | ast.AsyncFunctionDef) for c in ast.walk(f)}
            for call in ast.walk(tree):
                if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Attribute)
                        and isinstance(call.func.value, ast.Name) and call.func.value.id == "re"
                        and call.func.attr in FUNCTIONS and call.args):
                    continue
                where = f"{rel}:{call.lineno}"
                flag_node = next((k.value for k in call.keywords if k.arg == "flags"), None)
                position = FLAG_POSITION[call.func.attr]
                if flag_node is None and len(call.args) > position:
                    flag_node = call.args[position]
                first = call.args[0]
                if isinstance(first, ast.Constant) and isinstance(first.value, str | bytes):
                    sites.append(Site(where, first.value, _flags(flag_node)))
                elif id(call) in module_level:
                    module = importlib.import_module("storyteller." + rel.removesuffix(".py").replace("/", "."))
                    compiled = getattr(module, module_level[id(call)])
                    sites.append(Site(where, compiled.pattern, compiled.flags & ~re.UNICODE))
                else:
                    dynamic.add((rel, functions.get(id(call), "<module>")))
    for key, build in sorted(BUILT_AT_RUN_TIME.items()):
        for pattern, flags in build():
            sites.append(Site(f"{key[0]} ({key[1]}, built)", pattern, flags))
    return sites, dynamic


SITES, DYNAMIC = collect()


def test_the_collection_finds_the_patterns_it_must() -> None:
    where = {s.where.split(":")[0] for s in SITES}
    assert {"agents/event_parser.py", "sim/scene/meshes.py", "orchestrator/session/instruction_script.py",
            "agents/instruction_parts.py", "sim/bounded_files.py"} <= where
    assert len(SITES) > 40
    unlisted = DYNAMIC - set(BUILT_AT_RUN_TIME)
    assert not unlisted, f"patterns built at run time, not in BUILT_AT_RUN_TIME: {sorted(unlisted)}"
    assert set(BUILT_AT_RUN_TIME) == DYNAMIC, "a listed run-time site is gone: drop it from BUILT_AT_RUN_TIME"


def test_no_pattern_can_backtrack_super_linearly() -> None:
    risky = {f"{s.where}: {s.pattern!r}": [r.rule for r in backtracking_risks(s.pattern, s.flags)] for s in SITES}
    assert {k: v for k, v in risky.items() if v} == {}


def test_the_audit_flags_the_patterns_that_were_slow() -> None:
    """The structural check is not vacuous: the patterns issue 22 measured are flagged."""
    fence = r"```[ \t]*([A-Za-z0-9_+-]*)[ \t]*\n(.*?)(?:```|\Z)"
    assert "adjacent" in [r.rule for r in backtracking_risks(fence, re.DOTALL)]
    assert "adjacent" in [r.rule for r in backtracking_risks(r"([a-z][a-z0-9]*?)(\d+)")]
    assert [r.rule for r in backtracking_risks(r"(a+)+$")] == ["nested"]
    assert [r.rule for r in backtracking_risks(r"\s+and\s+then")] == ["leading"]
    assert backtracking_risks(r"(?<=[.!?;])\s+|\n+") == []


_BACKSTOP = textwrap.dedent(
    """
    import json, re, resource, sys
    sys.path.insert(0, sys.argv[2])
    from tests.support.regex_audit import pump_inputs
    seconds = int(sys.argv[1])
    for line in sys.stdin:
        case = json.loads(line)
        pattern = case["pattern"].encode("latin-1") if case["bytes"] else case["pattern"]
        compiled = re.compile(pattern, case["flags"])
        inputs = pump_inputs(pattern, case["flags"])
        used = resource.getrusage(resource.RUSAGE_SELF)
        soft = int(used.ru_utime + used.ru_stime) + 1 + seconds  # this pattern's CPU from now on
        resource.setrlimit(resource.RLIMIT_CPU, (soft, resource.RLIM_INFINITY))
        print(case["where"], flush=True)  # the last line printed names the pattern a kill stopped
        for subject in inputs:
            compiled.search(subject)
            compiled.match(subject)
            for _ in compiled.finditer(subject):
                pass
    print("done", flush=True)
    """
)


@pytest.mark.slow
def test_every_pattern_takes_adversarial_inputs_within_a_cpu_limit() -> None:
    lines = [
        json.dumps({"where": s.where, "flags": s.flags, "bytes": isinstance(s.pattern, bytes),
                    "pattern": s.pattern.decode("latin-1") if isinstance(s.pattern, bytes) else s.pattern})
        for s in SITES
    ]
    done = subprocess.run([sys.executable, "-c", _BACKSTOP, str(CPU_SECONDS), str(ROOT)], input="\n".join(lines),
                          capture_output=True, text=True, check=False)
    printed = done.stdout.split("\n")
    assert done.returncode == 0 and "done" in printed, f"stopped at {printed[-2:]}: {done.stderr[-500:]}"


# ----- the scans that replaced patterns give what the patterns gave --------------------------
_OLD_FENCE = re.compile(r"```[ \t]*([A-Za-z0-9_+-]*)[ \t]*\n(.*?)(?:```|\Z)", re.DOTALL)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.lists(st.sampled_from(["`", "```", "````", " ", "\t", "\n", "py", "x", "+", "def f():\n", "\r\n"]),
                max_size=14).map("".join))
def test_the_fence_scan_finds_the_blocks_the_pattern_found(text: str) -> None:
    assert fenced_blocks(text) == [m.group(2) for m in _OLD_FENCE.finditer(text)]

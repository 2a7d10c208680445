"""Every text an LLM reads lives in ``prompts/``: code names prompt files that exist, and no
string literal in ``agents/`` or ``orchestrator/planning/`` repeats a sentence of a prompt file.

The second check is what keeps a moved sentence from coming back: a feedback sentence or a
status line written again as an f-string beside its prompt file fails here.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from importlib import resources
from pathlib import Path

from storyteller.agents.prompt_templates import PLACEHOLDER, PromptLibrary

ROOT = Path(__file__).resolve().parents[2]
SCANNED = [*sorted((ROOT / "agents").rglob("*.py")), *sorted((ROOT / "orchestrator" / "planning").glob("*.py"))]
PROMPT_PATH = re.compile(r"^[a-z_]+(?:/[a-z_]+)*/[A-Za-z_]+\.md$")
WORD = re.compile(r"^\(?[A-Za-z]+[,.;:)]?$")


def _docstrings(tree: ast.AST) -> set[int]:
    """ids of bare string statements (module, class, function and attribute docstrings)."""
    return {
        id(node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)
    }


def string_literals(source: str) -> Iterator[str]:
    """String constants of ``source`` other than docstrings, f-strings' literal parts included."""
    tree = ast.parse(source)
    skip = _docstrings(tree)
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip:
            yield node.value


def prompt_sentences(text: str) -> set[str]:
    """The literal pieces of a prompt file (between placeholders, one line each) that are
    sentences or phrases: two plain words or more (not a lone word, punctuation or a line of
    code such as ``def parse_event():``)."""
    out = set()
    for piece in PLACEHOLDER.split(text)[::2]:  # split() puts the names at odd indices
        for line in piece.splitlines():
            line = line.strip()
            if len(line) >= 10 and sum(bool(WORD.match(w)) for w in line.split()) >= 2:
                out.add(line)
    return out


def _prompt_files() -> dict[str, str]:
    root = Path(str(resources.files("storyteller.prompts")))
    return {p.relative_to(root).as_posix(): p.read_text(encoding="utf-8") for p in sorted(root.rglob("*.md"))}


def sentences_in_code(sources: dict[str, str], prompt_texts: dict[str, str]) -> list[tuple[str, str, str]]:
    """(source file, prompt file, sentence) for every prompt sentence a string literal repeats."""
    wanted = {s: rel for rel, text in prompt_texts.items() for s in prompt_sentences(text)}
    hits = []
    for name, source in sources.items():
        for literal in string_literals(source):
            hits += [(name, rel, s) for s, rel in wanted.items() if s in literal]
    return hits


def test_every_prompt_file_named_in_code_exists() -> None:
    lib = PromptLibrary()
    named = sorted(
        {(path.relative_to(ROOT).as_posix(), s) for path in SCANNED for s in string_literals(path.read_text()) if PROMPT_PATH.match(s)}
    )
    assert len(named) > 40  # the scan sees the files the agents render
    missing = [(src, rel) for src, rel in named if not lib.exists(rel)]
    assert missing == []


def test_no_prompt_sentence_is_written_in_code() -> None:
    sources = {path.relative_to(ROOT).as_posix(): path.read_text() for path in SCANNED}
    assert sentences_in_code(sources, _prompt_files()) == []


def test_the_scan_finds_a_sentence_written_back_into_code() -> None:
    prompts = _prompt_files()
    planted = {
        "agents/x.py": '"""Docstrings may quote: is not a character in this story."""\n'
        'def f(name):\n    return f"{name} is not a character in this story"\n',
        "agents/y.py": 'LINE = "(nothing has happened yet)"\n',
    }
    hits = sentences_in_code(planted, prompts)
    assert ("agents/x.py", "feedback/narrator/not_a_character.md", "is not a character in this story") in hits
    assert ("agents/y.py", "story/history_empty.md", "(nothing has happened yet)") in hits
    assert len(hits) == 2  # the docstring is not a hit

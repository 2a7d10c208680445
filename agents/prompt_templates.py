"""Prompt files (``prompts/`` package data) and their strict rendering.

A prompt file is plain text with ``{{ name }}`` placeholders. Rendering replaces every
placeholder with the value given for it; a placeholder without a value is a
:class:`PromptTemplateError` (never an empty string), and so is a value given for a name the
template does not use (it would mean a caller and a prompt file disagree). Literal braces,
e.g. JSON in examples, need no escaping: only ``{{ identifier }}`` is a placeholder.

Files are read with :mod:`importlib.resources` from the ``prompts`` package by default; a
:class:`PromptLibrary` can be pointed at another folder (a user's prompt overrides, or a test's
edited copy). ``PromptLibrary.fingerprint`` hashes every file it has read, for cache keys.

Every text an LLM reads is such a file, down to one-line phrases (rendered with
:meth:`PromptLibrary.render_text`): a folder per role (``narrator/``, ``event_parser/``,
``describer/``, ``planner/``, ``direct/``), ``story/`` for the character, history and
instruction lines several roles share, ``feedback/`` for retry sentences (rule problems in a
sub-folder per role). ``tests/agents/test_prompt_sources.py`` fails when code names a missing file or
writes a prompt file's sentence as a string literal.
"""

from __future__ import annotations

import functools
import hashlib
import re
from collections.abc import Iterable, Mapping
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

from storyteller.sim.bounded_files import BoundedFileError, read_bounded_bytes

PLACEHOLDER = re.compile(r"\{\{\s*([A-Za-z_][A-Za-z0-9_]*)\s*\}\}")

BENCHMARK_TAGS: tuple[str, ...] = ("OA", "RC", "SS", "PI")
"""Benchmark tags with in-context examples: object affordance, region context, scene/character
state, position inference."""


MAX_PROMPT_BYTES = 1 << 20
"""Bytes of a prompt file read from a user's folder at most (ours are under 10 KB)."""


class PromptTemplateError(Exception):
    """A prompt file is missing, or a template and its values do not match."""


def placeholders(template: str) -> list[str]:
    """Placeholder names of ``template`` in order of first appearance."""
    seen: dict[str, None] = {}
    for match in PLACEHOLDER.finditer(template):
        seen.setdefault(match.group(1), None)
    return list(seen)


def render(template: str, values: Mapping[str, object], *, source: str = "<template>") -> str:
    """Fill ``{{ name }}`` placeholders; missing or unused values raise PromptTemplateError."""
    names = placeholders(template)
    missing = [n for n in names if n not in values]
    if missing:
        raise PromptTemplateError(f"{source}: no value for placeholder(s) {', '.join(missing)}")
    unused = sorted(set(values) - set(names))
    if unused:
        raise PromptTemplateError(f"{source}: value(s) given for unknown placeholder(s) {', '.join(unused)}")
    return PLACEHOLDER.sub(lambda m: str(values[m.group(1)]), template)


class PromptLibrary:
    """Reads prompt files by relative path, e.g. ``narrator/system.md``.

    ``root`` defaults to the installed ``prompts`` package; pass a folder to use other files.
    """

    def __init__(self, root: Path | None = None) -> None:
        self._root: Traversable = resources.files("storyteller.prompts") if root is None else Path(root)
        self._read: dict[str, str] = {}

    @property
    def root(self) -> str:
        return str(self._root)

    def text(self, relpath: str) -> str:
        """The file's text (cached per library instance)."""
        if relpath in self._read:
            return self._read[relpath]
        node = self._root
        for part in relpath.split("/"):
            node = node / part
        if not node.is_file():
            raise PromptTemplateError(f"prompt file '{relpath}' not found under {self._root}")
        if isinstance(node, Path):  # a user's folder: bounded, never a FIFO or a device (sim.bounded_files)
            try:
                text = read_bounded_bytes(node, MAX_PROMPT_BYTES, str(node)).decode("utf-8")
            except BoundedFileError as exc:
                raise PromptTemplateError(f"prompt file {exc}") from None
            except UnicodeDecodeError as exc:
                raise PromptTemplateError(f"prompt file {node}: not UTF-8 text (bad byte at offset {exc.start})") from None
        else:
            text = node.read_text(encoding="utf-8")
        self._read[relpath] = text
        return text

    def exists(self, relpath: str) -> bool:
        node = self._root
        for part in relpath.split("/"):
            node = node / part
        return node.is_file()

    def render(self, relpath: str, **values: object) -> str:
        return render(self.text(relpath), values, source=relpath)

    def render_text(self, relpath: str, **values: object) -> str:
        """:meth:`render` without the file's final newline: for a short text placed inside a
        message (a retry feedback sentence, an instruction)."""
        return render(self.text(relpath).removesuffix("\n"), values, source=relpath)

    def examples(self, role: str, tags: Iterable[str]) -> str:
        """In-context examples of ``role`` for the given benchmark tags, in BENCHMARK_TAGS order."""
        wanted = set(tags)
        unknown = wanted - set(BENCHMARK_TAGS)
        if unknown:
            raise PromptTemplateError(f"unknown example tag(s) {sorted(unknown)}; known: {list(BENCHMARK_TAGS)}")
        parts = [self.text(f"{role}/examples/{tag}.md").strip() for tag in BENCHMARK_TAGS if tag in wanted]
        return "\n\n".join(parts)

    def fingerprint(self, relpaths: Iterable[str]) -> str:
        """Short sha256 over the named files' contents (for cache keys)."""
        digest = hashlib.sha256()
        for relpath in sorted(relpaths):
            digest.update(relpath.encode())
            digest.update(b"\0")
            digest.update(self.text(relpath).encode("utf-8"))
            digest.update(b"\0")
        return digest.hexdigest()[:16]


@functools.cache
def package_prompts() -> PromptLibrary:
    """The library of the installed ``prompts`` package (for texts built where no library is
    passed, e.g. retry feedback raised deep in a parser)."""
    return PromptLibrary()

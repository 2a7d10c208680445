"""Prompt files and strict rendering."""

from __future__ import annotations

import re
import shutil
from importlib import resources
from pathlib import Path

import pytest

from storyteller.agents.prompt_templates import (
    BENCHMARK_TAGS,
    PromptLibrary,
    PromptTemplateError,
    placeholders,
    render,
)

REFERENCE_SCENE_WORDS = ("House", "Office", "Restaurant")


def test_render_fills_and_is_strict() -> None:
    assert render("a {{ x }} b {{y}} {{ x }}", {"x": 1, "y": "z"}) == "a 1 b z 1"
    with pytest.raises(PromptTemplateError, match="no value for placeholder"):
        render("{{ x }} {{ y }}", {"x": 1}, source="f.md")
    with pytest.raises(PromptTemplateError, match="unknown placeholder"):
        render("{{ x }}", {"x": 1, "extra": 2})


def test_json_braces_are_not_placeholders() -> None:
    text = '{"event": {"characters": []}} {{ name }}'
    assert placeholders(text) == ["name"]
    assert render(text, {"name": "Ann"}) == '{"event": {"characters": []}} Ann'


def test_every_role_has_its_files_and_examples_per_tag() -> None:
    lib = PromptLibrary()
    for role in ("narrator", "event_parser"):
        assert lib.exists(f"{role}/system.md") and lib.exists(f"{role}/request.md")
        for tag in BENCHMARK_TAGS:
            assert lib.text(f"{role}/examples/{tag}.md").strip()
    for role in ("describer", "planner", "direct"):
        assert lib.exists(f"{role}/system.md") and lib.exists(f"{role}/request.md")
    with pytest.raises(PromptTemplateError, match="unknown example tag"):
        lib.examples("narrator", ["XX"])
    with pytest.raises(PromptTemplateError, match="not found"):
        lib.text("narrator/nope.md")


def test_examples_never_use_reference_scenes_or_their_characters() -> None:
    root = Path(str(resources.files("storyteller.prompts")))
    for path in root.rglob("*.md"):
        text = path.read_text()
        for word in REFERENCE_SCENE_WORDS:
            assert word not in text, (path, word)
        # reference benchmark character names must not leak into our examples
        for name in ("Theodore", "Franklin", "Joshua", "Donna", "Alvin"):
            assert name not in text, (path, name)


def test_library_on_a_copy_and_fingerprint_changes_with_one_character(tmp_path: Path) -> None:
    root = Path(str(resources.files("storyteller.prompts")))
    copy = tmp_path / "prompts"
    shutil.copytree(root, copy)
    a = PromptLibrary(copy)
    before = a.fingerprint(["narrator/system.md"])
    path = copy / "narrator" / "system.md"
    path.write_text(path.read_text().replace("narrator", "narrateur", 1))
    assert PromptLibrary(copy).fingerprint(["narrator/system.md"]) != before
    assert PromptLibrary().fingerprint(["narrator/system.md"]) == before


def test_prompts_are_short_for_a_small_model() -> None:
    """Stable parts stay small: the 0.5B model reads ~150 tokens/s."""
    lib = PromptLibrary()

    def words(s: str) -> int:
        return len(re.findall(r"\S+", s))

    assert words(lib.text("narrator/system.md")) + words(lib.examples("narrator", BENCHMARK_TAGS)) < 450
    assert words(lib.text("event_parser/system.md")) + words(lib.examples("event_parser", BENCHMARK_TAGS)) < 500

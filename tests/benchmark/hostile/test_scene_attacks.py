"""The hostile-inputs harness's scene attack on names reaches the code that shows names: its
scene is valid apart from the names (before, it lacked ``bounds_min`` and was refused before
any name was read), and its check fails when the names are not shown as escaped text.
"""

from __future__ import annotations

from pathlib import Path

from storyteller.benchmark.hostile import scenes
from storyteller.benchmark.hostile.harness import BIDI, Box, Spec
from storyteller.sim.scene.model import Scene

NAMES_ATTACK = "names and labels with markup, ANSI, bidi, line separators"


def _built(tmp_path: Path) -> tuple[Box, Spec]:
    (build,) = [fn for _, name, fn in scenes.ATTACKS if name == NAMES_ATTACK]
    box = Box(tmp_path / "box", tmp_path / "base", tmp_path / "sweep", tmp_path / "box" / "CANARY")
    return box, build(box)


def test_the_names_attack_scene_is_valid_but_for_its_names(tmp_path: Path) -> None:
    box, spec = _built(tmp_path)
    scene = Scene.model_validate_json((box.root / "text.json").read_text(encoding="utf-8"))
    assert BIDI in scene.name and any(BIDI in obj.name for obj in scene.objects)
    assert spec.argv == ["scene", "inspect", str(box.root / "text.json")]


def test_the_names_attack_fails_when_the_names_are_not_shown(tmp_path: Path) -> None:
    _, spec = _built(tmp_path)
    assert spec.check_output is not None
    refused = "error: text.json: field 'bounds_min': required field is missing\n"
    assert spec.check_output(refused) is not None
    markup_applied = "[/]hostile\\u202e\\u2066\\x1b[31m\\x07: 2 objects\ntablex_1\n"  # rich ate "[bold red]"
    assert spec.check_output(markup_applied) is not None
    shown = "[/]hostile[bold red]\\u202e\\u2066\\x1b[31m\\x07\\u200b\\u2028: 2 objects\n│ table[bold red]x_1 │\n"
    assert spec.check_output(shown) is None

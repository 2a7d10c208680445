"""The hostile-inputs harness's scene and mesh attacks reach the code they target: each input is
valid apart from its hostile part, and each attack's check fails when the product refuses it for
another reason (a refusal at a missing ``bounds_min`` or a missing object ``name`` tests nothing).

Before, the scene of names lacked ``bounds_min`` and was refused before any name was read; 400
dense boxes, the cell size asking for 1e10 cells and the box sizes were refused for the same
missing floor (and their objects' missing names); the reference-folder attacks were refused at an
empty ``objects.json`` placeholder; a glTF of 1,000,000 points was refused as no whole number
of triangles; and a 5,000-digit face index hid an OBJ of 200,000 named objects.

Each attacked scene is loaded here in-process (``load_scene``, what every command reads scenes
with) and its refusal, printed as the CLI prints it, is given to the attack's check. Mesh
attacks build files of up to 64 MB, and one scene is 14 MB: the slow tier.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from storyteller.benchmark.hostile import scenes
from storyteller.benchmark.hostile.harness import BIDI, Attack, Box, Spec, refused_for, shown
from storyteller.benchmark.hostile.runner import ATTACKS
from storyteller.orchestrator.safe_text import plain
from storyteller.sim.scene.errors import SceneFileError
from storyteller.sim.scene.files import load_reference_folder, load_scene
from storyteller.sim.scene.model import Scene

NAMES_ATTACK = "names and labels with markup, ANSI, bidi, line separators"
SCENE_ATTACKS = [a for a in ATTACKS if a[0] == "scene"]
MESH_ATTACKS = [a for a in ATTACKS if a[0] == "mesh"]
WRONG_REASON = "error: /tmp/x/s.json: field 'bounds_min': required field is missing\n"
"""The refusal that hid the first attacks' targets: a scene without a floor."""


def _box(tmp_path: Path) -> Box:
    (tmp_path / "base").mkdir(parents=True)  # an empty run folder: one attack writes scene.json in a copy
    return Box(tmp_path / "box", tmp_path / "base", tmp_path / "sweep", tmp_path / "box" / "CANARY")


def _built(tmp_path: Path, name: str = NAMES_ATTACK, attacks: list[Attack] = SCENE_ATTACKS) -> tuple[Box, Spec]:
    (build,) = [fn for _, attack_name, fn in attacks if attack_name == name]
    box = _box(tmp_path)
    return box, build(box)


def _attacked_file(box: Box, spec: Spec) -> Path:
    if spec.command == "view --export":
        return box.run / "scene.json"
    return Path(spec.argv[2] if spec.command == "scene inspect" else spec.argv[1])


def _refusal(path: Path) -> str | None:
    """What the CLI prints when it refuses the scene at ``path`` (its one error line), or None
    when the scene loads."""
    try:
        load_scene(path)
    except SceneFileError as exc:
        return f"error: {plain(' '.join(str(exc).split()))}\n"
    return None


def _reaches_its_target(tmp_path: Path, name: str, attacks: list[Attack]) -> None:
    box, spec = _built(tmp_path, name, attacks)
    assert spec.check_output is not None, "an attack without a check passes when refused for any reason"
    assert spec.check_output(WRONG_REASON) is not None
    refusal = _refusal(_attacked_file(box, spec))
    if refusal is None:
        assert spec.expect == "either", "accepted, yet the attack expects a refusal"
    else:
        assert spec.check_output(refusal) is None, refusal


@pytest.mark.parametrize("name", [pytest.param(name, marks=[pytest.mark.slow] if "14 MB" in name else [])
                                  for _, name, _ in SCENE_ATTACKS])
def test_a_scene_attack_is_refused_only_for_its_hostile_part(tmp_path: Path, name: str) -> None:
    _reaches_its_target(tmp_path, name, SCENE_ATTACKS)


@pytest.mark.slow
@pytest.mark.parametrize("name", [name for _, name, _ in MESH_ATTACKS])
def test_a_mesh_attack_is_refused_only_for_its_hostile_part(tmp_path: Path, name: str) -> None:
    _reaches_its_target(tmp_path, name, MESH_ATTACKS)


def test_the_accepted_scene_attacks_reach_the_tables(tmp_path: Path) -> None:
    """400 overlapping boxes and a facing whose length overflows are valid scenes; the second was
    stored as a zero facing."""
    for i, (name, count) in enumerate((("400 dense boxes", 400), ("a facing of [1.7e308, -1.7e308]", 2))):
        (attack_name,) = [n for _, n, _ in SCENE_ATTACKS if n.startswith(name)]
        box, spec = _built(tmp_path / str(i), attack_name)
        scene = load_scene(_attacked_file(box, spec))
        assert len(scene.objects) == count
        assert all(abs(o.facing[0] ** 2 + o.facing[1] ** 2 - 1.0) < 1e-9 for o in scene.objects)


def test_the_reference_folder_without_the_reference_data_is_valid(tmp_path: Path) -> None:
    folder = scenes.reference_copy(_box(tmp_path), house=tmp_path / "no-reference-data")
    assert [o.name for o in load_reference_folder(folder).objects] == ["chair_1", "table_1"]


def test_a_refusal_must_name_the_hostile_part() -> None:
    check = refused_for("grid_map.json", "field 'x_margin'")
    assert check("hostile: 2 objects, floor [0.00, 4.00] x [0.00, 4.00] m\n") is None  # accepted
    assert check("error: House/grid_map.json: field 'x_margin': expected a number, got 'abc'\n") is None
    assert check("error: House/objects.json: expected a JSON list of objects at top level\n") is not None
    assert shown("chairs: 500 objects")("error: chairs.json: field 'objects': 2000 objects\n") is not None


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

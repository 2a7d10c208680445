"""Attacks on scene files: the project's JSON scenes (``scene inspect``, ``run``, a run folder's
``scene.json`` read by ``view --export``) and reference annotation folders. Mesh files are
attacked in :mod:`storyteller.benchmark.hostile.meshes`.

Each scene is valid but for its hostile part (:func:`~storyteller.benchmark.hostile.harness.scene_json`,
:func:`~storyteller.benchmark.hostile.harness.box_object`, :func:`reference_copy`), one to an attack,
and each attack's check fails when the product refuses it for another reason (such a refusal
tests nothing: 400 boxes without a floor were refused at ``bounds_min``).
"""

from __future__ import annotations

import gzip
import json
import re
import shutil
import unicodedata
from pathlib import Path

from storyteller.benchmark.hostile.harness import (
    BIDI,
    Attack,
    Box,
    Spec,
    box_object,
    deep_json,
    export,
    inspect,
    refused_for,
    registrar,
    scene_json,
    shown,
)
from storyteller.orchestrator.reference_data import locate_reference

ATTACKS: list[Attack] = []
attack = registrar(ATTACKS)


@attack("scene", "scene.json in the run folder: 30,000 boxes (export)")
def _run_scene_big(box: Box) -> Spec:
    run = box.copy_run()
    objects = [box_object(i, x=float(i % 170), y=i // 170 * 0.1) for i in range(30_000)]
    (run / "scene.json").write_text(scene_json(objects), encoding="utf-8")
    spec = export(box, "either")
    spec.check_output = refused_for("scene.json", "field 'objects'")
    return spec


@attack("scene", "JSON scene of 20,000 boxes")
def _scene_many(box: Box) -> Spec:
    objects = [box_object(i, size=0.4, x=(i % 140) * 0.5, y=(i // 140) * 0.5) for i in range(20_000)]
    return inspect(box.file("many.json", scene_json(objects)), check_output=refused_for("field 'objects'"))


@attack("scene", "400 dense boxes")
def _scene_dense(box: Box) -> Spec:
    """Overlapping boxes are a valid scene: the check requires it shown."""
    objects = [box_object(i, size=0.9, x=(i % 20) * 0.5, y=(i // 20) * 0.5) for i in range(400)]
    return inspect(box.file("dense.json", scene_json(objects)), "either",
                   check_output=shown("hostile: 400 objects"))


@attack("scene", "names and labels with markup, ANSI, bidi, line separators")
def _scene_text(box: Box) -> Spec:
    """A scene valid but for its names, so they reach the tables ``scene inspect`` prints; the
    check requires them shown, markup as text and the rest escaped (a refusal tests nothing)."""
    objects = [{"name": f"{label}_{i}", "label": label, "idx": i, "center": [2.0 * i, 0.0, 0.25],
                "size": [0.5, 0.5, 0.5]} for i, label in enumerate(("[/]" + BIDI + "chair", "table[bold red]x"))]
    scene = scene_json(objects, name="[/]hostile[bold red]" + BIDI, bounds_min=[-1.0, -1.0], bounds_max=[3.0, 1.0])
    return inspect(box.file("text.json", scene), "either", check_output=_names_shown)


def _names_shown(printed: str) -> str | None:
    """The scene name and a label with markup printed as text, the control characters escaped."""
    shown = ("[/]hostile[bold red]\\u202e\\u2066\\x1b[31m\\x07", "table[bold red]x_1")
    missing = [text for text in shown if text not in printed]
    return "names not shown as escaped text: " + ", ".join(missing) if missing else None


def _no_control_glyph(printed: str) -> str | None:
    """matplotlib warns of each glyph its font lacks, quoting its code: a control or format
    character among them was drawn raw."""
    drawn = sorted({int(code) for code in re.findall(r"Glyph (\d+) ", printed) if int(code) < 0x110000})
    raw = [f"U+{code:04X}" for code in drawn if unicodedata.category(chr(code)) in ("Cc", "Cf", "Zl", "Zp", "Cs")]
    return "drawn raw in the picture: " + ",".join(raw[:4]) if raw else None


@attack("scene", "names, labels and scene name with ANSI, BEL, bidi, line separators drawn (scene inspect --png)")
def _scene_text_png(box: Box) -> Spec:
    objects = [{"name": f"{label}_1", "label": label, "idx": 1, "center": [x, 0.0, 0.25], "size": [0.5, 0.5, 0.5]}
               for x, label in ((0.0, "chair" + BIDI), (2.0, "table\x1b]0;title\x07" + BIDI))]
    png = box.root / "top.png"
    scene = scene_json(objects, name="hostile" + BIDI, bounds_min=[-1.0, -1.0], bounds_max=[3.0, 1.0])
    spec = inspect(box.file("text.json", scene), "either")
    spec.argv += ["--png", str(png)]
    spec.writable = (png,)
    spec.check_output = lambda printed: "no picture drawn" if not png.is_file() else _no_control_glyph(printed)
    return spec


@attack("scene", "nav.cell_size asking for 1e10 cells")
def _scene_cells(box: Box) -> Spec:
    objects = [box_object(0), box_object(1), box_object(2, x=99.0, y=99.0)]  # a floor of 101 m by 101 m
    return inspect(box.file("cells.json", scene_json(objects, nav={"cell_size": 0.001})),
                   check_output=refused_for("navigation cells of 0.001 m"))


@attack("scene", "NaN and 1e999 in a box")
def _scene_nan(box: Box) -> Spec:
    text = scene_json([box_object(0), box_object(2)]).replace("[0.0, 0.0, 0.25]", "[NaN, 1e999, 0.25]", 1)
    return inspect(box.file("nan.json", text), check_output=refused_for("field 'center'", "NaN"))


@attack("scene", "gzip-compressed .json scene")
def _scene_gzip(box: Box) -> Spec:
    return inspect(box.file("gz.json", gzip.compress(scene_json([box_object(0)]).encode())),
                   check_output=refused_for("gz.json", "UTF-8"))


@attack("scene", "UTF-16 scene with BOM")
def _scene_utf16(box: Box) -> Spec:
    return inspect(box.file("u16.json", scene_json([box_object(0)]).encode("utf-16")), "either",
                   check_output=refused_for("u16.json", "UTF-8"))


@attack("scene", "nested 100,000 deep")
def _scene_deep(box: Box) -> Spec:
    floor = '{"name": "x", "bounds_min": [0, 0], "bounds_max": [4, 4], "objects": '
    return inspect(box.file("deep.json", floor + deep_json(100_000) + "}"),
                   check_output=refused_for("deep.json", "nested"))


@attack("scene", "FIFO scene (run SCENE_FILE)")
def _scene_fifo(box: Box) -> Spec:
    fifo = box.fifo(box.root / "fifo.json")
    out = box.root / "o"
    argv = ["run", str(fifo), "--out", str(out), "--no-interactive", "--no-live"]
    return Spec(argv, "run", "bad", writable=(out,), check_output=refused_for("fifo.json", "not a regular file"))


@attack("scene", "/dev/zero named scene.json (scene inspect)")
def _scene_zero(box: Box) -> Spec:
    return inspect(box.link(box.root / "zero.json", "/dev/zero"),
                   check_output=refused_for("zero.json", "not a regular file"))


@attack("scene", "a box of size -1")
def _scene_negative(box: Box) -> Spec:
    objects = [box_object(0), {**box_object(1), "size": [-1.0, 0.5, 0.5]}]
    return inspect(box.file("sizes.json", scene_json(objects)),
                   check_output=refused_for("object 'chair_1', field 'size'"))


@attack("scene", "a box of size 1e300")
def _scene_huge(box: Box) -> Spec:
    objects = [box_object(0), {**box_object(1), "size": [1e300, 1e300, 1.0]}]
    return inspect(box.file("sizes.json", scene_json(objects)),
                   check_output=refused_for("object 'chair_1', field 'size'"))


@attack("scene", "a facing of [1.7e308, -1.7e308] (its length overflows to inf)")
def _scene_facing_overflow(box: Box) -> Spec:
    """The direction is valid; the check requires it shown as a unit vector."""
    objects = [box_object(0), {**box_object(1), "facing": [1.7e308, -1.7e308], "has_facing": True}]
    return inspect(box.file("facing.json", scene_json(objects)), "either", check_output=shown("+0.71 -0.71"))


SMALL_HOUSE = {
    "objects.json": [{"label": "chair", "idx": 1, "center": [1.0, 1.0, 0.45], "width": 0.5, "depth": 0.5,
                      "height": 0.9, "orientation": [0.0, 1.0, 0.0], "has_orientation": True,
                      "sit_offset_vertical": 0.2},
                     {"label": "table", "idx": 1, "center": [2.5, 2.5, 0.375], "width": 1.2, "depth": 0.8,
                      "height": 0.75, "orientation": [1.0, 0.0, 0.0], "has_orientation": False}],
    "scene.json": {"bbox": [[0.0, 0.0, 0.0], [4.0, 4.0, 2.5]]},
    "grid_map.json": {"grid_step": 0.3, "x_margin": 0.1, "y_margin": 0.1, "cylinder_radius": 0.3,
                      "user_modifications": {"occupied": [], "unoccupied": []}},
    "scene_cfg.json": {},
}
"""A valid reference annotation folder of the reference data's files (``scene_cfg.json`` is not read)."""


def reference_copy(box: Box, house: Path | None = None) -> Path:
    """A valid reference folder in the box for an attack to break one file of: the reference
    data's House (``house``, default where :func:`locate_reference` finds it), else
    :data:`SMALL_HOUSE`. (A folder of empty files was refused at ``objects.json`` before any
    attacked file was read.)"""
    folder = box.root / "House"
    source = house or locate_reference().path / "configs" / "scenes" / "House"
    if (source / "objects.json").is_file():
        shutil.copytree(source, folder)
    else:
        folder.mkdir()
        for name, value in SMALL_HOUSE.items():
            (folder / name).write_text(json.dumps(value), encoding="utf-8")
    return folder


@attack("scene", "reference folder: objects.json a FIFO")
def _reference_fifo(box: Box) -> Spec:
    folder = reference_copy(box)
    box.fifo(folder / "objects.json")
    return inspect(folder, check_output=refused_for("objects.json", "not a regular file"))


@attack("scene", "reference folder: grid_map.json -> /dev/zero")
def _reference_zero(box: Box) -> Spec:
    folder = reference_copy(box)
    box.link(folder / "grid_map.json", "/dev/zero")
    return inspect(folder, check_output=refused_for("grid_map.json", "not a regular file"))


@attack("scene", "reference folder: scene.json deep, scene_cfg.json with bidi and 5,000 digits")
def _reference_text(box: Box) -> Spec:
    folder = reference_copy(box)
    (folder / "scene.json").write_text(deep_json(100_000), encoding="utf-8")
    config = '{"name": ' + json.dumps(BIDI) + ', "cell": ' + "9" * 5000 + "}"  # a file the product never reads
    (folder / "scene_cfg.json").write_text(config, encoding="utf-8")
    return inspect(folder, check_output=refused_for("scene.json", "nested"))


@attack("scene", "an object with 1.2 million unknown keys (14 MB)")
def _scene_keys(box: Box) -> Spec:
    obj = {"name": "chair_1", "label": "chair", "idx": 1, "center": [1.0, 1.0, 0.25], "size": [0.5, 0.5, 0.5],
           "facing": [0.0, 1.0], "has_facing": True, "sit_offset_horizontal": 0.0, "sit_offset_vertical": 0.0,
           "interactive": True, **{f"k{i}": 0 for i in range(1_200_000)}}
    text = json.dumps({"format": "storyteller-scene/1", "name": "keys", "floor_z": 0.0, "bounds_min": [0, 0],
                       "bounds_max": [4, 4], "objects": [obj]}, separators=(",", ":"))
    return inspect(box.file("keys.json", text), check_output=refused_for("keys.json", "1200010 keys"))


@attack("scene", "reference folder: grid_map.json margins of text, lists, 1e308")
def _reference_grid(box: Box) -> Spec:
    folder = reference_copy(box)
    margins = {"x_margin": "abc" + BIDI, "y_margin": [1e308]}  # control characters escaped in JSON, read into text
    (folder / "grid_map.json").write_text(json.dumps(margins), encoding="utf-8")
    return inspect(folder, check_output=refused_for("grid_map.json", "field 'x_margin'"))


def _chairs(count: int, floor: float, columns: int) -> str:
    """A valid scene of ``count`` chairs on a ``floor`` metres square, ``columns`` to a row."""
    step = (floor - 2) / columns
    objects = [{"name": f"chair_{i + 1}", "label": "chair", "idx": i + 1,
                "center": [1 + (i % columns) * step, 1 + (i // columns) * step, 0.25], "size": [0.5, 0.5, 0.5],
                "facing": [0.0, 1.0], "has_facing": True, "sit_offset_horizontal": 0.0, "sit_offset_vertical": 0.0,
                "interactive": True} for i in range(count)]
    return json.dumps({"format": "storyteller-scene/1", "name": "chairs", "floor_z": 0.0, "bounds_min": [0, 0],
                       "bounds_max": [floor, floor], "objects": objects})


@attack("scene", "a valid scene of 2,000 chairs 1.5 m apart (900 KB)")
def _scene_chairs(box: Box) -> Spec:
    return inspect(box.file("chairs.json", _chairs(2000, 69.5, 45)), "either",
                   check_output=refused_for("field 'objects'"))


@attack("scene", "a valid scene of 500 chairs on a 94 m floor")
def _scene_chairs_wide(box: Box) -> Spec:
    return inspect(box.file("chairs.json", _chairs(500, 94.0, 23)), "either",
                   check_output=shown("chairs: 500 objects"))


@attack("scene", "50 chairs on a 590 m floor (3.9 million cells)")
def _scene_floor(box: Box) -> Spec:
    return inspect(box.file("floor.json", _chairs(50, 590.0, 10)), "either",
                   check_output=refused_for("navigation cells"))

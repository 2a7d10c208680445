"""Attacks on scene files (JSON scenes, the reference scene folders) and meshes (``.obj``,
``.ply``, ``.glb``), read by ``scene inspect``, ``run`` and ``view --export``.
"""

from __future__ import annotations

import gzip
import json
import os
import re
import shutil
import struct
import unicodedata
from pathlib import Path

import numpy as np

from storyteller.benchmark.hostile.harness import (
    BIDI,
    Attack,
    Box,
    Spec,
    box_object,
    deep_json,
    export,
    glb_file,
    gltf_doc,
    inspect,
    registrar,
    scene_json,
    sparse_file,
)

ATTACKS: list[Attack] = []
attack = registrar(ATTACKS)


@attack("scene", "scene.json in the run folder: 30,000 boxes (export)")
def _run_scene_big(box: Box) -> Spec:
    run = box.copy_run()
    (run / "scene.json").write_text(scene_json([box_object(i % 170, y=i // 170 * 0.1) for i in range(30_000)]),
                                    encoding="utf-8")
    return export(box, "either")


@attack("scene", "JSON scene of 20,000 boxes")
def _scene_many(box: Box) -> Spec:
    objects = [box_object(i % 140, size=0.6, y=(i // 140) * 0.5) for i in range(20_000)]
    return inspect(box.file("many.json", scene_json(objects)))


@attack("scene", "400 dense boxes")
def _scene_dense(box: Box) -> Spec:
    objects = [box_object(i, size=0.9, x=(i % 20) * 0.5, y=(i // 20) * 0.5) for i in range(400)]
    return inspect(box.file("dense.json", scene_json(objects)), "either")


@attack("scene", "names and labels with markup, ANSI, bidi, line separators")
def _scene_text(box: Box) -> Spec:
    """A scene valid but for its names, so they reach the tables ``scene inspect`` prints; the
    check requires them shown, markup as text and the rest escaped (a refusal tests nothing)."""
    objects = [{"name": f"{label}_{i}", "label": label, "idx": i, "center": [2.0 * i, 0.0, 0.25],
                "size": [0.5, 0.5, 0.5]} for i, label in enumerate(("[/]" + BIDI + "chair", "table[bold red]x"))]
    scene = scene_json(objects, name="[/]hostile[bold red]" + BIDI, bounds_min=[-1.0, -1.0], bounds_max=[3.0, 1.0])
    spec = inspect(box.file("text.json", scene), "either")
    spec.check_output = _names_shown
    return spec


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


@attack("scene", "cell size asking for 1e10 cells")
def _scene_cells(box: Box) -> Spec:
    objects = [box_object(0), box_object(1), {**box_object(2), "center": [90000.0, 90000.0, 0.25]}]
    return inspect(box.file("cells.json", scene_json(objects, cell_size=0.001)))


@attack("scene", "NaN and 1e999 in a box")
def _scene_nan(box: Box) -> Spec:
    text = scene_json([box_object(0), box_object(2)]).replace("[0.0, 0.0, 0.25]", "[NaN, 1e999, 0.25]", 1)
    return inspect(box.file("nan.json", text))


@attack("scene", "gzip-compressed .json scene")
def _scene_gzip(box: Box) -> Spec:
    return inspect(box.file("gz.json", gzip.compress(scene_json([box_object(0)]).encode())))


@attack("scene", "UTF-16 scene with BOM")
def _scene_utf16(box: Box) -> Spec:
    return inspect(box.file("u16.json", scene_json([box_object(0)]).encode("utf-16")), "either")


@attack("scene", "nested 100,000 deep")
def _scene_deep(box: Box) -> Spec:
    return inspect(box.file("deep.json", '{"name": "x", "objects": ' + deep_json(100_000) + "}"))


@attack("scene", "FIFO scene (run SCENE_FILE)")
def _scene_fifo(box: Box) -> Spec:
    fifo = box.fifo(box.root / "fifo.json")
    out = box.root / "o"
    return Spec(["run", str(fifo), "--out", str(out), "--no-interactive", "--no-live"], "run", "bad", writable=(out,))


@attack("scene", "/dev/zero named scene.json (scene inspect)")
def _scene_zero(box: Box) -> Spec:
    return inspect(box.link(box.root / "zero.json", "/dev/zero"))


@attack("scene", "box sizes -1 and 1e300, heading 1e300")
def _scene_sizes(box: Box) -> Spec:
    objects = [box_object(0), {**box_object(1), "size": [-1.0, 0.5, 0.5]},
               {**box_object(2), "size": [1e300, 1e300, 1.0], "heading": 1e300}]
    return inspect(box.file("sizes.json", scene_json(objects)))


REFERENCE_HOUSE = Path(os.environ.get("STORYTELLER_REFERENCE", "/nonexistent")) / "configs" / "scenes" / "House"


def _reference_copy(box: Box) -> Path:
    folder = box.root / "House"
    if REFERENCE_HOUSE.is_dir():
        shutil.copytree(REFERENCE_HOUSE, folder)
    else:  # without the reference data: a folder of the same files, empty
        folder.mkdir()
        for name in ("objects.json", "scene.json", "scene_cfg.json", "grid_map.json"):
            (folder / name).write_text("{}", encoding="utf-8")
    return folder


@attack("scene", "reference folder: objects.json a FIFO, grid_map.json -> /dev/zero")
def _reference_special(box: Box) -> Spec:
    folder = _reference_copy(box)
    box.fifo(folder / "objects.json")
    box.link(folder / "grid_map.json", "/dev/zero")
    return inspect(folder)


@attack("scene", "reference folder: scene.json deep, scene_cfg.json with bidi and 5,000 digits")
def _reference_text(box: Box) -> Spec:
    folder = _reference_copy(box)
    (folder / "scene.json").write_text(deep_json(100_000), encoding="utf-8")
    (folder / "scene_cfg.json").write_text('{"name": "' + BIDI + '", "cell": ' + "9" * 5000 + "}", encoding="utf-8")
    return inspect(folder)


@attack("mesh", ".obj with a 60,000-digit object name and 300,000 vertices")
def _mesh_obj(box: Box) -> Spec:
    lines = ["o " + "7" * 60_000 + BIDI]
    lines += [f"v {i % 97 * 0.01} {i % 89 * 0.01} {i % 83 * 0.01}" for i in range(300_000)]
    lines += [f"f {i + 1} {i + 2} {i + 3}" for i in range(0, 299_997, 3)]
    return inspect(box.file("big.obj", "\n".join(lines) + "\n"), "either")


@attack("mesh", ".ply claiming 10**15 vertices")
def _mesh_ply(box: Box) -> Spec:
    text = "ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000000\nproperty float x\n" \
           "property float y\nproperty float z\nend_header\n"
    return inspect(box.file("huge.ply", text.encode() + b"\0" * 1200))


@attack("mesh", ".glb JSON chunk claiming 4 GB, node names with control characters")
def _mesh_glb(box: Box) -> Spec:
    doc = json.dumps({"asset": {"version": "2.0"}, "nodes": [{"name": "\x1b[2J" + BIDI}], "scenes": [{"nodes": [0]}]})
    body = doc.encode() + b" " * (-len(doc.encode()) % 4)
    glb = b"glTF" + struct.pack("<II", 2, 12 + 8 + len(body)) + struct.pack("<I", 0xFFFFFFF0) + b"JSON" + body
    return inspect(box.file("huge.glb", glb))


@attack("mesh", ".glb with a 5,000-digit accessor index")
def _mesh_glb_index(box: Box) -> Spec:
    doc = '{"asset": {"version": "2.0"}, "meshes": [{"primitives": [{"attributes": {"POSITION": ' + "9" * 5000 + \
          '}}]}], "nodes": [{"mesh": 0, "name": "chair_1"}], "scenes": [{"nodes": [0]}]}'
    body = doc.encode() + b" " * (-len(doc.encode()) % 4)
    glb = b"glTF" + struct.pack("<II", 2, 12 + 8 + len(body)) + struct.pack("<I", len(body)) + b"JSON" + body
    return inspect(box.file("index.glb", glb))


@attack("mesh", ".obj with 200,000 named objects and 5,000-digit face indices")
def _mesh_objects(box: Box) -> Spec:
    lines = ["v 0 0 0", "v 1 0 0", "v 0 1 0", "v 0 0 1"]
    for i in range(200_000):
        lines += [f"o chair_{i}", "f 1 2 3"]
    lines += ["o table_1", "f " + "9" * 5000 + " 2 3"]
    return inspect(box.file("objects.obj", "\n".join(lines) + "\n"), "either")


TRIANGLE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4").tobytes()


@attack("mesh", ".gltf whose buffer is a FIFO")
def _gltf_fifo(box: Box) -> Spec:
    box.fifo(box.root / "buf.bin")
    return inspect(box.file("s.gltf", json.dumps(gltf_doc([{"mesh": 0, "name": "chair_1"}], uri="buf.bin"))))


@attack("mesh", ".gltf whose buffer is a sparse 3 GB file")
def _gltf_sparse(box: Box) -> Spec:
    sparse_file(box.root / "buf.bin", 3 << 30)
    return inspect(box.file("s.gltf", json.dumps(gltf_doc([{"mesh": 0, "name": "chair_1"}], uri="buf.bin"))))


@attack("mesh", ".gltf buffer ../outside/secret.txt and a symlink to it")
def _gltf_outside(box: Box) -> Spec:
    (box.root / "link.bin").symlink_to(box.outside / "secret.txt")
    doc = gltf_doc([{"mesh": 0, "name": "chair_1"}, {"mesh": 1, "name": "table_1"}], uri="../outside/secret.txt")
    doc["buffers"].append({"byteLength": 36, "uri": "link.bin"})
    return inspect(box.file("s.gltf", json.dumps(doc)), "either")


@attack("mesh", ".obj naming a FIFO material library and a sparse 3 GB one")
def _obj_mtllib(box: Box) -> Spec:
    box.fifo(box.root / "m.mtl")
    sparse_file(box.root / "n.mtl", 3 << 30)
    text = "mtllib m.mtl\nmtllib n.mtl\no chair_1\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nusemtl x\nf 1 2 3\nf 1 2 4\n"
    return inspect(box.file("s.obj", text), "either")


@attack("mesh", ".glb: 2,000 nodes instancing one 1M-vertex geometry (12 MB)")
def _glb_instances(box: Box) -> Spec:
    n = 1_000_000
    points = np.random.default_rng(0).random((n, 3)).astype("<f4").tobytes()
    nodes = [{"mesh": 0, "name": f"chair_{i + 1}", "translation": [i % 45 * 1.5, 0, i // 45 * 1.5]} for i in range(2000)]
    return inspect(box.file("instances.glb", glb_file(gltf_doc(nodes, n), points)))


def _chain(box: Box, depth: int) -> Spec:
    nodes = [{"name": f"n{i}", "children": [i + 1]} for i in range(depth)] + [{"mesh": 0, "name": "chair_1"}]
    doc = gltf_doc(nodes)
    doc["scenes"] = [{"nodes": [0]}]
    return inspect(box.file("chain.glb", glb_file(doc, TRIANGLE)))


@attack("mesh", ".glb: a chain of 100,000 nested nodes")
def _glb_chain(box: Box) -> Spec:
    return _chain(box, 100_000)


@attack("mesh", ".glb: a chain of 19,000 nested nodes (quadratic transforms)")
def _glb_chain_short(box: Box) -> Spec:
    return _chain(box, 19_000)


@attack("mesh", ".glb: a bufferless accessor of 2e8 items, a count of 1e9, a node cycle")
def _glb_counts(box: Box) -> Spec:
    doc = gltf_doc([{"mesh": 0, "name": "chair_1", "children": [1]}, {"name": "x", "children": [0]}])
    del doc["accessors"][0]["bufferView"]
    doc["accessors"][0]["count"] = 200_000_000
    doc["accessors"].append({"bufferView": 0, "componentType": 5126, "count": 10**9, "type": "MAT4"})
    return inspect(box.file("counts.glb", glb_file(doc, TRIANGLE)))


@attack("mesh", ".glb: a node scaled by 1e308 (numpy overflow warnings)")
def _glb_scale(box: Box) -> Spec:
    doc = gltf_doc([{"mesh": 0, "name": "chair_1", "scale": [1e308, 1e308, 1e308]}])
    return inspect(box.file("scale.glb", glb_file(doc, TRIANGLE)))


@attack("scene", "an object with 1.2 million unknown keys (14 MB)")
def _scene_keys(box: Box) -> Spec:
    obj = {"name": "chair_1", "label": "chair", "idx": 1, "center": [1.0, 1.0, 0.25], "size": [0.5, 0.5, 0.5],
           "facing": [0.0, 1.0], "has_facing": True, "sit_offset_horizontal": 0.0, "sit_offset_vertical": 0.0,
           "interactive": True, **{f"k{i}": 0 for i in range(1_200_000)}}
    text = json.dumps({"format": "storyteller-scene/1", "name": "keys", "floor_z": 0.0, "bounds_min": [0, 0],
                       "bounds_max": [4, 4], "objects": [obj]}, separators=(",", ":"))
    return inspect(box.file("keys.json", text))


@attack("scene", "reference folder: grid_map.json margins of text, lists, 1e308")
def _reference_grid(box: Box) -> Spec:
    folder = _reference_copy(box)
    (folder / "grid_map.json").write_text('{"x_margin": "abc' + BIDI + '", "y_margin": [1e308]}', encoding="utf-8")
    return inspect(folder)


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
    return inspect(box.file("chairs.json", _chairs(2000, 69.5, 45)), "either")


@attack("scene", "a valid scene of 500 chairs on a 94 m floor")
def _scene_chairs_wide(box: Box) -> Spec:
    return inspect(box.file("chairs.json", _chairs(500, 94.0, 23)), "either")


@attack("scene", "50 chairs on a 590 m floor (3.9 million cells)")
def _scene_floor(box: Box) -> Spec:
    return inspect(box.file("floor.json", _chairs(50, 590.0, 10)), "either")


@attack("mesh", ".obj of 8 million faces (64 MB)")
def _obj_faces(box: Box) -> Spec:
    head = "o chair_1\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
    return inspect(box.file("faces.obj", head + "f 1 2 3\nf 1 2 4\n" * 4_000_000))


@attack("mesh", ".obj of 2,500 faces of 12,000 corners (30 million triangles)")
def _obj_polygons(box: Box) -> Spec:
    head = "o chair_1\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
    return inspect(box.file("polygons.obj", head + ("f " + " ".join(str(1 + i % 4) for i in range(12_000)) + "\n") * 2500))


@attack("mesh", "binary .ply of 4.5 million faces (58 MB)")
def _ply_faces(box: Box) -> Spec:
    faces = 4_500_000
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
            f"property float z\nelement face {faces}\nproperty list uchar int vertex_indices\nend_header\n").encode()
    table = np.zeros(faces, dtype=[("n", "u1"), ("i", "<i4", (3,))])
    table["n"] = 3
    table["i"] = [0, 1, 2]
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype="<f4").tobytes()
    return inspect(box.file("faces.ply", head + corners + table.tobytes()), "either")

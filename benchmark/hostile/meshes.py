"""Attacks on mesh scene files (``.obj``, ``.ply``, ``.glb``, ``.gltf``), read by ``scene inspect``.

Each file is a mesh the loader would read but for its hostile part (one to an attack: a second
one would be refused first and test nothing), and each attack's check fails when the product
refuses it for another reason (:func:`~storyteller.benchmark.hostile.harness.refused_for`) or
does not show what it must accept (:func:`~storyteller.benchmark.hostile.harness.shown`).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from storyteller.benchmark.hostile.harness import (
    BIDI,
    Attack,
    Box,
    Spec,
    glb_file,
    gltf_doc,
    inspect,
    refused_for,
    registrar,
    shown,
    sparse_file,
)

ATTACKS: list[Attack] = []
attack = registrar(ATTACKS)


@attack("mesh", ".obj with a 60,000-digit object name and 300,000 vertices")
def _mesh_obj(box: Box) -> Spec:
    lines = ["o " + "7" * 60_000 + BIDI]
    lines += [f"v {i % 97 * 0.01} {i % 89 * 0.01} {i % 83 * 0.01}" for i in range(300_000)]
    lines += [f"f {i + 1} {i + 2} {i + 3}" for i in range(0, 299_997, 3)]
    return inspect(box.file("big.obj", "\n".join(lines) + "\n"), "either",
                   check_output=refused_for("field 'name'", "60009 characters"))


@attack("mesh", ".ply claiming 10**15 vertices")
def _mesh_ply(box: Box) -> Spec:
    text = "ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000000\nproperty float x\n" \
           "property float y\nproperty float z\nend_header\n"
    return inspect(box.file("huge.ply", text.encode() + b"\0" * 1200),
                   check_output=refused_for("huge.ply", "length"))


@attack("mesh", ".glb JSON chunk claiming 4 GB")
def _mesh_glb(box: Box) -> Spec:
    doc = json.dumps(gltf_doc([{"mesh": 0, "name": "chair_1"}]))
    body = doc.encode() + b" " * (-len(doc.encode()) % 4)
    glb = b"glTF" + struct.pack("<II", 2, 12 + 8 + len(body)) + struct.pack("<I", 0xFFFFFFF0) + b"JSON" + body
    return inspect(box.file("huge.glb", glb), check_output=refused_for("huge.glb", "chunk"))


@attack("mesh", ".glb node names with escapes, bidi and line separators")
def _mesh_glb_names(box: Box) -> Spec:
    """Names are read as labels (lower snake case): nothing of them may reach the terminal raw."""
    doc = gltf_doc([{"mesh": 0, "name": "\x1b[2J" + BIDI}, {"mesh": 0, "name": "chair\x1b]0;x\x07" + BIDI + "_1"}])
    return inspect(box.file("names.glb", glb_file(doc, TRIANGLE)), "either",
                   check_output=shown("names: 2 objects"))


@attack("mesh", ".glb with a 5,000-digit accessor index")
def _mesh_glb_index(box: Box) -> Spec:
    doc = '{"asset": {"version": "2.0"}, "meshes": [{"primitives": [{"attributes": {"POSITION": ' + "9" * 5000 + \
          '}}]}], "nodes": [{"mesh": 0, "name": "chair_1"}], "scenes": [{"nodes": [0]}]}'
    body = doc.encode() + b" " * (-len(doc.encode()) % 4)
    glb = b"glTF" + struct.pack("<II", 2, 12 + 8 + len(body)) + struct.pack("<I", len(body)) + b"JSON" + body
    return inspect(box.file("index.glb", glb), check_output=refused_for("index.glb", "5000 digits"))


OBJ_CORNERS = ["v 0 0 0", "v 1 0 0", "v 0 1 0", "v 0 0 1"]


@attack("mesh", ".obj with 200,000 named objects")
def _mesh_objects(box: Box) -> Spec:
    lines = [*OBJ_CORNERS, *(line for i in range(200_000) for line in (f"o chair_{i}", "f 1 2 3"))]
    return inspect(box.file("objects.obj", "\n".join(lines) + "\n"), "either",
                   check_output=refused_for("objects.obj", "objects"))


@attack("mesh", ".obj with a 5,000-digit face index")
def _mesh_face_digits(box: Box) -> Spec:
    lines = [*OBJ_CORNERS, "o chair_1", "f 1 2 3", "o table_1", "f " + "9" * 5000 + " 2 3"]
    return inspect(box.file("digits.obj", "\n".join(lines) + "\n"),
                   check_output=refused_for("digits.obj", "index"))


TRIANGLE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4").tobytes()


@attack("mesh", ".gltf whose buffer is a FIFO")
def _gltf_fifo(box: Box) -> Spec:
    box.fifo(box.root / "buf.bin")
    return inspect(box.file("s.gltf", json.dumps(gltf_doc([{"mesh": 0, "name": "chair_1"}], uri="buf.bin"))),
                   check_output=refused_for("buf.bin", "not a regular file"))


@attack("mesh", ".gltf whose buffer is a sparse 3 GB file")
def _gltf_sparse(box: Box) -> Spec:
    sparse_file(box.root / "buf.bin", 3 << 30)
    return inspect(box.file("s.gltf", json.dumps(gltf_doc([{"mesh": 0, "name": "chair_1"}], uri="buf.bin"))),
                   check_output=refused_for("buf.bin", "3221225472 bytes"))


def _gltf_in_folder(box: Box, uri: str) -> Path:
    """A glTF in its own folder beside the box's ``outside`` (``../outside/secret.txt`` names the
    secret), whose one buffer is ``uri``."""
    (box.root / "mesh").mkdir()
    doc = gltf_doc([{"mesh": 0, "name": "chair_1"}], uri=uri)
    return box.file("mesh/s.gltf", json.dumps(doc))


@attack("mesh", ".gltf buffer ../outside/secret.txt")
def _gltf_outside(box: Box) -> Spec:
    return inspect(_gltf_in_folder(box, "../outside/secret.txt"), "either",
                   check_output=refused_for("../outside/secret.txt", "outside its folder"))


@attack("mesh", ".gltf buffer: a symlink in its folder to a file outside")
def _gltf_link(box: Box) -> Spec:
    gltf = _gltf_in_folder(box, "link.bin")
    (gltf.parent / "link.bin").symlink_to(box.outside / "secret.txt")
    return inspect(gltf, "either", check_output=refused_for("link.bin", "outside its folder"))


@attack("mesh", ".obj naming a FIFO material library and a sparse 3 GB one")
def _obj_mtllib(box: Box) -> Spec:
    """Materials are never read: the check requires the object shown."""
    box.fifo(box.root / "m.mtl")
    sparse_file(box.root / "n.mtl", 3 << 30)
    text = "mtllib m.mtl\nmtllib n.mtl\no chair_1\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nusemtl x\nf 1 2 3\nf 1 2 4\n"
    return inspect(box.file("s.obj", text), "either", check_output=shown("s: 1 objects"))


@attack("mesh", ".glb: 2,000 nodes instancing one 1M-vertex geometry (12 MB)")
def _glb_instances(box: Box) -> Spec:
    n = 999_999  # a whole number of triangles: 1,000,000 points were refused as a geometry trimesh cannot split
    points = np.random.default_rng(0).random((n, 3)).astype("<f4").tobytes()
    nodes = [{"mesh": 0, "name": f"chair_{i + 1}", "translation": [i % 45 * 1.5, 0, i // 45 * 1.5]} for i in range(2000)]
    return inspect(box.file("instances.glb", glb_file(gltf_doc(nodes, n), points)),
                   check_output=refused_for("instances.glb", "vertices"))


def _chain(box: Box, depth: int, refusal: str) -> Spec:
    nodes = [{"name": f"n{i}", "children": [i + 1]} for i in range(depth)] + [{"mesh": 0, "name": "chair_1"}]
    doc = gltf_doc(nodes)
    doc["scenes"] = [{"nodes": [0]}]
    return inspect(box.file("chain.glb", glb_file(doc, TRIANGLE)),
                   check_output=refused_for("chain.glb", refusal))


@attack("mesh", ".glb: a chain of 100,000 nested nodes")
def _glb_chain(box: Box) -> Spec:
    return _chain(box, 100_000, "nodes")


@attack("mesh", ".glb: a chain of 19,000 nested nodes (quadratic transforms)")
def _glb_chain_short(box: Box) -> Spec:
    return _chain(box, 19_000, "deeper than")


@attack("mesh", ".glb: a bufferless accessor of 2e8 items, a count of 1e9")
def _glb_counts(box: Box) -> Spec:
    doc = gltf_doc([{"mesh": 0, "name": "chair_1"}])
    del doc["accessors"][0]["bufferView"]
    doc["accessors"][0]["count"] = 200_000_000
    doc["accessors"].append({"bufferView": 0, "componentType": 5126, "count": 10**9, "type": "MAT4"})
    return inspect(box.file("counts.glb", glb_file(doc, TRIANGLE)),
                   check_output=refused_for("counts.glb", "accessors"))


@attack("mesh", ".glb: a node cycle")
def _glb_cycle(box: Box) -> Spec:
    doc = gltf_doc([{"mesh": 0, "name": "chair_1", "children": [1]}, {"name": "x", "children": [0]}])
    doc["scenes"] = [{"nodes": [0]}]  # the cycle hangs from the scene's one root
    return inspect(box.file("cycle.glb", glb_file(doc, TRIANGLE)),
                   check_output=refused_for("cycle.glb", "cycle"))


@attack("mesh", ".glb: a node scaled by 1e308 (numpy overflow warnings)")
def _glb_scale(box: Box) -> Spec:
    doc = gltf_doc([{"mesh": 0, "name": "chair_1", "scale": [1e308, 1e308, 1e308]}])
    return inspect(box.file("scale.glb", glb_file(doc, TRIANGLE)),
                   check_output=refused_for("object 'chair_1'", "within"))


@attack("mesh", ".obj of 8 million faces (64 MB)")
def _obj_faces(box: Box) -> Spec:
    head = "o chair_1\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
    return inspect(box.file("faces.obj", head + "f 1 2 3\nf 1 2 4\n" * 4_000_000),
                   check_output=refused_for("faces.obj", "triangles"))


@attack("mesh", ".obj of 2,500 faces of 12,000 corners (30 million triangles)")
def _obj_polygons(box: Box) -> Spec:
    head = "o chair_1\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
    polygon = "f " + " ".join(str(1 + i % 4) for i in range(12_000)) + "\n"
    return inspect(box.file("polygons.obj", head + polygon * 2500),
                   check_output=refused_for("polygons.obj", "triangles"))


@attack("mesh", "binary .ply of 4.5 million faces (58 MB)")
def _ply_faces(box: Box) -> Spec:
    faces = 4_500_000
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
            f"property float z\nelement face {faces}\nproperty list uchar int vertex_indices\nend_header\n").encode()
    table = np.zeros(faces, dtype=[("n", "u1"), ("i", "<i4", (3,))])
    table["n"] = 3
    table["i"] = [0, 1, 2]
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype="<f4").tobytes()
    return inspect(box.file("faces.ply", head + corners + table.tobytes()), "either",
                   check_output=refused_for("faces.ply", "triangles"))

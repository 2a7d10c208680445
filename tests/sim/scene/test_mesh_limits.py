"""What a mesh file may make the loader do (``storyteller.sim.scene.mesh_limits``), found by the hostile
corpus (``python -m storyteller.benchmark.hostile_inputs``, issue 22): a ``.gltf`` whose buffer is a FIFO
hung ``scene inspect``, a sparse 3 GB buffer or material library filled 2 GB, an OBJ's
``mtllib`` FIFO hung it, 100,000 nested nodes and 2,000 instances of a 1M-vertex geometry ran
past a minute, a 1e308 scale printed numpy's warnings before the error line."""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from storyteller.benchmark.hostile.harness import gltf_doc
from storyteller.sim.scene import mesh_limits
from storyteller.sim.scene.files import SceneFileError, load_scene

TRIANGLE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4")


def _doc(nodes: list[dict[str, Any]], count: int = 3, uri: str | None = None) -> dict[str, Any]:
    """The hostile harness's glTF document (``storyteller.benchmark.hostile.harness.gltf_doc``) with only the
    first node at the scene's root (a chain or a cycle hangs from it)."""
    return {**gltf_doc(nodes, count, uri), "scenes": [{"nodes": [0]}]}


def _glb(path: Path, doc: dict[str, Any], binary: bytes = TRIANGLE.tobytes()) -> Path:
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<I", len(text)) + b"JSON" + text + struct.pack("<I", len(binary)) + b"BIN\0" + binary
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks)
    return path


def _refused(path: Path, words: str) -> None:
    with pytest.raises(SceneFileError) as info:
        load_scene(path)
    assert words in str(info.value), str(info.value)


def test_a_plain_glb_loads(tmp_path: Path) -> None:
    scene = load_scene(_glb(tmp_path / "ok.glb", _doc([{"mesh": 0, "name": "chair_1"}])))
    assert [o.name for o in scene.objects] == ["chair_1"]


def test_gltf_buffer_that_is_a_fifo_is_refused_not_waited_on(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "buf.bin")
    (tmp_path / "s.gltf").write_text(json.dumps(_doc([{"mesh": 0, "name": "chair_1"}], uri="buf.bin")))
    _refused(tmp_path / "s.gltf", "not a regular file")


def test_gltf_buffer_larger_than_a_mesh_file_is_refused_unread(tmp_path: Path) -> None:
    with open(tmp_path / "buf.bin", "wb") as f:
        f.truncate(3 << 30)  # sparse: costs nothing on disk
    (tmp_path / "s.gltf").write_text(json.dumps(_doc([{"mesh": 0, "name": "chair_1"}], uri="buf.bin")))
    _refused(tmp_path / "s.gltf", "more than the")


def test_gltf_buffer_outside_the_folder_is_refused(tmp_path: Path) -> None:
    (tmp_path / "in").mkdir()
    (tmp_path / "buf.bin").write_bytes(TRIANGLE.tobytes())
    (tmp_path / "in" / "s.gltf").write_text(json.dumps(_doc([{"mesh": 0, "name": "chair_1"}], uri="../buf.bin")))
    _refused(tmp_path / "in" / "s.gltf", "outside its folder")


def test_obj_material_library_is_never_read(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "m.mtl")
    (tmp_path / "s.obj").write_text("mtllib m.mtl\no chair_1\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nusemtl x\n"
                                    "f 1 2 3\nf 1 2 4\n")
    assert [o.name for o in load_scene(tmp_path / "s.obj").objects] == ["chair_1"]


def test_accessors_declaring_gigabytes_are_refused(tmp_path: Path) -> None:
    doc = _doc([{"mesh": 0, "name": "chair_1"}])
    del doc["accessors"][0]["bufferView"]  # bufferless: trimesh would allocate zeros of any count
    doc["accessors"][0]["count"] = 200_000_000
    _refused(_glb(tmp_path / "zeros.glb", doc), "accessors declare")


def test_too_many_nodes_are_refused_before_loading(tmp_path: Path) -> None:
    nodes: list[dict[str, Any]] = [{}] * mesh_limits.MAX_MESH_NODES + [{"mesh": 0, "name": "chair_1"}]
    _refused(_glb(tmp_path / "nodes.glb", _doc(nodes)), "nodes, at most")


def test_deep_and_cyclic_hierarchies_are_refused(tmp_path: Path) -> None:
    depth = mesh_limits.MAX_NODE_DEPTH + 5
    chain = [{"name": f"n{i}", "children": [i + 1]} for i in range(depth)] + [{"mesh": 0, "name": "chair_1"}]
    _refused(_glb(tmp_path / "deep.glb", _doc(chain)), "deeper than")
    cycle: list[dict[str, Any]] = [{"mesh": 0, "name": "chair_1", "children": [1]}, {"name": "x", "children": [0]}]
    _refused(_glb(tmp_path / "cycle.glb", _doc(cycle)), "node hierarchy")


def test_instances_count_their_vertices_each_time(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(mesh_limits, "MAX_MESH_VERTICES", 5)
    one = _glb(tmp_path / "one.glb", _doc([{"mesh": 0, "name": "chair_1"}]))
    assert len(load_scene(one).objects) == 1  # 3 vertices
    two = _doc([{"mesh": 0, "name": "chair_1"}, {"mesh": 0, "name": "chair_2", "translation": [2, 0, 0]}])
    two["scenes"] = [{"nodes": [0, 1]}]
    _refused(_glb(tmp_path / "two.glb", two), "vertices in all")  # 6: the one geometry counted twice


def test_huge_scale_is_one_error_and_no_warning(tmp_path: Path) -> None:
    # pytest runs with warnings as errors: numpy's overflow warning would fail this test
    doc = _doc([{"mesh": 0, "name": "chair_1", "scale": [1e308, 1e308, 1e308]}])
    _refused(_glb(tmp_path / "scale.glb", doc), "within")


def test_declared_triangles_are_counted_before_loading(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Found by the hostile corpus: a 64 MB OBJ of 8 million faces ran past 12 s and 1.4 GB in
    trimesh's reader; a face of k corners makes k - 2 triangles, a glTF primitive a third of its
    index (or position) count."""
    assert mesh_limits.obj_triangles(b"f 1 2 3\nf 1 2 3 4\nv 0 0 0\nf\t1 2 3 4 5\r\n") == 6
    monkeypatch.setattr(mesh_limits, "MAX_MESH_FACES", 4)
    head = "o chair_1\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
    (tmp_path / "lines.obj").write_text(head + "f 1 2 3\n" * 5)
    _refused(tmp_path / "lines.obj", "5 triangles")
    (tmp_path / "polygon.obj").write_text(head + "f " + " ".join(["1", "2", "3", "4"] * 2) + "\n")
    _refused(tmp_path / "polygon.obj", "6 triangles")
    (tmp_path / "four.obj").write_text(head + "f 1 2 3\n" * 4)
    assert len(load_scene(tmp_path / "four.obj").objects) == 1
    doc = _doc([{"mesh": 0, "name": "chair_1"}], count=15)  # 5 triangles of positions
    _refused(_glb(tmp_path / "five.glb", doc, np.zeros((15, 3), dtype="<f4").tobytes()), "5 triangles")


def test_obj_objects_are_counted_before_loading(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Found by the hostile corpus once its OBJ of 200,000 named objects was no longer refused for
    a 5,000-digit face index first: trimesh took 160 s and 1.3 GB to build them before the count of
    its nodes refused the file."""
    import trimesh

    from storyteller.sim.scene import meshes

    monkeypatch.setattr(meshes, "MAX_SCENE_OBJECTS", 3)
    corners = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
    (tmp_path / "three.obj").write_text(corners + "".join(f"o chair_{i}\nf 1 2 3\n" for i in range(1, 4)))
    assert len(load_scene(tmp_path / "three.obj").objects) == 3
    (tmp_path / "four.obj").write_text(corners + "".join(f"o chair_{i}\nf 1 2 3\n" for i in range(1, 5)))
    monkeypatch.setattr(trimesh, "load_scene", lambda *args, **kwargs: pytest.fail("trimesh read the file"))
    _refused(tmp_path / "four.obj", "more than 3 OBJ objects")

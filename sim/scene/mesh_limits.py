"""What a mesh file may make trimesh do, checked before and while it is read (``storyteller.sim.scene.meshes``).

A mesh file is small on disk but can ask for much more: a glTF accessor declares how many items
it holds and trimesh allocates that many (a bufferless accessor is zeros of any ``count``, a
``byteStride`` of 1 reads a MAT4 per byte), a ``.gltf`` names other files for its buffers (a
FIFO there hangs the reader, a sparse file of gigabytes fills memory), an OBJ names material
libraries and textures, a node hierarchy thousands deep costs trimesh time quadratic in the
depth for every transform, and one geometry instanced by 2,000 nodes is transformed 2,000 times.
So:

- :func:`check_gltf_declarations` reads the JSON part of a ``.glb`` / ``.gltf`` (the bytes
  already read within ``MAX_MESH_FILE_BYTES``) with :func:`storyteller.sim.bounded_files.load_bounded_json`
  (nesting, number and key limits) and refuses more than :data:`MAX_MESH_NODES` nodes or
  accessors declaring more than :data:`MAX_MESH_ARRAY_BYTES` in all, before trimesh builds
  anything;
- :class:`BoundedResolver` is the only way trimesh reaches another file: inside the mesh file's
  folder (trimesh's own rule), a regular file (never a FIFO or a device), and all of them
  together within ``MAX_MESH_FILE_BYTES`` (``storyteller.sim.bounded_files.read_bounded_bytes``); materials
  and textures are not read at all (the loader passes ``skip_materials``);
- :func:`check_mesh_graph`, on the loaded scene graph, refuses a hierarchy deeper than
  :data:`MAX_NODE_DEPTH` and geometry nodes holding more than :data:`MAX_MESH_VERTICES`
  vertices in all (instances counted each time), in time linear in the nodes.

Every refusal is a :class:`~storyteller.sim.scene.errors.SceneFileError` naming the file.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from trimesh.resolvers import Resolver

from storyteller.sim.bounded_files import BoundedFileError, load_bounded_json, read_bounded_bytes
from storyteller.sim.scene.errors import SceneFileError

MAX_MESH_NODES = 20_000
"""Nodes a glTF file may declare (geometry or not: 40 per object a scene may hold)."""
MAX_MESH_ARRAY_BYTES = 256 * 1024 * 1024
"""Bytes all accessors of a glTF file may declare together (4 x the largest mesh file)."""
MAX_NODE_DEPTH = 64
"""Levels of a mesh file's node hierarchy."""
MAX_MESH_VERTICES = 4_000_000
"""Vertices of all geometry nodes together, an instanced geometry counted once per node."""
MAX_MESH_FACES = 2_000_000
"""Triangles a mesh file may declare (an OBJ's face lines, a glTF's primitives): trimesh's load
costs about 2 s and 250 MB per million (8 million in a 64 MB OBJ: past 12 s and 1.4 GB)."""
MAX_GLTF_JSON_DEPTH = 32
"""Nesting of a glTF file's JSON (the format needs about 8)."""

_COMPONENT_BYTES: dict[Any, int] = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_TYPE_ITEMS: dict[Any, int] = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def _gltf_json_bytes(path: Path, data: bytes) -> bytes:
    if path.suffix.lower() != ".glb":
        return data
    if len(data) < 20 or data[:4] != b"glTF":
        raise SceneFileError(path, "cannot read mesh file (not a GLB file: no 'glTF' header)")
    (length,) = struct.unpack_from("<I", data, 12)
    if data[16:20] != b"JSON" or length > len(data) - 20:
        raise SceneFileError(path, "cannot read mesh file (its first chunk is not a JSON chunk within the file)")
    return data[20 : 20 + length]


def check_gltf_declarations(path: Path, data: bytes) -> None:
    """Refuse a ``.glb`` / ``.gltf`` (its bytes ``data``) whose JSON declares more nodes or
    accessor bytes than allowed, or cannot be read as bounded JSON."""
    try:
        doc = load_bounded_json(_gltf_json_bytes(path, data), MAX_GLTF_JSON_DEPTH, "JSON part")
    except BoundedFileError as exc:
        raise SceneFileError(path, str(exc)) from None
    if not isinstance(doc, dict):
        raise SceneFileError(path, "glTF JSON is not an object")
    nodes = doc.get("nodes", [])
    if isinstance(nodes, list) and len(nodes) > MAX_MESH_NODES:
        raise SceneFileError(path, f"{len(nodes)} nodes, at most {MAX_MESH_NODES} allowed in a mesh file", field="nodes")
    accessors = doc.get("accessors", [])
    total = 0
    for i, acc in enumerate(accessors if isinstance(accessors, list) else []):
        if not isinstance(acc, dict):
            continue
        count = acc.get("count", 0)
        if not isinstance(count, int) or isinstance(count, bool) or count < 0:
            raise SceneFileError(path, f"count must be a whole number >= 0, got {count!r:.40}", field=f"accessors.{i}.count")
        total += count * _COMPONENT_BYTES.get(acc.get("componentType"), 4) * _TYPE_ITEMS.get(acc.get("type"), 16)
    if total > MAX_MESH_ARRAY_BYTES:
        raise SceneFileError(path, f"accessors declare {total} bytes of data, more than the {MAX_MESH_ARRAY_BYTES} allowed",
                             field="accessors")
    check_declared_faces(path, _gltf_triangles(doc, accessors if isinstance(accessors, list) else []))


def _gltf_triangles(doc: dict[str, Any], accessors: list[Any]) -> int:
    """Triangles the primitives of ``doc`` declare (a third of their index or position count)."""
    def count(ref: Any) -> int:
        acc = accessors[ref] if isinstance(ref, int) and 0 <= ref < len(accessors) else None
        value = acc.get("count", 0) if isinstance(acc, dict) else 0
        return value if isinstance(value, int) else 0

    triangles = 0
    meshes = doc.get("meshes", [])
    for mesh in meshes if isinstance(meshes, list) else []:
        primitives = mesh.get("primitives", []) if isinstance(mesh, dict) else []
        for prim in primitives if isinstance(primitives, list) else []:
            if isinstance(prim, dict):
                attributes = prim.get("attributes", {})
                position = attributes.get("POSITION") if isinstance(attributes, dict) else None
                triangles += count(prim.get("indices", position)) // 3
    return triangles


def obj_triangles(data: bytes) -> int:
    """Triangles the face lines (``f a b c ...``) of OBJ text make: k - 2 for a face of k corners,
    counted with numpy over the bytes (a Python loop over 8 million lines took 7 s and 850 MB)."""
    lines_of_faces = data.count(b"\nf ") + data.startswith(b"f ")
    if lines_of_faces > MAX_MESH_FACES:  # a triangle at least per line: enough to refuse, no arrays
        return lines_of_faces
    text = np.frombuffer(data, dtype=np.uint8)
    if len(text) < 2:
        return 0
    blank = (text == 32) | (text == 9) | (text == 10) | (text == 13)
    starts = np.concatenate(([0], np.flatnonzero(text == 10) + 1))
    starts = starts[starts < len(text) - 1]
    faces = starts[(text[starts] == ord("f")) & ((text[starts + 1] == 32) | (text[starts + 1] == 9))]
    if not len(faces):
        return 0
    # a word starts at a non-blank after a blank (or at the start); per line: "f" and its corners
    word = np.empty(len(text), dtype=bool)
    word[0] = not blank[0]
    word[1:] = blank[:-1] & ~blank[1:]
    lines = np.concatenate(([0], np.flatnonzero(text == 10) + 1))
    lines = lines[lines < len(text)]
    per_line = np.add.reduceat(word, lines, dtype=np.int64)
    return int(np.maximum(per_line[np.searchsorted(lines, faces)] - 3, 0).sum())


def check_declared_faces(path: Path, triangles: int) -> None:
    """Refuse a mesh file that declares more than :data:`MAX_MESH_FACES` triangles."""
    if triangles > MAX_MESH_FACES:
        raise SceneFileError(path, f"{triangles} triangles, at most {MAX_MESH_FACES} allowed in a mesh file")


class BoundedResolver(Resolver):
    """What trimesh reads the files a mesh file names (glTF buffers) through: names inside the
    mesh file's folder only (trimesh's own rule), regular files only, ``budget`` bytes in all;
    nothing is listed or written."""

    def __init__(self, source: Path, budget: int) -> None:
        self.folder = source.parent.resolve()
        self.left = budget

    def get(self, key: str) -> bytes:
        path = (self.folder / str(key).strip()).resolve()
        if not path.is_relative_to(self.folder):
            raise ValueError(f"{str(key)[:80]!r} named by the mesh file is outside its folder")
        data = read_bounded_bytes(path, max(self.left, 0), f"{str(key)[:80]!r} named by the mesh file")
        self.left -= len(data)
        return data

    def write(self, name: str, data: Any) -> None:
        raise ValueError("a mesh file is read, never written beside")

    def namespaced(self, namespace: str) -> BoundedResolver:
        raise ValueError("a mesh file may name files in its own folder only")

    def keys(self) -> Iterator[str]:
        return iter(())


def check_mesh_graph(path: Path, graph: Any, geometry: Mapping[str, Any]) -> None:
    """Refuse a loaded trimesh scene ``graph`` deeper than :data:`MAX_NODE_DEPTH` or whose
    geometry nodes hold more than :data:`MAX_MESH_VERTICES` vertices in all."""
    parents: Mapping[Any, Any] = graph.transforms.parents
    depth: dict[Any, int] = {}
    for node in parents:
        chain: list[Any] = []
        current = node
        while current in parents and current not in depth:
            if chain and current == node:
                raise SceneFileError(path, "node hierarchy has a cycle", obj=str(node)[:40])
            chain.append(current)
            if len(chain) > MAX_NODE_DEPTH:
                raise SceneFileError(path, f"node hierarchy deeper than {MAX_NODE_DEPTH} levels", obj=str(node)[:40])
            current = parents[current]
        base = depth.get(current, 0)
        for k, n in enumerate(reversed(chain), start=1):
            depth[n] = base + k
        if depth.get(node, 0) > MAX_NODE_DEPTH:
            raise SceneFileError(path, f"node hierarchy deeper than {MAX_NODE_DEPTH} levels", obj=str(node)[:40])
    total = 0
    for node in graph.nodes_geometry:
        geom = geometry.get(str(graph.transforms.node_data[node].get("geometry")))
        total += len(getattr(geom, "vertices", ()))
        if total > MAX_MESH_VERTICES:
            raise SceneFileError(path, f"geometry nodes hold more than {MAX_MESH_VERTICES} vertices in all "
                                       "(an instanced geometry counts once per node)")

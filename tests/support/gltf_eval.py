"""Reading a glTF document back in tests: accessors as numpy arrays, node world matrices with
the animation sampled at one key (what a glTF viewer computes), independent of our writer."""

from __future__ import annotations

import numpy as np
import pygltflib as gl
from scipy.spatial.transform import Rotation

NUMPY_DTYPES = {
    gl.FLOAT: np.float32,
    gl.UNSIGNED_SHORT: np.uint16,
    gl.UNSIGNED_BYTE: np.uint8,
    gl.UNSIGNED_INT: np.uint32,
}
COMPONENTS = {gl.SCALAR: 1, gl.VEC2: 2, gl.VEC3: 3, gl.VEC4: 4, gl.MAT4: 16}


def read_accessor(doc: gl.GLTF2, index: int) -> np.ndarray:
    acc = doc.accessors[index]
    view = doc.bufferViews[acc.bufferView]
    blob = doc.binary_blob()
    dtype = np.dtype(NUMPY_DTYPES[acc.componentType])
    width = COMPONENTS[acc.type]
    start = view.byteOffset + acc.byteOffset
    data = np.frombuffer(blob, dtype=dtype, count=acc.count * width, offset=start)
    return data.reshape(acc.count, width) if width > 1 else data


def _local_matrix(node: gl.Node) -> np.ndarray:
    m = np.eye(4)
    if node.rotation is not None:
        m[:3, :3] = Rotation.from_quat(node.rotation).as_matrix()
    if node.scale is not None:
        m[:3, :3] = m[:3, :3] @ np.diag(node.scale)
    if node.translation is not None:
        m[:3, 3] = node.translation
    return m


def world_matrices(doc: gl.GLTF2, frame: int) -> list[np.ndarray]:
    """Every node's world matrix with the animation sampled at key ``frame``."""
    nodes = [
        gl.Node(**{k: getattr(n, k) for k in ("rotation", "translation", "scale")})
        for n in doc.nodes
    ]
    for c in doc.animations[0].channels:
        value = read_accessor(doc, doc.animations[0].samplers[c.sampler].output)[frame]
        setattr(nodes[c.target.node], c.target.path, [float(x) for x in value])
    world: list[np.ndarray | None] = [None] * len(nodes)

    def visit(i: int, parent: np.ndarray) -> None:
        matrix = parent @ _local_matrix(nodes[i])
        world[i] = matrix
        for child in doc.nodes[i].children:
            visit(child, matrix)

    for root in doc.scenes[doc.scene].nodes:
        visit(root, np.eye(4))
    placed = [m for m in world if m is not None]
    assert len(placed) == len(world), "a node is not reachable from the scene's roots"
    return placed

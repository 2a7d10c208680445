""":func:`~storyteller.orchestrator.viewer.bone_updates.pose_bones` against viser's per-bone setters: the same
bone state and the same messages, in the same order, for poses that change some bones, all of
them, none, or by less than ``np.allclose``'s tolerance."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import viser
from viser import _messages

from storyteller.orchestrator.viewer.bone_updates import pose_bones
from storyteller.orchestrator.viewer.figures import standin_rig
from storyteller.sim.body.skeleton import NUM_JOINTS


@pytest.fixture
def server() -> Iterator[viser.ViserServer]:
    srv = viser.ViserServer(port=0, verbose=False)
    yield srv
    srv.stop()


def _poses(rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    w = rng.normal(size=(NUM_JOINTS, 4))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    p = rng.normal(size=(NUM_JOINTS, 3))
    some = w.copy()
    some[3:9] = -some[3:9]
    tiny = p + 1e-10  # within np.allclose's tolerance: nothing sent
    half = p.copy()
    half[::2] += 0.01
    return [(w, p), (w, p), (some, p), (some, tiny), (some, half), (w.copy() * 0.5, half * 2)]


def test_pose_bones_does_what_the_setters_do(server: viser.ViserServer, monkeypatch: pytest.MonkeyPatch) -> None:
    rig = standin_rig()
    identity = np.tile([1.0, 0.0, 0.0, 0.0], (NUM_JOINTS, 1))
    meshes = {name: server.scene.add_mesh_skinned(f"/f/{name}", rig.vertices, rig.faces, bone_wxyzs=identity,
                                                  bone_positions=rig.bind_positions, skin_weights=rig.skin_weights)
              for name in ("setters", "pose_bones")}  # fmt: skip
    sent: list[tuple[str, str, int, tuple[float, ...]]] = []

    def record(message: _messages.Message) -> None:
        if isinstance(message, _messages.SetBoneOrientationMessage):
            sent.append(("wxyz", message.name.rsplit("/", 1)[-1], message.bone_index, message.wxyz))
        elif isinstance(message, _messages.SetBonePositionMessage):
            sent.append(("position", message.name.rsplit("/", 1)[-1], message.bone_index, message.position))
        else:
            sent.append((type(message).__name__, "", -1, ()))

    monkeypatch.setattr(server.scene, "_queue_scene_message", record)
    for wxyz, pos in _poses(np.random.default_rng(7)):
        sent.clear()
        for j, bone in enumerate(meshes["setters"].bones):
            bone.wxyz = wxyz[j]
            bone.position = pos[j]
        by_setters = [(kind, j, v) for kind, name, j, v in sent if name != "pose_bones"]
        sent.clear()
        count = pose_bones(meshes["pose_bones"].bones, wxyz, pos)
        assert [(kind, j, v) for kind, name, j, v in sent if name != "setters"] == by_setters
        assert count == len(by_setters)
        for a, b in zip(meshes["setters"].bones, meshes["pose_bones"].bones, strict=True):
            assert a.wxyz.tobytes() == b.wxyz.tobytes() and a.position.tobytes() == b.position.tobytes()
    assert sent  # the recorder saw the messages (the last pose changes every bone)

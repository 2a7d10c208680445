"""SMPL-X bodies (``--smplx-model``): computed with the real ``smplx`` package from the exported
parameters, skinned in the GLB export and in the viewer. Uses the stand-in model of
``tests.support.smplx_standin`` (no pose correctives, so skinning must equal smplx's output)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pygltflib as gl
import pytest
import smplx
import torch
import viser
from typer.testing import CliRunner

from storyteller.benchmark.support.random_tracks import random_track
from storyteller.orchestrator.bodies.smplx_meshes import (
    SmplxBody,
    SmplxModelError,
    SmplxModels,
    load_parameters,
    model_file,
    posed_vertices,
    run_bodies,
    smplx_bodies,
)
from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.viewer.run_folder import load_run
from storyteller.orchestrator.viewer.scene_view import SceneView
from storyteller.sim.body.skeleton import BODY_TO_WORLD, NUM_JOINTS, REST_OFFSETS, heading_to_root
from storyteller.sim.export.bundle import export_run
from storyteller.sim.export.smplx_npz import smplx_parameters
from storyteller.sim.world.character_track import CharacterTrack
from tests.support.gltf_eval import read_accessor, world_matrices
from tests.support.smplx_standin import NUM_FACES, NUM_VERTICES, write_standin_model


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("models")
    write_standin_model(root)
    return root


def _glide(name: str, frames: int = 12, betas: tuple[float, ...] = (0.0,) * 10) -> CharacterTrack:
    """Upright, facing +x, the pelvis gliding 3 cm per frame along +x."""
    rot = np.broadcast_to(np.eye(3), (frames, NUM_JOINTS, 3, 3)).copy()
    rot[:, 0] = heading_to_root(0.0)
    root = np.column_stack([0.03 * np.arange(frames), np.full(frames, 1.0), np.full(frames, 0.92)])
    return CharacterTrack(name=name, root_positions=root, local_rotations=rot, betas=np.array(betas))


def _smplx_vertices(model_dir: Path, params: dict[str, np.ndarray]) -> np.ndarray:
    """The model's own output for the parameters (N, V, 3)."""
    n = params["poses"].shape[0]
    model = smplx.create(
        str(model_dir), model_type="smplx", gender="neutral", ext="npz", use_pca=False,
        flat_hand_mean=True, num_betas=10, batch_size=n,
    )  # fmt: skip
    poses = torch.tensor(params["poses"], dtype=torch.float32)
    with torch.no_grad():
        out = model(
            betas=torch.tensor(np.tile(params["betas"], (n, 1)), dtype=torch.float32),
            global_orient=poses[:, :3], body_pose=poses[:, 3:66], transl=torch.tensor(params["trans"], dtype=torch.float32),
        )  # fmt: skip
    return np.asarray(out.vertices.numpy(), dtype=np.float64)


def test_skinned_body_is_what_smplx_computes(model_dir: Path) -> None:
    track = random_track("a", 16, seed=5, max_joint_angle=1.2)
    params = smplx_parameters(track)
    body = smplx_bodies(model_dir, {"a": params})["a"]
    assert body.skin.vertices.shape == (NUM_VERTICES, 3) and body.skin.faces.shape == (NUM_FACES, 3)
    assert body.skin.joints.max() < NUM_JOINTS  # jaw, eyes and fingers folded into head and wrists
    np.testing.assert_allclose(body.bone_positions, track.joint_positions(), atol=1e-5)
    theirs = _smplx_vertices(model_dir, params)
    for frame in (0, 7, 15):
        assert np.abs(posed_vertices(body, frame) - theirs[frame]).max() < 1e-4


def test_a_vertex_near_the_pelvis_moves_with_trans(model_dir: Path) -> None:
    track = _glide("g")
    params = smplx_parameters(track)
    body = smplx_bodies(model_dir, {"g": params})["g"]
    near = int(np.argmin(np.linalg.norm(body.skin.vertices - body.skin.bind_joints[0], axis=1)))
    path = np.array([posed_vertices(body, k)[near] for k in range(track.num_frames)])
    np.testing.assert_allclose(path - path[0], params["trans"] - params["trans"][0], atol=1e-6)
    assert np.linalg.norm(path[-1] - path[0]) > 0.3


def test_missing_model_and_parameter_files_are_named(model_dir: Path, tmp_path: Path) -> None:
    assert model_file(model_dir, "female").name == "SMPLX_NEUTRAL.npz"  # falls back to neutral
    with pytest.raises(SmplxModelError, match=r"no SMPLX_NEUTRAL\.npz"):
        model_file(tmp_path, "neutral")
    with pytest.raises(SmplxModelError, match=r"Ava\.smplx\.npz: not found"):
        run_bodies(tmp_path, ["Ava"], SmplxModels(model_dir))


def _glb_body_vertices(doc: gl.GLTF2, name: str, frame: int) -> np.ndarray:
    """A character's skinned mesh at animation key ``frame``, evaluated from the file (world, z up)."""
    world = world_matrices(doc, frame)
    skin = next(s for s in doc.skins if s.name == name)
    node = next(n for n in doc.nodes if n.name == f"{name}:body")
    prim = doc.meshes[node.mesh].primitives[0]
    pos = read_accessor(doc, prim.attributes.POSITION).astype(float)
    joints = read_accessor(doc, prim.attributes.JOINTS_0).astype(int)
    weights = read_accessor(doc, prim.attributes.WEIGHTS_0).astype(float)
    ibm = read_accessor(doc, skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    skinning = np.array([world[j] for j in skin.joints]) @ ibm  # (22, 4, 4)
    homogeneous = np.column_stack([pos, np.ones(len(pos))])
    moved = np.einsum("vkij,vj->vki", skinning[joints], homogeneous)[..., :3]
    vertices: np.ndarray = np.einsum("vk,vki->vi", weights, moved) @ BODY_TO_WORLD.T
    return vertices


def test_glb_carries_the_smplx_mesh_skinned_and_animated(model_dir: Path, tmp_path: Path) -> None:
    """With betas the body's pelvis differs from ours: the GLB must still show what smplx shows."""
    moving = random_track("a", 10, seed=1, max_joint_angle=1.0)
    tall = np.array((3.0,) + (0.0,) * 9)  # beta 0 of the stand-in: +6 % height
    a = CharacterTrack(name="a", root_positions=moving.root_positions, local_rotations=moving.local_rotations, betas=tall)
    tracks = [a, _glide("b", 10)]
    body = smplx_bodies(model_dir, {"a": smplx_parameters(a)})["a"]
    assert body.skin.bind_joints[0, 1] > 1.05 * REST_OFFSETS[0][1]
    export_run(tmp_path, None, tracks, bodies={"a": body.skin})
    doc = gl.GLTF2.load(str(tmp_path / "scene.glb"))
    mesh_a = doc.meshes[next(n for n in doc.nodes if n.name == "a:body").mesh]
    mesh_b = doc.meshes[next(n for n in doc.nodes if n.name == "b:body").mesh]
    assert doc.accessors[mesh_a.primitives[0].attributes.POSITION].count == NUM_VERTICES
    assert doc.accessors[mesh_a.primitives[0].indices].count == 3 * NUM_FACES
    assert doc.accessors[mesh_b.primitives[0].attributes.POSITION].count < 2000  # b keeps the boxes
    assert [s.name for s in doc.skins] == ["a", "b"] and all(len(s.joints) == NUM_JOINTS for s in doc.skins)
    animated = {c.target.node for c in doc.animations[0].channels}
    assert set(doc.skins[0].joints) <= animated
    theirs = _smplx_vertices(model_dir, smplx_parameters(a))
    for frame in (0, 9):
        assert np.abs(_glb_body_vertices(doc, "a", frame) - theirs[frame]).max() < 1e-4


def _run_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "run"
    tracks = [_glide("Ava"), random_track("Ben", 12, seed=2, max_joint_angle=0.8)]
    export_run(folder, None, tracks)
    story = {"scene": "nowhere", "characters": ["Ava", "Ben"], "instruction": "x", "fps": 30, "events": []}
    (folder / "story.json").write_text(json.dumps(story), encoding="utf-8")
    return folder


def test_viewer_scene_shows_the_smplx_bodies(model_dir: Path, tmp_path: Path) -> None:
    folder = _run_folder(tmp_path)
    run = load_run(folder)
    bodies: dict[str, SmplxBody] = run_bodies(folder, ["Ava", "Ben"], SmplxModels(model_dir))
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        view = SceneView(server, run, bodies=bodies)
        for name in ("Ava", "Ben"):
            assert view.figures[name].vertices.shape == (NUM_VERTICES, 3)
        view.show(11)
        ava = view.figures["Ava"]
        np.testing.assert_allclose([b.position for b in ava.bones], bodies["Ava"].bone_positions[11], atol=1e-6)
        plain = SceneView(server, run)  # without --smplx-model: the stand-in figures
        assert plain.figures["Ava"].vertices.shape[0] < 2000
    finally:
        server.stop()


def test_view_with_smplx_model_exports_and_names_a_bad_folder(model_dir: Path, tmp_path: Path) -> None:
    folder = _run_folder(tmp_path)
    out = tmp_path / "story.html"
    result = CliRunner().invoke(app, ["view", str(folder), "--export", str(out), "--smplx-model", str(model_dir)])
    assert result.exit_code == 0, result.stderr
    assert out.stat().st_size > 0
    bad = CliRunner().invoke(app, ["view", str(folder), "--export", str(out), "--smplx-model", str(tmp_path / "no")])
    assert bad.exit_code == 2 and "not a folder" in bad.stderr and "Traceback" not in bad.stderr


def test_run_names_a_bad_model_folder_before_running(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["run", "home", "--out", str(tmp_path / "o"), "--smplx-model", str(tmp_path / "no")])
    assert result.exit_code == 2 and "SMPLX_NEUTRAL.npz" in result.stderr
    assert not (tmp_path / "o").exists()  # refused before any planning or output


COFFEE = (
    '```python\ndef parse_event():\n    a = get_character("Ava")\n'
    '    a.set_position(get_area_to_interact_with("coffee_maker_1"))\n'
    '    a.set_orientation("coffee_maker_1")\n    a.set_target_action("use_coffee_maker")\n```'
)


def _body_vertex_count(glb: Path, name: str) -> int:
    doc = gl.GLTF2.load(str(glb))
    mesh = doc.meshes[next(n for n in doc.nodes if n.name == f"{name}:body").mesh]
    return int(doc.accessors[mesh.primitives[0].attributes.POSITION].count)


@pytest.mark.slow
def test_resume_and_replay_export_smplx_bodies_with_smplx_model(
    model_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from storyteller.benchmark.support.fake_openai_server import FakeOpenAI

    monkeypatch.setenv("FAKE_PROVIDER_KEY", "sk-test-123")
    monkeypatch.setenv("STORYTELLER_CACHE_DIR", str(tmp_path / "cache"))
    for var in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL", "STORYTELLER_PLANNER_MODEL"):
        monkeypatch.delenv(var, raising=False)
    run, replayed = tmp_path / "run", tmp_path / "replayed"
    cli = CliRunner()
    with FakeOpenAI(default='{"error": "no script"}') as fake:
        cfg = tmp_path / "fake.toml"
        cfg.write_text(
            f'[llm]\napi_base = "{fake.base}"\napi_key_env = "FAKE_PROVIDER_KEY"\ntimeout_s = 10.0\n'
            '[llm.retry]\nmax_attempts = 1\n[nodes.planner]\nmodel = "openai/fake-planner"\n',
            encoding="utf-8",
        )
        fake.script["fake-planner"] = [COFFEE]
        args = ["run", "home", "-n", "1", "--names", "Ava", "-d", "2", "--max-events", "1", "--planner", "unified",
                "--description", "object-list", "--config", str(cfg), "--out", str(run), "--no-interactive"]  # fmt: skip
        result = cli.invoke(app, args, catch_exceptions=False)
        assert result.exit_code == 0, result.stderr
        assert _body_vertex_count(run / "scene.glb", "Ava") < 2000  # without --smplx-model: the stand-in figure
        for bad in (["resume", str(run)], ["replay", str(run), "--out", str(replayed)]):
            refused = cli.invoke(app, [*bad, "--smplx-model", str(tmp_path / "no")])
            assert refused.exit_code == 2 and "SMPLX_NEUTRAL.npz" in refused.stderr, refused.stderr
        assert not replayed.exists()  # refused before anything ran
        resumed = cli.invoke(app, ["resume", str(run), "--no-interactive", "--smplx-model", str(model_dir)],
                             catch_exceptions=False)  # fmt: skip
        assert resumed.exit_code == 0, resumed.stderr
    assert _body_vertex_count(run / "scene.glb", "Ava") == NUM_VERTICES
    again = cli.invoke(app, ["replay", str(run), "--out", str(replayed), "--smplx-model", str(model_dir)],
                       catch_exceptions=False)  # fmt: skip
    assert again.exit_code == 0, again.stderr
    assert _body_vertex_count(replayed / "scene.glb", "Ava") == NUM_VERTICES


def test_a_shared_parameter_file_is_read_bounded_and_never_unpickled(tmp_path: Path) -> None:
    pickled = tmp_path / "Ava.smplx.npz"
    np.savez(pickled, poses=np.array([{"x": 1}], dtype=object), trans=np.zeros((1, 3)), betas=np.zeros(10))
    with pytest.raises(SmplxModelError, match="never unpickled"):
        load_parameters(pickled)
    text = tmp_path / "Ben.smplx.npz"
    np.savez(text, poses=np.array([["a"] * 165]), trans=np.zeros((1, 3)), betas=np.zeros(10))
    with pytest.raises(SmplxModelError, match="expected real numbers"):
        load_parameters(text)
    fifo = tmp_path / "Cy.smplx.npz"
    os.mkfifo(fifo)
    with pytest.raises(SmplxModelError, match="not a regular file"):
        load_parameters(fifo)  # refused, never waited on

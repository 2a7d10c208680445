"""Rotations converted once for every exporter give, bit for bit, what each exporter's own
conversion of the matrices gives; ``export_run`` (threads, shared rotations) writes the bytes
the exporters write one by one, and a writer's error reaches the caller.

The oracles below are the conversions the exporters made before they shared one: a fresh
``Rotation.from_matrix`` of exactly the matrices each file is made from. The tracks get noise
of 1e-6 on their matrices, so scipy's orthonormalisation has something to do.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from storyteller.benchmark.support.random_tracks import random_track
from storyteller.sim.export.bundle import export_run
from storyteller.sim.export.bvh import (
    EULER_ORDER,
    WORLD_TO_BVH,
    bvh_motion_values,
    depth_first_order,
    export_bvh,
)
from storyteller.sim.export.glb import WORLD_TO_GLTF, export_glb
from storyteller.sim.export.joint_rotations import JointRotations
from storyteller.sim.export.smplx_npz import export_smplx_npz, smplx_parameters
from storyteller.sim.run_folder_names import file_slug
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.world.character_track import CharacterTrack


def _noisy(name: str, frames: int, seed: int) -> CharacterTrack:
    track = random_track(name, frames, seed)
    noise = np.random.default_rng(seed).normal(0.0, 1e-6, track.local_rotations.shape)
    return CharacterTrack(name=name, root_positions=track.root_positions,
                          local_rotations=track.local_rotations + noise, fps=track.fps)


def _with_root(matrices: np.ndarray, axes: np.ndarray) -> np.ndarray:
    out = np.array(matrices)
    out[:, 0] = axes @ out[:, 0]
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_shared_rotations_equal_each_exporters_own_conversion(seed: int) -> None:
    track = _noisy("ann", 97, seed)
    m, n = track.local_rotations, track.num_frames
    shared = JointRotations.of(track)
    np.testing.assert_array_equal(
        smplx_parameters(track, rotations=shared)["poses"][:, :66],
        Rotation.from_matrix(m.reshape(-1, 3, 3)).as_rotvec().reshape(n, 66),
    )
    order = list(depth_first_order())
    bvh = Rotation.from_matrix(_with_root(m, WORLD_TO_BVH)[:, order].reshape(-1, 3, 3)).as_euler(EULER_ORDER)
    np.testing.assert_array_equal(shared.with_root(WORLD_TO_BVH, order).as_euler(EULER_ORDER), bvh)
    glb = Rotation.from_matrix(_with_root(m, WORLD_TO_GLTF).reshape(-1, 3, 3)).as_quat()
    np.testing.assert_array_equal(shared.with_root(WORLD_TO_GLTF).as_quat(), glb)
    np.testing.assert_array_equal(bvh_motion_values(track, rotations=shared), bvh_motion_values(track))


def test_export_run_writes_the_bytes_of_the_exporters_one_by_one(tmp_path: Path) -> None:
    scene = load_bundled_scene("home")
    tracks = [_noisy("Zoe", 61, 4), _noisy("Max Power", 61, 5)]
    together = export_run(tmp_path / "run", scene, tracks)
    alone = tmp_path / "alone"
    alone.mkdir()
    for t in tracks:
        slug = file_slug(t.name)
        assert together.smplx[t.name].read_bytes() == export_smplx_npz(t, alone / f"{slug}.smplx.npz").read_bytes()
        assert together.bvh[t.name].read_bytes() == export_bvh(t, alone / f"{slug}.bvh").read_bytes()
        assert together.tracks[t.name].read_bytes() == t.save(alone / f"{slug}.track.npz").read_bytes()
    assert together.glb.read_bytes() == export_glb(alone / "scene.glb", scene, tracks).read_bytes()


def test_a_writer_that_fails_raises_after_the_others_wrote(tmp_path: Path) -> None:
    tracks = [_noisy("Zoe", 31, 6), _noisy("Max", 31, 7)]
    (tmp_path / "Max.bvh").mkdir()  # the BVH of Max cannot be written
    with pytest.raises(IsADirectoryError):
        export_run(tmp_path, None, tracks)
    written = sorted(p.name for p in tmp_path.iterdir() if p.is_file())
    assert written == ["Max.smplx.npz", "Max.track.npz", "Zoe.bvh", "Zoe.smplx.npz", "Zoe.track.npz", "scene.glb"]

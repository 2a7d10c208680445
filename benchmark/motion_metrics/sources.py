"""What the measures run over: run folders, a crowd of walkers without an LLM, the real clips.

- A **run folder** of ``storyteller run`` (``story.json``, ``scene.json``, one
  ``<name>.track.npz`` per character) is read with the viewer's reader
  (``storyteller.orchestrator.viewer.run_folder.load_run``: bounded, validated). A folder that is not a run
  but holds run folders (the ``--out`` of ``python -m storyteller.benchmark.story_suite run``) stands for
  each of them.
- The **crowd** is ``storyteller.benchmark.crowd_scenario``'s scenario (``IdleErrands``: walkers on random
  errands in the reference Office, cooperative paths, motion matching), run through the world
  step with the project's motion databases.
- The **real clips**: the walks of ``benchmark/mocap_shared.toml`` (CMU) and the walks of
  ``bandai_namco/`` in the located mocap folder (``STORYTELLER_MOCAP``, else
  ``../shared/mocap``; CC BY-NC: measured here, never copied), imported on our skeleton at
  30 fps; and every other clip of that config by label (wave, dance).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import forward_kinematics
from storyteller.sim.scene.model import Scene

BANDAI_WALKS = (
    "dataset-1_walk_normal_001.bvh", "dataset-1_walk_tired_001.bvh", "dataset-1_walk_active_001.bvh",
    "dataset-2_walk_normal_001.bvh", "dataset-2_walk_active_001.bvh", "dataset-2_walk_elderly_001.bvh",
    "dataset-2_walk_exhausted_001.bvh", "dataset-2_walk-turn-left_normal_001.bvh",
    "dataset-2_walk-turn-right_normal_001.bvh",
)  # fmt: skip
BANDAI_MAPPING = {
    "left_hip": "UpperLeg_L", "right_hip": "UpperLeg_R", "left_knee": "LowerLeg_L", "right_knee": "LowerLeg_R",
    "left_ankle": "Foot_L", "right_ankle": "Foot_R", "left_foot": "Toes_L", "right_foot": "Toes_R",
    "left_collar": "Shoulder_L", "right_collar": "Shoulder_R", "left_shoulder": "UpperArm_L",
    "right_shoulder": "UpperArm_R", "left_elbow": "LowerArm_L", "right_elbow": "LowerArm_R",
    "left_wrist": "Hand_L", "right_wrist": "Hand_R",
}  # fmt: skip
"""Our leg and arm joints in the Bandai Namco skeleton (the importer finds the rest by name)."""
PELVIS_RANGE_M = (0.6, 1.2)
"""Median pelvis height of a clip imported right (a standing, walking adult), metres."""
PLANTED_PERCENTILE = 5.0
"""A real clip's floor is unknown on our skeleton (the importer scales the body, not the
floor): it is placed so that the clip's lowest foot joint is, at this percentile of its
frames, as high as our skeleton's lowest foot joint standing in the rest pose."""


class SourceError(Exception):
    """Something to measure that cannot be read (one line: the path and what is wrong)."""


@dataclass(frozen=True)
class CharacterMotion:
    """One character's world joints (F, 22, 3) and per-frame action labels (database keys)."""

    name: str
    joints: NDArray[np.float64]
    labels: tuple[str, ...]


@dataclass(frozen=True)
class RunMotion:
    """The characters of one run (or one set of clips), at ``fps``, in ``scene`` (None: no
    objects); ``folder`` when it was read from a run folder (facing needs its plans)."""

    name: str
    fps: float
    scene: Scene | None
    characters: tuple[CharacterMotion, ...]
    folder: Path | None = None

    @property
    def frames(self) -> int:
        return sum(len(c.joints) for c in self.characters)


def run_folders(paths: Sequence[Path]) -> list[Path]:
    """``paths`` with each folder that is not a run replaced by the run folders inside it."""
    out: list[Path] = []
    for p in paths:
        if (p / "story.json").is_file():
            out.append(p)
        elif p.is_dir() and (inner := sorted(q for q in p.iterdir() if (q / "story.json").is_file())):
            out.extend(inner)
        else:
            raise SourceError(f"{p}: not a run folder (no story.json) nor a folder of run folders")
    return out


def load_run_motion(folder: Path) -> RunMotion:
    """The characters of a finished run folder."""
    from storyteller.orchestrator.viewer.run_folder import RunFolderError, load_run

    try:
        run = load_run(folder)
    except RunFolderError as exc:
        raise SourceError(str(exc)) from None
    chars = []
    for t in run.tracks:
        joints = forward_kinematics(t.local_rotations, t.root_positions)[0]
        labels = t.action_labels if t.action_labels is not None else ("",) * t.num_frames
        chars.append(CharacterMotion(t.name, joints, tuple(labels)))
    return RunMotion(folder.name, run.fps, run.scene, tuple(chars), folder)


def crowd_motion(n: int, seconds: float, seed: int) -> RunMotion:
    """``n`` walkers on random errands in the reference Office for ``seconds`` (30 fps)."""
    from storyteller.benchmark.crowd_scenario import OFFICE, REFERENCE, IdleErrands
    from storyteller.orchestrator.cache_paths import motion_cache_dir
    from storyteller.sim.motion.database import load_databases
    from storyteller.sim.motion.matching import MotionMatcher
    from storyteller.sim.paths.nav_grid import build_nav_grid
    from storyteller.sim.scene.files import load_scene
    from storyteller.sim.world.step import World, WorldConfig, step

    if not REFERENCE.found:
        raise SourceError(f"crowd: {REFERENCE.reason}")
    scene = load_scene(OFFICE)
    grid = build_nav_grid(scene)
    frames = round(seconds * 30)
    errands = IdleErrands(grid, n, seed)
    world = World(scene, errands.starts, MotionMatcher(load_databases(cache_dir=motion_cache_dir())), grid=grid,
                  config=WorldConfig(seed=seed, initial_capacity=frames))
    for _ in range(frames):
        _, out = step(world, errands.commands(), world.dt)
        errands.observe(out)
    chars = []
    for name, t in sorted(world.tracks().items()):
        joints = forward_kinematics(t.local_rotations, t.root_positions)[0]
        labels = t.action_labels if t.action_labels is not None else ("",) * len(joints)
        chars.append(CharacterMotion(name, joints, tuple(labels)))
    return RunMotion(f"crowd of {n} (Office, {seconds:g} s)", 30.0, scene, tuple(chars))


def rest_foot_height() -> float:
    """Height of our skeleton's lowest foot joint standing in the rest pose (metres)."""
    from storyteller.benchmark.motion_metrics.feet import lowest_foot_height
    from storyteller.sim.body.skeleton import NUM_JOINTS, REST_OFFSETS, heading_to_root

    rot = np.broadcast_to(np.eye(3), (1, NUM_JOINTS, 3, 3)).copy()
    rot[0, 0] = heading_to_root(0.0)
    joints = forward_kinematics(rot, np.array([[0.0, 0.0, REST_OFFSETS[0, 1]]]))[0]
    return float(lowest_foot_height(joints)[0])


def on_floor(joints: NDArray[np.float64]) -> NDArray[np.float64]:
    """A real clip's joints moved up or down onto our floor (``PLANTED_PERCENTILE``)."""
    from storyteller.benchmark.motion_metrics.feet import lowest_foot_height

    low = float(np.percentile(lowest_foot_height(joints), PLANTED_PERCENTILE))
    out = np.array(joints, dtype=np.float64)
    out[..., 2] += rest_foot_height() - low
    return out


def real_clips() -> tuple[RunMotion, str]:
    """The real clips (each a character, labelled with its database key on every frame), and a
    note of what was found; empty when the mocap folder is absent."""
    from storyteller.benchmark.motion_quality import MOCAP, shipped_config
    from storyteller.benchmark.motion_quality import real_clips as config_clips
    from storyteller.orchestrator.cache_paths import motion_cache_dir
    from storyteller.sim.motion.config import ClipEntry, MotionConfig, MotionConfigError, import_entry
    from storyteller.sim.motion.sources.bvh_import import MocapImportError

    if not MOCAP.found:
        return RunMotion("real clips", 30.0, None, ()), f"real clips: {MOCAP.reason}"
    chars: list[CharacterMotion] = []
    skipped: list[str] = []
    try:
        by_key = config_clips(shipped_config())
    except (MotionConfigError, MocapImportError, OSError) as exc:
        by_key = {}
        skipped.append(str(exc).splitlines()[0][:200])
    for key, clips in by_key.items():
        chars.extend(CharacterMotion(c.name, on_floor(c.joint_positions()), (key,) * c.num_frames) for c in clips)
    bandai = MotionConfig(root=str(MOCAP.path / "bandai_namco"),
                          clips=tuple(ClipEntry(file=f, label="walk", mapping=BANDAI_MAPPING) for f in BANDAI_WALKS))
    for entry in bandai.clips:
        try:
            c = import_entry(bandai, entry, motion_cache_dir())
        except (MotionConfigError, MocapImportError, OSError) as exc:
            skipped.append(str(exc).splitlines()[0][:200])
            continue
        joints = c.joint_positions()
        if not PELVIS_RANGE_M[0] <= float(np.median(joints[:, 0, 2])) <= PELVIS_RANGE_M[1]:
            skipped.append(f"{entry.file}: imported with its pelvis {np.median(joints[:, 0, 2]):.2f} m high (not a"
                           " standing adult: the import is wrong, left out)")
            continue
        chars.append(CharacterMotion(Path(entry.file).stem, on_floor(joints), ("walk",) * c.num_frames))
    note = f"real clips: {len(chars)} from {MOCAP.path}" + (f"; skipped: {'; '.join(skipped)}" if skipped else "")
    return RunMotion("real clips", 30.0, None, tuple(chars)), note

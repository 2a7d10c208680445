"""A tiny finished run folder written directly (no simulation): one character, ``frames``
frames standing at (1, 2), the bundled home scene, one event; for viewer tests that need a run
but not a story."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from storyteller.sim.body.skeleton import NUM_JOINTS, heading_to_root
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.files import save_scene_json
from storyteller.sim.world.character_track import CharacterTrack


def write_tiny_run(
    folder: Path, *, activity: str = "Ava waves", instruction: str = "wave", frames: int = 20
) -> Path:
    """Write the run into ``folder`` (created) and return it; ``activity`` is the event's and
    every frame's action label, ``instruction`` the story's."""
    folder.mkdir(parents=True)
    event = {
        "event_id": "event-0000",
        "index": 0,
        "characters": ["Ava"],
        "activity": activity,
        "requested_frame": 0,
        "applied_frame": 0,
        "state": "ongoing",
        "finished_frame": None,
        "failure": None,
    }
    story = {"scene": "home", "characters": ["Ava"], "instruction": instruction, "fps": 30, "frames": frames,
             "steps": [], "events": [event]}  # fmt: skip
    (folder / "story.json").write_text(json.dumps(story), encoding="utf-8")
    rot = np.broadcast_to(np.eye(3), (frames, NUM_JOINTS, 3, 3)).copy()
    rot[:, 0] = heading_to_root(0.0)
    root = np.column_stack([np.full(frames, 1.0), np.full(frames, 2.0), np.full(frames, 0.92)])
    CharacterTrack(name="Ava", root_positions=root, local_rotations=rot,
                   action_labels=(activity,) * frames).save(folder / "Ava.track.npz")  # fmt: skip
    save_scene_json(load_bundled_scene("home"), folder / "scene.json")
    return folder

"""Names written into the run's GLB are data (issue 22): a glTF viewer shows node, mesh, material
and skin names as text, so an object label and a character named with ESC[31m, BEL, U+202E and
U+2028 are written with each shown as its escape, and an ordinary name is written as it is.
Before the names went through ``plain`` this failed: they were written raw.
"""

from __future__ import annotations

import unicodedata

import numpy as np

from storyteller.sim.body.skeleton import NUM_JOINTS
from storyteller.sim.export.glb import build_glb
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.visible_text import UNSAFE_CATEGORIES
from storyteller.sim.world.character_track import CharacterTrack

HOSTILE = "x\x1b[31my\x07z\u202ew\u2028v"
SHOWN = "x\\x1b[31my\\x07z\\u202ew\\u2028v"


def test_every_name_in_the_glb_is_written_escaped() -> None:
    table = SceneObject(name=f"table{HOSTILE}_1", label=f"table{HOSTILE}", idx=1, center=(2.0, 2.0, 0.375),
                        size=(1.0, 0.8, 0.75))
    chair = SceneObject(name="chair_1", label="chair", idx=1, center=(0.5, 0.5, 0.45), size=(0.5, 0.5, 0.9))
    scene = Scene(name="room", bounds_min=(0.0, 0.0), bounds_max=(4.0, 4.0), objects=(table, chair))
    frames = 3
    track = CharacterTrack(name=f"Ann{HOSTILE}", root_positions=np.tile([1.0, 1.0, 0.93], (frames, 1)),
                           local_rotations=np.tile(np.eye(3), (frames, NUM_JOINTS, 1, 1)))
    doc = build_glb(scene, [track])
    groups = (doc.scenes, doc.nodes, doc.meshes, doc.materials, doc.skins, doc.accessors, doc.animations)
    names = [item.name for group in groups for item in group if item.name is not None]
    raw = [n for n in names if any(unicodedata.category(c) in UNSAFE_CATEGORIES for c in n)]
    assert raw == []
    assert f"table{SHOWN}_1" in names and f"table{SHOWN}" in names  # the node; the label's mesh
    assert f"Ann{SHOWN}" in names and f"Ann{SHOWN}:pelvis" in names and f"Ann{SHOWN}:body" in names
    assert "chair_1" in names  # an ordinary name is unchanged

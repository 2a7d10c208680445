"""The default, generated clip set of every motion database key (no downloaded data).

``procedural_clips(key)`` returns deterministic clips for a database key (see
storyteller.sim.motion.action_labels.database_key). Bump ``GENERATOR_VERSION`` whenever a generator changes so
that cached databases are rebuilt (a refit of the gait changes it by itself).
"""

from __future__ import annotations

import dataclasses

from storyteller.sim.motion.action_labels import action_spec, family_of, is_seated_key
from storyteller.sim.motion.cache import content_key
from storyteller.sim.motion.clips import MotionClip
from storyteller.sim.motion.sources.gait_params import FITTED_GAIT
from storyteller.sim.motion.sources.procedural_actions import (
    SEAT_HEIGHTS,
    action_clip,
    sit_idle_clip,
    sitting_clip,
)
from storyteller.sim.motion.sources.procedural_locomotion import dance_clip, locomotion_clips

GENERATOR_VERSION = f"procedural-motion-2-{content_key(dataclasses.asdict(FITTED_GAIT))[:12]}"
"""Names the generators and the fitted gait they read, so a refit rebuilds cached databases too."""


def procedural_clips(key: str) -> list[MotionClip]:
    """Generated clips for one database key (raises UnknownActionLabelError for bad keys)."""
    family_of(key)
    spec = action_spec(key)
    if key == "walk":
        return locomotion_clips()
    if key in ("sit_down", "stand_up"):
        return [sitting_clip(key, h) for h in SEAT_HEIGHTS]
    if key == "sit_idle":
        return [sit_idle_clip(h) for h in SEAT_HEIGHTS]
    if is_seated_key(key):
        return [action_clip(spec.label, seated=True, seat_height=h, name=f"{key}_h{h:.2f}")
                for h in SEAT_HEIGHTS]
    if key == "dance":
        return [dance_clip(), action_clip("idle", name="dance_rest")._replace_key("dance")]
    return [action_clip(spec.label)]

"""A stand-in motion layer for world tests: the rest pose on the world's root, pelvis lowered
when seated, no foot contacts. Tests of the world's own rules (where roots go, which way they
face, which phase plays) use it to run fast; the real matcher runs in tests/sim/motion/test_crowd_motion.py."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from storyteller.sim.body.skeleton import NUM_JOINTS, REST_OFFSETS, heading_to_root
from storyteller.sim.motion.matching import MotionQuery, Pose


class RestPoseMotion:
    """``sim.world.motion_layer.MotionLayer``: every pose is the rest pose facing the query's
    heading on its root; ``queries`` keeps every query (when ``record``)."""

    def __init__(self, record: bool = False) -> None:
        self.record = record
        self.queries: list[MotionQuery] = []

    def initial_state(
        self, label: str, root_xy: Sequence[float] | np.ndarray, heading: float, seated: bool = False
    ) -> int:
        return 0

    def step(self, state: int, query: MotionQuery, dt: float) -> tuple[int, Pose]:
        if self.record:
            self.queries.append(query)
        rot = np.tile(np.eye(3), (NUM_JOINTS, 1, 1))
        rot[0] = heading_to_root(float(query.heading or 0.0))
        sitting = query.seated or query.label in ("sit_down", "stand_up")
        z = 0.55 if sitting else float(REST_OFFSETS[0, 1])
        root = np.asarray(query.root_xy, dtype=float)
        return state + 1, Pose(np.array([*root, z]), rot, root, float(query.heading or 0.0), np.zeros(2, dtype=bool))

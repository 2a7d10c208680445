"""Random but plausible character tracks, for the exporter tests (not motion anyone would want).

``random_track(name, frames, seed)`` is a pure function of its arguments: the same seed gives
the same arrays, so exporter tests can compare bytes across runs.
"""

from __future__ import annotations

import numpy as np

from sim.body.skeleton import NUM_JOINTS, axis_angle_to_matrix, heading_to_root
from sim.world.character_track import CharacterTrack


def random_track(
    name: str, num_frames: int, seed: int, *, fps: float = 30.0, max_joint_angle: float = 0.6
) -> CharacterTrack:
    """A random but plausible track.

    The pelvis wanders on the floor (about 0.8-0.95 m high) with a slowly turning heading and
    a small tilt; every other joint bends smoothly by at most ``max_joint_angle`` radians.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(num_frames) / fps
    # Smooth signals: a few random sinusoids per channel.
    freqs = rng.uniform(0.1, 1.5, size=(3, NUM_JOINTS, 3))
    phases = rng.uniform(0.0, 2 * np.pi, size=(3, NUM_JOINTS, 3))
    amps = rng.uniform(0.0, 1.0, size=(3, NUM_JOINTS, 3))
    wave = (
        np.einsum(
            "kjc,nkjc->njc", amps, np.sin(2 * np.pi * freqs * t[:, None, None, None] + phases)
        )
        / 3.0
    )
    aa = wave * max_joint_angle / np.sqrt(3.0)
    rotations = axis_angle_to_matrix(aa)
    heading = rng.uniform(-np.pi, np.pi) + np.cumsum(rng.normal(0.0, 0.02, num_frames))
    tilt = axis_angle_to_matrix(0.15 * wave[:, 0])
    rotations[:, 0] = heading_to_root(heading) @ tilt
    step = 1.2 / fps * np.stack([np.cos(heading), np.sin(heading)], axis=1)
    xy = rng.uniform(-3.0, 3.0, size=2) + np.cumsum(step, axis=0)
    z = 0.875 + 0.075 * np.sin(2 * np.pi * 0.9 * t + rng.uniform(0, 2 * np.pi))
    return CharacterTrack(
        name=name, root_positions=np.column_stack([xy, z]), local_rotations=rotations, fps=fps
    )

"""Random but plausible character tracks, for the exporter tests (not motion anyone would want).

``random_track(name, frames, seed)`` is a pure function of its arguments: the same seed gives
the same arrays, so exporter tests can compare bytes across runs. ``wandering_story`` is a
whole run recording (people walking between free cells, pausing with actions and events) for
the picture tests and ``benchmark/bench_pictures.py``.
"""

from __future__ import annotations

import numpy as np

from storyteller.sim.body.skeleton import NUM_JOINTS, axis_angle_to_matrix, heading_to_root
from storyteller.sim.export.video import RunRecording
from storyteller.sim.paths.nav_grid import NavGrid
from storyteller.sim.scene.model import Scene
from storyteller.sim.world.character_track import CharacterTrack


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


def wandering_story(
    scene: Scene, grid: NavGrid, characters: int, seconds: float, seed: int, *, fps: float = 30.0
) -> RunRecording:
    """A run recording of ``characters`` people walking (1.2 m/s, straight lines) between
    random free cells of ``grid`` and pausing 2-5 s at each with an action, a few of the pauses
    inside a shared event: what a story's animation shows, without a planner or a motion model.
    A pure function of its arguments."""
    rng = np.random.default_rng(seed)
    n = round(seconds * fps)
    free = np.argwhere(grid.free)
    centres = np.asarray(grid.origin) + (free + 0.5) * grid.cell_size
    tracks: dict[str, CharacterTrack] = {}
    events: dict[str, list[str]] = {}
    for k in range(characters):
        name = f"P{k + 1}"
        xy = np.empty((n, 2))
        heading = np.empty(n)
        labels: list[str] = []
        ids: list[str] = []
        here, facing, f = centres[rng.integers(len(centres))], 0.0, 0
        while f < n:
            there = centres[rng.integers(len(centres))]
            d = there - here
            walk = max(1, int(np.hypot(*d) / 1.2 * fps))
            facing = float(np.arctan2(d[1], d[0]))
            s = np.linspace(0.0, 1.0, walk, endpoint=False)[:, None]
            m = min(walk, n - f)
            xy[f : f + m], heading[f : f + m] = (here + s * d)[:m], facing
            labels += ["walk"] * m
            ids += [""] * m
            f += m
            here = there
            stay = min(int(rng.uniform(2.0, 5.0) * fps), n - f)
            xy[f : f + stay], heading[f : f + stay] = here, facing
            labels += [str(rng.choice(["sit", "talk", "drink", "stand"]))] * stay
            ids += [f"e{f // int(10 * fps) + 1}" if rng.random() < 0.5 else ""] * stay
            f += stay
        rotations = np.tile(np.eye(3), (n, NUM_JOINTS, 1, 1))
        rotations[:, 0] = heading_to_root(heading)
        root = np.column_stack([xy, np.full(n, 0.9)])
        tracks[name] = CharacterTrack(
            name=name, root_positions=root, local_rotations=rotations, fps=fps, action_labels=tuple(labels)
        )
        events[name] = ids
    return RunRecording(scene, tracks, events, grid)

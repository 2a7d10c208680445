"""The path-following rule for one path in plain numpy: the oracle of the compiled
``storyteller.sim.paths.tracks.path_tracks``.

``track_reference`` is the arithmetic of ``storyteller.sim.paths.cooperative_astar.position_at`` for every
frame of one path; ``tests/sim/paths/test_path_tracks.py`` checks that the compiled loop gives the very
same floats. Not used by the simulation.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from storyteller.sim.paths.tracks import Cell, track_frames


def track_reference(path: Sequence[Cell], origin: tuple[float, float], cell_size: float, step_frames: int,
                    fps: int, step_time: float) -> np.ndarray:
    """Positions (track_frames, 2) of one path for frames d = 0, 1, ... after its start."""
    cells = np.asarray(path, dtype=float).reshape(-1, 2)
    centres = np.asarray(origin) + (cells + 0.5) * cell_size
    d = np.arange(track_frames(len(path), step_frames))
    u = (d / fps) / step_time
    k = np.floor(u).astype(np.int64)
    last = len(path) - 1
    kk = np.minimum(k, max(last - 1, 0))
    s = (u - kk)[:, None]
    nxt = np.minimum(kk + 1, last)
    track: np.ndarray = (1.0 - s) * centres[kk] + s * centres[nxt]
    track[(u <= 0) | (k >= last)] = centres[np.where(u <= 0, 0, last)][(u <= 0) | (k >= last)]
    return track

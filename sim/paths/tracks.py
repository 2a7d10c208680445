"""Per-frame positions along planned grid paths, for many walkers at once (compiled).

A walker following a cooperative plan (``storyteller.sim.paths.following.CrowdNavigator``) is, ``d``
frames after the plan was made, at ``u = (d / fps) / step_time`` steps along its path of cell
centres: on the straight segment from cell ``floor(u)`` to the next one, at fraction
``u - floor(u)``; at the first centre before it starts and at the last one once the path is
done (the arithmetic of ``storyteller.sim.paths.cooperative_astar.position_at``). ``path_tracks`` computes
it for every path of a plan in one compiled loop, with the very same float operations as its
numpy oracle (``tests/support/path_reference.py``) element by element (so the same floats;
``tests/sim/paths/test_path_tracks.py`` compares them), into one array whose rows are padded with each
path's last centre (later frames stay there). :class:`PlanTracks` keeps that array for the
current plan of a crowd.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Hashable, Mapping, Sequence

import numpy as np
from numba import njit

__all__ = ["PlanTracks", "gather_rows", "is_movement", "path_tracks", "track_frames", "walker_headings"]

Cell = tuple[int, int]


def track_frames(path_len: int, step_frames: int) -> int:
    """Rows of a path's track: every frame until it ends, plus one at the end."""
    return (path_len - 1) * step_frames + 2


def path_tracks(paths: Sequence[Sequence[Cell]], origin: tuple[float, float], cell_size: float, step_frames: int,
                fps: int, step_time: float) -> tuple[np.ndarray, list[int]]:
    """(tracks (len(paths), D, 2), rows per path): the positions of every (non-empty) path at
    frames 0, 1, ... (``track_frames`` rows), row ``i`` padded with path ``i``'s last centre up
    to the longest track ``D``."""
    lens = [len(p) for p in paths]
    sizes = [track_frames(n, step_frames) for n in lens]
    if not paths:
        return np.zeros((0, 1, 2)), sizes
    if min(lens) < 1:
        raise ValueError("path_tracks needs non-empty paths")
    chain = itertools.chain.from_iterable
    flat = np.fromiter(chain(chain(paths)), dtype=np.float64, count=2 * sum(lens)).reshape(-1, 2)
    out = _tracks(flat, np.asarray(lens, dtype=np.int64), float(origin[0]), float(origin[1]), float(cell_size),
                  max(sizes), int(fps), float(step_time))
    return out, sizes


@njit(cache=True, nogil=True)
def _tracks(flat: np.ndarray, lens: np.ndarray, ox: float, oy: float, cell_size: float, rows: int, fps: int,
            step_time: float) -> np.ndarray:  # pragma: no cover - compiled
    out = np.empty((lens.shape[0], rows, 2))
    u = np.empty(rows)
    for d in range(rows):
        u[d] = (d / fps) / step_time
    start = 0
    for a in range(lens.shape[0]):
        last = lens[a] - 1
        for d in range(rows):
            ud = u[d]
            k = math.floor(ud)
            if ud <= 0 or k >= last:  # before the first move / after the last: on a centre
                e = start + (0 if ud <= 0 else last)
                out[a, d, 0] = ox + (flat[e, 0] + 0.5) * cell_size
                out[a, d, 1] = oy + (flat[e, 1] + 0.5) * cell_size
                continue
            kk = min(k, max(last - 1, 0))
            nx = min(kk + 1, last)
            s = ud - kk
            p, q = start + kk, start + nx
            out[a, d, 0] = (1.0 - s) * (ox + (flat[p, 0] + 0.5) * cell_size) + s * (ox + (flat[q, 0] + 0.5) * cell_size)
            out[a, d, 1] = (1.0 - s) * (oy + (flat[p, 1] + 0.5) * cell_size) + s * (oy + (flat[q, 1] + 0.5) * cell_size)
        start += lens[a]
    return out


def gather_rows(tracks: np.ndarray, rows: np.ndarray, offset: int, frames: tuple[int, ...]) -> np.ndarray:
    """``tracks[rows[i], clip(offset + frames[j], 0, D - 1)]`` as a new array (len(rows), len(frames), 2)
    (``tracks`` (A, D, 2) as built by ``path_tracks``: later frames stay on the last row)."""
    return _gather_rows(tracks, rows, int(offset), frames)


@njit(cache=True, nogil=True)
def _gather_rows(tracks: np.ndarray, rows: np.ndarray, offset: int, frames: tuple[int, ...]) -> np.ndarray:  # pragma: no cover
    last = tracks.shape[1] - 1
    out = np.empty((rows.shape[0], len(frames), 2))
    for j in range(len(frames)):
        d = min(max(frames[j] + offset, 0), last)
        for i in range(rows.shape[0]):
            out[i, j, 0] = tracks[rows[i], d, 0]
            out[i, j, 1] = tracks[rows[i], d, 1]
    return out


def walker_headings(last: np.ndarray, path: np.ndarray, heading: np.ndarray, step_dir: np.ndarray,
                    max_turn: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The world's per-frame walker kinematics, for W walkers at once.

    ``last`` (W, 2): each walker's position at the last frame; ``path`` (W, 5, 2): its position
    now, its planned positions +10/+20/+30 frames ahead and the lookahead point it turns to;
    ``heading`` (W,): headings at the last frame; ``step_dir`` (W, 3): ``np.arctan2`` of the
    three future steps (numpy's, as the world always used). Returns (new headings wrapped to
    [-pi, pi), future headings (W, 3): each future step's direction, or the new (unwrapped)
    heading where a step does not move, moved this frame (W,)): the heading turns towards the
    lookahead point (when it is more than 0.05 m away) by at most ``max_turn``. Same float
    operations as the Python loop it replaces (``math.atan2``, ``math.hypot``, Python's float
    ``%``), compiled.
    """
    return _walker_headings(np.ascontiguousarray(last, dtype=float), np.ascontiguousarray(path, dtype=float),
                            np.ascontiguousarray(heading, dtype=float), np.ascontiguousarray(step_dir, dtype=float),
                            float(max_turn))


@njit(cache=True, nogil=True)
def _walker_headings(last: np.ndarray, path: np.ndarray, heading: np.ndarray, step_dir: np.ndarray,
                     max_turn: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    n = path.shape[0]
    wrapped = np.empty(n)
    fut = np.empty((n, 3))
    moved = np.empty(n, dtype=np.bool_)
    tau = 2.0 * math.pi
    for i in range(n):
        moved[i] = math.hypot(path[i, 0, 0] - last[i, 0], path[i, 0, 1] - last[i, 1]) > 1e-6
        ax = path[i, 4, 0] - path[i, 0, 0]
        ay = path[i, 4, 1] - path[i, 0, 1]
        h = heading[i]
        if math.hypot(ax, ay) > 0.05:
            err = (math.atan2(ay, ax) - h + math.pi) % tau - math.pi
            lo = -max_turn
            err = lo if lo > err else err  # Python's max(err, -max_turn)
            err = max_turn if max_turn < err else err  # min(err, max_turn)
            h = h + err
        wrapped[i] = (h + math.pi) % tau - math.pi
        for j in range(3):
            size = math.hypot(path[i, j + 1, 0] - path[i, j, 0], path[i, j + 1, 1] - path[i, j, 1])
            fut[i, j] = step_dir[i, j] if size > 1e-6 else h
    return wrapped, fut, moved


def is_movement(d0: float, d1: float) -> bool:
    """Whether a displacement (d0, d1) counts as movement: ``d @ d > 1e-12`` exactly as numpy's
    dot computes it (its rounding may differ by an ulp from ``d0 * d0 + d1 * d1``, so numpy
    decides the rare values near the threshold)."""
    dd = d0 * d0 + d1 * d1
    if dd > 2e-12:
        return True
    if dd < 0.5e-12:
        return False
    d = np.array([d0, d1])
    return float(d @ d) > 1e-12


class PlanTracks:
    """Per-frame positions on every walker's path of the current plan (``path_tracks``): one
    (A, D, 2) array, a row per agent of ``paths`` (padded with its last position), built on first
    use after ``clear`` (the navigator clears it at each replan and when a walker is added), for
    all agents at once (the same floats as one agent at a time)."""

    def __init__(self, origin: tuple[float, float], cell_size: float, step_frames: int, fps: int,
                 step_time: float) -> None:
        self._layout = (origin, cell_size, step_frames, fps, step_time)
        self._stack: np.ndarray | None = None
        self._row: dict[Hashable, int] = {}
        self._len: list[int] = []
        self._rows_cache: dict[tuple[Hashable, ...], tuple[np.ndarray, np.ndarray]] = {}  # see rows_of

    def clear(self) -> None:
        """Drop the array: the next use builds it from the paths it is given."""
        self._stack = None

    def forget(self, agent: Hashable) -> None:
        """Drop ``agent``'s row (it stopped walking); the other rows stay valid."""
        self._row.pop(agent, None)

    def stacked(self, paths: Mapping[Hashable, Sequence[Cell]]) -> np.ndarray:
        """Every agent's track (see ``track``) in one array (A, D, 2), rows padded with the
        agent's last position (later frames stay there)."""
        stack = self._stack
        if stack is None:
            agents = list(paths)
            stack, self._len = path_tracks([paths[a] for a in agents], *self._layout)
            self._stack = stack
            self._row = {a: i for i, a in enumerate(agents)}
        return stack

    def track(self, paths: Mapping[Hashable, Sequence[Cell]], agent: Hashable) -> np.ndarray:
        """Positions (D, 2) on the agent's current path for the frames ``d`` after the plan
        (d = 0 .. D - 1; later frames: the last row), with the very arithmetic of
        ``position_at`` (a view of the agent's row of ``stacked``)."""
        stack = self.stacked(paths)
        i = self._row.get(agent)
        if i is None:  # a walker added since the stack was built
            self._stack = None
            stack = self.stacked(paths)
            i = self._row[agent]
        return stack[i, : self._len[i]]

    def rows_of(self, paths: Mapping[Hashable, Sequence[Cell]],
                agents: Sequence[Hashable]) -> tuple[np.ndarray, np.ndarray]:
        """(``stacked(paths)``, each agent's row in it)."""
        key = tuple(agents)
        hit = self._rows_cache.get(key)
        if hit is not None and hit[0] is self._stack:
            return hit
        stack = self.stacked(paths)
        row = self._row
        if any(a not in row for a in key):  # a walker added since the stack was built
            self._stack = None
            stack = self.stacked(paths)
            row = self._row
        hit = (stack, np.array([row[a] for a in key], dtype=np.int64))
        if len(self._rows_cache) > 8:
            self._rows_cache.clear()
        self._rows_cache[key] = hit
        return hit
